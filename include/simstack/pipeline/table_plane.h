#pragma once
/// @file table_plane.h
/// The table frame from a depth image alone (RANSAC plane, PCL), as the paper does on real
/// data: z along the plane normal towards the camera, x along the camera's x axis projected on
/// the plane, origin below the camera centre.
///
/// Without a workspace, the table is the largest plane. With a bounded workspace (a box in the
/// frame the plane defines), the largest plane is not always the table: the top of a robot's
/// base near the camera can hold more pixels, but the table lies behind it. So the table is
/// the largest of `max_planes` planes with (almost) nothing seen behind it within the
/// workspace's x/y footprint, estimated again from the points inside the workspace alone.
/// A mask on the depth (DepthView::mask) restricts the points before all this.

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/pipeline/workspace.h"
#include "simstack/types.h"

namespace simstack {

struct TablePlaneConfig {
  double inlier_distance_m = 0.01;  ///< RANSAC threshold
  int max_iterations = 1000;
  int pixel_stride = 4;            ///< every n-th pixel along both image axes
  double max_depth_m = 3.0;        ///< farther points are ignored
  double min_inlier_share = 0.15;  ///< of the valid sampled points; less means "no table"
  int max_planes = 3;              ///< with a bounded workspace: planes tried, largest first
  /// With a bounded workspace: a plane with more than this share of the points in the
  /// workspace's footprint farther than 2 x inlier_distance_m behind it is not the table.
  double max_behind_share = 0.05;
  /// Throws std::invalid_argument naming the field out of range.
  void validate() const;
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
                              const TablePlaneConfig& config = TablePlaneConfig(),
                              const WorkspaceConfig& workspace = WorkspaceConfig());

}  // namespace simstack
