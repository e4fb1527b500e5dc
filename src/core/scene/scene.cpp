#include "simstack/scene/scene.h"

#include <algorithm>
#include <stdexcept>

namespace simstack {
namespace {
constexpr double kSampleSpacing = 0.004;  // m; GT distances near the surface use the normal
constexpr int kMaxSamples = 60000;
}  // namespace

std::shared_ptr<const ObjectShape> ObjectShape::fromSuperquadric(const Superquadric& sq) {
  if (!(sq.scale_m.array() > 0.0).all())
    throw std::invalid_argument("superquadric scales must be > 0");
  if (!(sq.exponents.array() > 0.0).all())
    throw std::invalid_argument("superquadric exponents must be > 0");
  std::shared_ptr<ObjectShape> s(new ObjectShape());
  s->kind_ = Kind::kSuperquadric;
  s->name_ = "superquadric";
  s->superquadric_ = sq;
  s->superquadric_.T_table_object = Transform::Identity();
  s->mesh_ = s->superquadric_.meshObject(24);
  // A coarse lattice (duplicates on cube edges removed) keeps Bullet's GJK fast.
  for (const Vec3& v : s->superquadric_.meshObject(4).vertices) {
    bool seen = false;
    for (const Vec3& h : s->hull_points_) seen |= (h - v).squaredNorm() < 1e-14;
    if (!seen) s->hull_points_.push_back(v);
  }
  s->volume_ = s->superquadric_.volume();
  // Deterministic per shape: the samples depend on the parameters only.
  std::seed_seq seq{static_cast<int>(sq.scale_m.x() * 1e6), static_cast<int>(sq.scale_m.y() * 1e6),
                    static_cast<int>(sq.scale_m.z() * 1e6),
                    static_cast<int>(sq.exponents.sum() * 1e3)};
  std::mt19937_64 rng(seq);
  s->finish(rng);
  return s;
}

std::shared_ptr<const ObjectShape> ObjectShape::fromMesh(const std::string& name,
                                                         int catalogue_index,
                                                         const TriangleMesh& mesh) {
  const double volume = mesh.volume();
  if (mesh.empty() || !(std::abs(volume) > 1e-9)) {
    throw std::invalid_argument("mesh '" + name + "' encloses no volume");
  }
  std::shared_ptr<ObjectShape> s(new ObjectShape());
  s->kind_ = Kind::kMesh;
  s->name_ = name;
  s->catalogue_index_ = catalogue_index;
  Transform T = Transform::Identity();
  T.translation() = -mesh.volumeCentroid();
  s->mesh_ = mesh.transformed(T);
  if (volume < 0.0) {  // inward-facing triangles: flip so that normals point out
    for (auto& t : s->mesh_.triangles) std::swap(t[1], t[2]);
  }
  s->volume_ = std::abs(volume);
  s->hull_.emplace(s->mesh_.vertices);
  s->hull_points_ = s->hull_->vertices();
  std::mt19937_64 rng(static_cast<uint64_t>(catalogue_index + 1) * 7919u);
  s->finish(rng);
  return s;
}

void ObjectShape::finish(std::mt19937_64& rng) {
  // Dense samples about kSampleSpacing apart; superquadric samples sit on the exact surface.
  const double area = mesh_.area();
  const int n =
      std::clamp(static_cast<int>(area / (kSampleSpacing * kSampleSpacing)), 500, kMaxSamples);
  samples_ = kind_ == Kind::kSuperquadric ? superquadric_.sampleSurfaceObject(n, rng)
                                          : mesh_.sampleSurface(n, rng);
  sample_spacing_m_ = std::sqrt(area / n);
  bounding_radius_ = 0.0;
  for (const auto& v : mesh_.vertices) bounding_radius_ = std::max(bounding_radius_, v.norm());
}

bool ObjectShape::containsObject(const Vec3& p_object) const {
  if (kind_ == Kind::kSuperquadric) return superquadric_.insideOutsideObject(p_object) < 1.0;
  return hull_->contains(p_object);
}

Vec3 Scene::surfaceCentroid() const {
  Vec3 sum = Vec3::Zero();
  double weight = 0.0;
  for (const auto& o : objects) {
    const auto& samples = o.shape->surfaceSamples();
    if (samples.empty()) continue;
    Vec3 c = Vec3::Zero();
    for (const auto& s : samples) c += s.position;
    c /= static_cast<double>(samples.size());
    // Weight each object by its area (samples are spaced evenly, so the count is the area).
    const double area = samples.size() * o.shape->sampleSpacing() * o.shape->sampleSpacing();
    sum += area * (o.T_table_object * c);
    weight += area;
  }
  return weight > 0.0 ? Vec3(sum / weight) : Vec3::Zero();
}

std::vector<SurfacePoint> Scene::surfaceSamplesTable(std::vector<int>* object_index) const {
  std::vector<SurfacePoint> out;
  if (object_index) object_index->clear();
  for (size_t k = 0; k < objects.size(); ++k) {
    const auto& T = objects[k].T_table_object;
    for (const auto& s : objects[k].shape->surfaceSamples()) {
      out.push_back({T * s.position, T.linear() * s.normal});
      if (object_index) object_index->push_back(static_cast<int>(k));
    }
  }
  return out;
}

}  // namespace simstack
