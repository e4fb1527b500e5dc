#pragma once
/// @file conversions.h
/// ROS message <-> core type conversions (free functions, no algorithm). Each throws
/// std::invalid_argument with a message fit for a throttled ROS warning.

#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"

namespace simstack {

/// Depth in metres from a 16UC1 (mm) or 32FC1 (m) image; 0 and NaN stay missing (0).
/// Rejects other encodings, big-endian data and a step or data size that does not fit.
DepthImage depthFromImage(const sensor_msgs::Image& msg);

/// Pinhole intrinsics from a CameraInfo (the rectified P matrix, K when P is zero).
/// Rejects zero focal lengths and empty sizes.
PinholeCamera cameraFromInfo(const sensor_msgs::CameraInfo& msg);

}  // namespace simstack
