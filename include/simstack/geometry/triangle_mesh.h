#pragma once
/// @file triangle_mesh.h
/// Indexed triangle mesh (metres) with the few measurements the package needs.

#include <random>
#include <vector>

#include "simstack/types.h"

namespace simstack {

/// A point on a surface with its outward unit normal, both in the same frame.
struct SurfacePoint {
  Vec3 position;
  Vec3 normal;
};

/// Indexed triangle mesh. Triangles are counter-clockwise seen from outside (outward normals).
/// Not thread-safe for concurrent mutation; const methods may be called concurrently.
struct TriangleMesh {
  std::vector<Vec3> vertices;
  std::vector<Eigen::Vector3i> triangles;

  bool empty() const { return triangles.empty(); }
  /// Total surface area in m^2.
  double area() const;
  /// Area of triangle `i` in m^2.
  double triangleArea(size_t i) const {
    const auto& t = triangles[i];
    return 0.5 * (vertices[t[1]] - vertices[t[0]]).cross(vertices[t[2]] - vertices[t[0]]).norm();
  }
  /// Enclosed volume in m^3 (divergence theorem; exact for closed, consistently oriented meshes).
  double volume() const;
  /// Centroid of the enclosed solid (uniform density).
  Vec3 volumeCentroid() const;
  /// Axis-aligned bounds of the vertices; returns false for an empty mesh.
  bool bounds(Vec3* min, Vec3* max) const;
  /// The mesh with every vertex mapped through T.
  TriangleMesh transformed(const Transform& T) const;
  /// Appends another mesh (indices are offset).
  void append(const TriangleMesh& other);
  /// `count` points distributed by area (stratified along the triangle order), with face normals.
  std::vector<SurfacePoint> sampleSurface(int count, std::mt19937_64& rng) const;
};

}  // namespace simstack
