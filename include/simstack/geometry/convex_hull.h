#pragma once
/// @file convex_hull.h
/// Convex hull of a point set as half-spaces, for a fast inside test of (nearly) convex meshes.

#include <vector>

#include "simstack/types.h"

namespace simstack {

class ConvexHull {
 public:
  /// Builds the hull of `points` (Bullet's btConvexHullComputer). Throws std::invalid_argument
  /// when the points span no volume.
  explicit ConvexHull(const std::vector<Vec3>& points);
  /// True when p lies inside every face plane (within `tolerance_m`).
  bool contains(const Vec3& p, double tolerance_m = 0.0) const;
  /// The hull's vertices.
  const std::vector<Vec3>& vertices() const { return vertices_; }
  /// Face planes (n, d) with outward unit normal n and n.p + d = 0 on the face.
  const std::vector<Eigen::Vector4d>& planes() const { return planes_; }

 private:
  std::vector<Vec3> vertices_;
  std::vector<Eigen::Vector4d> planes_;
};

}  // namespace simstack
