#pragma once
/// @file types.h
/// Eigen types shared by the whole package. Frames are carried in variable names
/// (`T_table_camera` maps camera-frame points into the table frame, `p_table` is a point in
/// the table frame). Units: metres, radians, seconds.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <vector>

namespace simstack {

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;
using Vec3f = Eigen::Vector3f;
using Vec3i = Eigen::Vector3i;
using Mat3 = Eigen::Matrix3d;
using Quat = Eigen::Quaterniond;
using Transform = Eigen::Isometry3d;

/// Points as a plain vector of Eigen vectors (3 doubles, no alignment requirement).
using Points3 = std::vector<Vec3>;

}  // namespace simstack
