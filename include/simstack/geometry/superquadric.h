#pragma once
/// @file superquadric.h
/// The superquadric of the SIMstack paper, eq. 4:
///   f(x, y, z) = |x/a1|^r + |y/a2|^s + |z/a3|^t,  surface f = 1, inside f < 1,
/// in the object frame; `T_table_object` places it in the table frame.

#include <random>
#include <vector>

#include "simstack/geometry/triangle_mesh.h"
#include "simstack/types.h"

namespace simstack {

/// A posed superquadric. (Named SuperquadricShape so that it does not collide with the ROS
/// message simstack::Superquadric, which lives in the same namespace.)
struct SuperquadricShape {
  /// Semi-axes a1, a2, a3 in metres (half the extent along each object axis).
  Vec3 scale_m{0.05, 0.05, 0.05};
  /// Exponents r, s, t (2 = ellipsoid, large = box-like; >= 1 keeps the shape convex).
  Vec3 exponents{2.0, 2.0, 2.0};
  /// Pose: maps object-frame points into the table frame.
  Transform T_table_object = Transform::Identity();

  /// f of eq. 4 for a point in the table frame (< 1 inside, 1 on the surface, > 1 outside).
  double insideOutside(const Vec3& p_table) const;
  /// f of eq. 4 for a point already in the object frame.
  double insideOutsideObject(const Vec3& p_object) const;
  /// True when f(p) < 1.
  bool contains(const Vec3& p_table) const { return insideOutside(p_table) < 1.0; }
  /// The surface point on the ray from the centre through `direction_object` (object frame).
  Vec3 surfacePointAlong(const Vec3& direction_object) const;
  /// Outward unit normal at an object-frame point (gradient of f).
  Vec3 normalObject(const Vec3& p_object) const;
  /// Exact volume in m^3: 8 a1 a2 a3 G(1+1/r) G(1+1/s) G(1+1/t) / G(1+1/r+1/s+1/t).
  double volume() const;
  /// Centroid of the solid in the table frame (the pose origin, by symmetry).
  Vec3 centroid() const { return T_table_object.translation(); }
  /// Closed triangle mesh in the object frame: a cube whose faces carry `subdivisions` x
  /// `subdivisions` cells, projected radially onto the surface (keeps box edges sharp).
  TriangleMesh meshObject(int subdivisions = 24) const;
  /// `count` surface points in the object frame at near-uniform density (area-weighted on a
  /// fine mesh, then projected onto the exact surface), with exact normals.
  std::vector<SurfacePoint> sampleSurfaceObject(int count, std::mt19937_64& rng) const;
};

/// The same solid written with its axes ordered by size, largest first: the semi-axes,
/// exponents and rotation columns are permuted together (and one column negated when needed to
/// keep the rotation proper), and the columns turned so that each one's largest component is
/// positive. Two parameter sets of one solid that differ by an axis permutation or a symmetry
/// flip have the same canonical form (up to axes of equal size).
SuperquadricShape canonicalSuperquadric(const SuperquadricShape& sq);

/// Whether two parameter sets describe the same solid within `tolerance_m`: every point of a
/// fine surface sample of each lies within `tolerance_m` (along the ray from the centre) of the
/// other's surface. Independent of how the axes are numbered.
bool sameSuperquadric(const SuperquadricShape& a, const SuperquadricShape& b, double tolerance_m);

/// The share of the smaller solid's volume that lies inside the other, from `samples` points
/// drawn uniformly inside the smaller one (a fixed random stream: the same shapes give the same
/// share). 0 when their bounding spheres do not meet.
double sharedVolumeShare(const SuperquadricShape& a, const SuperquadricShape& b, int samples = 400);

}  // namespace simstack
