#include "simstack/geometry/convex_hull.h"

#include <LinearMath/btConvexHullComputer.h>

#include <stdexcept>

namespace simstack {

ConvexHull::ConvexHull(const std::vector<Vec3>& points) {
  if (points.size() < 4) throw std::invalid_argument("convex hull needs at least 4 points");
  std::vector<double> coords;
  coords.reserve(points.size() * 3);
  for (const auto& p : points) coords.insert(coords.end(), {p.x(), p.y(), p.z()});
  btConvexHullComputer hull;
  hull.compute(coords.data(), 3 * sizeof(double), static_cast<int>(points.size()), 0.0, 0.0);
  for (int i = 0; i < hull.vertices.size(); ++i) {
    const btVector3& v = hull.vertices[i];
    vertices_.emplace_back(v.x(), v.y(), v.z());
  }
  Vec3 centre = Vec3::Zero();
  for (const auto& v : vertices_) centre += v;
  if (!vertices_.empty()) centre /= static_cast<double>(vertices_.size());
  for (int f = 0; f < hull.faces.size(); ++f) {
    // Walk the face's edge loop and take the Newell normal, robust for polygons.
    const btConvexHullComputer::Edge* start = &hull.edges[hull.faces[f]];
    const btConvexHullComputer::Edge* e = start;
    std::vector<Vec3> loop;
    do {
      loop.push_back(vertices_[e->getSourceVertex()]);
      e = e->getNextEdgeOfFace();
    } while (e != start && loop.size() < 1000);
    Vec3 n = Vec3::Zero();
    Vec3 c = Vec3::Zero();
    for (size_t i = 0; i < loop.size(); ++i) {
      const Vec3& a = loop[i];
      const Vec3& b = loop[(i + 1) % loop.size()];
      n += a.cross(b);
      c += a;
    }
    if (n.norm() < 1e-15) continue;
    n.normalize();
    c /= static_cast<double>(loop.size());
    if (n.dot(c - centre) < 0.0) n = -n;  // orientation-independent: point away from inside
    planes_.emplace_back(n.x(), n.y(), n.z(), -n.dot(c));
  }
  if (planes_.size() < 4)
    throw std::invalid_argument("convex hull of the points is degenerate (flat or empty)");
}

bool ConvexHull::contains(const Vec3& p, double tolerance_m) const {
  for (const auto& pl : planes_) {
    if (pl.head<3>().dot(p) + pl[3] > tolerance_m) return false;
  }
  return true;
}

}  // namespace simstack
