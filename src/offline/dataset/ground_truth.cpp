#include "simstack/offline/dataset/ground_truth.h"

#include <nanoflann.hpp>

#include <cmath>
#include <limits>
#include <stdexcept>

namespace simstack {
namespace {

struct SampleCloud {
  const std::vector<SurfacePoint>* samples;
  size_t kdtree_get_point_count() const { return samples->size(); }
  double kdtree_get_pt(size_t i, size_t dim) const { return (*samples)[i].position[dim]; }
  template <class BBox>
  bool kdtree_get_bbox(BBox&) const {
    return false;
  }
};

using KdTree =
    nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, SampleCloud>,
                                        SampleCloud, 3, size_t>;

struct ObjectField {
  const SceneObject* object;
  Transform T_object_table;
  SampleCloud cloud;
  std::unique_ptr<KdTree> tree;
  double near_surface_m;
};

}  // namespace

struct SceneDistanceField::Impl {
  std::vector<ObjectField> objects;
  double truncation_m;
};

SceneDistanceField::SceneDistanceField(const Scene& scene, double truncation_m)
    : impl_(std::make_unique<Impl>()) {
  if (!(truncation_m > 0.0)) throw std::invalid_argument("truncation must be > 0 m");
  impl_->truncation_m = truncation_m;
  impl_->objects.reserve(scene.objects.size());
  for (const auto& o : scene.objects) {
    ObjectField f;
    f.object = &o;
    f.T_object_table = o.T_table_object.inverse();
    f.cloud.samples = &o.shape->surfaceSamples();
    f.near_surface_m = 3.0 * o.shape->sampleSpacing();
    impl_->objects.push_back(std::move(f));
    auto& back = impl_->objects.back();
    back.tree =
        std::make_unique<KdTree>(3, back.cloud, nanoflann::KDTreeSingleIndexAdaptorParams(16));
    back.tree->buildIndex();
  }
}

SceneDistanceField::~SceneDistanceField() = default;

float SceneDistanceField::signedDistance(const Vec3& p_table, uint8_t* label) const {
  const double tau = impl_->truncation_m;
  double best = tau;
  if (label) *label = 0;
  for (size_t k = 0; k < impl_->objects.size(); ++k) {
    const ObjectField& f = impl_->objects[k];
    const Vec3 p = f.T_object_table * p_table;
    // Farther than tau outside the bounding sphere: neither inside nor within truncation (the
    // costly inside test is left for the voxels near the object).
    if (p.norm() - f.object->shape->boundingRadius() > tau) continue;
    const bool inside = f.object->shape->containsObject(p);
    size_t index = 0;
    double dist_sq = 0.0;
    f.tree->knnSearch(p.data(), 1, &index, &dist_sq);
    const SurfacePoint& s = (*f.cloud.samples)[index];
    double d = std::sqrt(dist_sq);
    if (d < f.near_surface_m) d = std::abs((p - s.position).dot(s.normal));
    if (inside) {
      if (label) *label = static_cast<uint8_t>(k + 1);
      return static_cast<float>(std::max(-tau, -d));  // objects do not overlap
    }
    best = std::min(best, d);
  }
  return static_cast<float>(best);
}

GroundTruthGrids computeGroundTruth(const Scene& scene, const GridSpec& grid, double truncation_m) {
  if (scene.objects.size() > 254)
    throw std::invalid_argument("at most 254 objects fit the uint8 labels");
  SceneDistanceField field(scene, truncation_m);
  GroundTruthGrids gt;
  gt.tsdf = Grid3<float>(grid, static_cast<float>(truncation_m));
  gt.votes = Grid3<Vec3f>(grid, Vec3f::Zero());
  gt.labels = Grid3<uint8_t>(grid, 0);
  std::vector<Vec3> centroids;
  for (const auto& o : scene.objects) centroids.push_back(o.T_table_object * Vec3::Zero());
  const int r = grid.resolution;
#pragma omp parallel for schedule(dynamic, 1)
  for (int iz = 0; iz < r; ++iz) {
    for (int iy = 0; iy < r; ++iy) {
      for (int ix = 0; ix < r; ++ix) {
        const Vec3 p = grid.voxelCentre(ix, iy, iz);
        uint8_t label = 0;
        const int i = grid.linear(ix, iy, iz);
        gt.tsdf.data[i] = field.signedDistance(p, &label);
        gt.labels.data[i] = label;
        if (label > 0) {
          const Vec3 to_centre = centroids[label - 1] - p;
          const double n = to_centre.norm();
          if (n > 1e-12) gt.votes.data[i] = (to_centre / n).cast<float>();
        }
      }
    }
  }
  return gt;
}

}  // namespace simstack
