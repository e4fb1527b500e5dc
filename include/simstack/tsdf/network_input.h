#pragma once
/// @file network_input.h
/// How a depth view is framed for the network, the same way in training and at inference:
/// where the scene grid is centred (on the visible pile) and how the partial TSDF becomes the
/// network's input channels.

#include <vector>

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/voxel_grid.h"

namespace simstack {

/// x/y centre (table frame, metres) of the visible pile: the centroid of depth points more than
/// `min_height_m` above the table and within `radius_m` of `near_xy`; `near_xy` when there are
/// none. Training passes the stored grid's centre as `near_xy`.
Vec2 visiblePileCentre(const DepthImage& depth, const PinholeCamera& camera,
                       const Transform& T_table_camera, const Vec2& near_xy, double radius_m,
                       double min_height_m = 0.01);

/// Network input channels [2][z][y][x]: partial TSDF / tau clamped to [-1, 1], and observed
/// (weight > 0) as 0 / 1.
std::vector<float> partialChannels(const Grid3<float>& tsdf_m, const Grid3<float>& weight,
                                   double truncation_m);

}  // namespace simstack
