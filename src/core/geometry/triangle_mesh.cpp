#include "simstack/geometry/triangle_mesh.h"

#include <algorithm>

namespace simstack {

double TriangleMesh::area() const {
  double a = 0.0;
  for (size_t i = 0; i < triangles.size(); ++i) a += triangleArea(i);
  return a;
}

double TriangleMesh::volume() const {
  double v = 0.0;
  for (const auto& t : triangles) {
    v += vertices[t[0]].dot(vertices[t[1]].cross(vertices[t[2]])) / 6.0;
  }
  return v;
}

Vec3 TriangleMesh::volumeCentroid() const {
  // Each triangle with the origin spans a signed tetrahedron; weight its centroid by volume.
  double v_total = 0.0;
  Vec3 moment = Vec3::Zero();
  for (const auto& t : triangles) {
    const Vec3& a = vertices[t[0]];
    const Vec3& b = vertices[t[1]];
    const Vec3& c = vertices[t[2]];
    const double v = a.dot(b.cross(c)) / 6.0;
    v_total += v;
    moment += v * (a + b + c) / 4.0;
  }
  return std::abs(v_total) > 0.0 ? Vec3(moment / v_total) : Vec3::Zero();
}

bool TriangleMesh::bounds(Vec3* min, Vec3* max) const {
  if (vertices.empty()) return false;
  *min = vertices.front();
  *max = vertices.front();
  for (const auto& v : vertices) {
    *min = min->cwiseMin(v);
    *max = max->cwiseMax(v);
  }
  return true;
}

TriangleMesh TriangleMesh::transformed(const Transform& T) const {
  TriangleMesh out;
  out.triangles = triangles;
  out.vertices.reserve(vertices.size());
  for (const auto& v : vertices) out.vertices.push_back(T * v);
  return out;
}

void TriangleMesh::append(const TriangleMesh& other) {
  const int offset = static_cast<int>(vertices.size());
  vertices.insert(vertices.end(), other.vertices.begin(), other.vertices.end());
  for (const auto& t : other.triangles) triangles.push_back(t + Eigen::Vector3i::Constant(offset));
}

std::vector<SurfacePoint> TriangleMesh::sampleSurface(int count, std::mt19937_64& rng) const {
  std::vector<SurfacePoint> out;
  if (triangles.empty() || count <= 0) return out;
  std::vector<double> cumulative(triangles.size());
  double total = 0.0;
  for (size_t i = 0; i < triangles.size(); ++i) {
    total += triangleArea(i);
    cumulative[i] = total;
  }
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  out.reserve(count);
  // Stratified along the cumulative area: one sample per 1/count of it. Neighbouring triangles
  // are neighbours in the lattice meshes used here, so gaps stay near the mean spacing
  // (independent draws leave Poisson gaps several spacings wide).
  for (int k = 0; k < count; ++k) {
    const double pick = (k + uni(rng)) / count * total;
    const size_t i = std::min<size_t>(
        std::lower_bound(cumulative.begin(), cumulative.end(), pick) - cumulative.begin(),
        triangles.size() - 1);
    const auto& t = triangles[i];
    double r1 = std::sqrt(uni(rng));
    double r2 = uni(rng);
    const Vec3& a = vertices[t[0]];
    const Vec3& b = vertices[t[1]];
    const Vec3& c = vertices[t[2]];
    Vec3 n = (b - a).cross(c - a);
    const double len = n.norm();
    out.push_back({(1.0 - r1) * a + r1 * (1.0 - r2) * b + r1 * r2 * c,
                   len > 0.0 ? Vec3(n / len) : Vec3::UnitZ()});
  }
  return out;
}

}  // namespace simstack
