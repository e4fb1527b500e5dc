#pragma once
/// @file classical_baseline.h
/// The classical baseline of docs/design.md section 6: table removal, Euclidean clustering of the
/// visible points (PCL), and the same superquadric fitter as the network pipeline. It sees
/// only the visible surface, which is what it is there to show.

#include <vector>

#include "simstack/fitting/superquadric_fit.h"
#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/voxel_grid.h"

namespace simstack {

struct ClassicalConfig {
  double min_height_m = 0.01;         ///< points lower than this are table
  double cluster_tolerance_m = 0.01;  ///< neighbour distance within a cluster
  int min_cluster_points = 50;
  int pixel_stride = 2;  ///< every n-th pixel along both image axes
  bool joint_refinement = true;
  int threads = 2;
  FitConfig fit;
};

/// Above-table points of the depth image within the x/y box of `crop` (if given), clustered.
/// With `pixels`, also each cluster's pixel indices (v * width + u), point for point.
std::vector<Points3> clusterVisiblePoints(const DepthImage& depth, const PinholeCamera& camera,
                                          const Transform& T_table_camera,
                                          const ClassicalConfig& config,
                                          const GridSpec* crop = nullptr,
                                          std::vector<std::vector<int>>* pixels = nullptr);

/// One superquadric per cluster. With `pixel_instances`, also the cluster of every sampled
/// pixel (-1 elsewhere), numbered as the superquadrics; a cluster whose fit fails is left out
/// of both.
std::vector<SuperquadricShape> classicalBaseline(const DepthImage& depth,
                                                 const PinholeCamera& camera,
                                                 const Transform& T_table_camera,
                                                 const ClassicalConfig& config,
                                                 const GridSpec* crop = nullptr,
                                                 Image<int>* pixel_instances = nullptr);

}  // namespace simstack
