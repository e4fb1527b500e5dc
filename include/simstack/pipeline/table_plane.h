#pragma once
/// @file table_plane.h
/// The table frame from a depth image alone (RANSAC plane, PCL), as the paper does on real
/// data: z along the plane normal towards the camera, x along the camera's x axis projected on
/// the plane, origin below the camera centre.

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/types.h"

namespace simstack {

struct TablePlaneConfig {
  double inlier_distance_m = 0.01;  ///< RANSAC threshold
  int max_iterations = 1000;
  int pixel_stride = 4;            ///< every n-th pixel along both image axes
  double max_depth_m = 3.0;        ///< farther points are ignored
  double min_inlier_share = 0.15;  ///< of the valid sampled points; less means "no table"
};

struct TablePlane {
  Transform T_table_camera = Transform::Identity();
  Eigen::Vector4d plane_camera = Eigen::Vector4d::Zero();  ///< n.p + d = 0, n towards camera
  int inliers = 0;
  int points = 0;
};

/// Throws std::runtime_error when the image has too few valid points or no dominant plane,
/// and std::invalid_argument when the image does not match the camera.
TablePlane estimateTablePlane(const DepthImage& depth, const PinholeCamera& camera,
                              const TablePlaneConfig& config = TablePlaneConfig());

}  // namespace simstack
