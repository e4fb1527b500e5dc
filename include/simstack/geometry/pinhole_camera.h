#pragma once
/// @file pinhole_camera.h
/// Pinhole camera in the ROS optical frame (x right, y down, z forward), no distortion.

#include <string>

#include "simstack/types.h"

namespace simstack {

struct PinholeCamera {
  int width = 640;
  int height = 480;
  double fx = 525.0;
  double fy = 525.0;
  double cx = 319.5;
  double cy = 239.5;
  /// A window (ROI) of a larger image whose own camera was checked: its principal point may lie
  /// outside the window and its field of view may be narrow.
  bool window = false;

  /// Throws std::invalid_argument naming the bad value: zero/negative focal length or size,
  /// non-finite parameters, and (but for a window) a principal point outside the middle half
  /// of the image or a focal length whose field of view is outside 2-175 degrees (normalized
  /// intrinsics, or another image size's).
  void validate() const;
  /// Camera-frame point of pixel (u, v) at depth z (z along the optical axis, metres).
  Vec3 backproject(double u, double v, double depth_m) const {
    return {(u - cx) * depth_m / fx, (v - cy) * depth_m / fy, depth_m};
  }
  /// Pixel coordinates of a camera-frame point; false when behind the camera.
  bool project(const Vec3& p_camera, double* u, double* v) const {
    if (p_camera.z() <= 1e-9) return false;
    *u = fx * p_camera.x() / p_camera.z() + cx;
    *v = fy * p_camera.y() / p_camera.z() + cy;
    return true;
  }
  /// Ray direction through pixel (u, v), scaled so that its z component is 1.
  Vec3 ray(double u, double v) const { return {(u - cx) / fx, (v - cy) / fy, 1.0}; }
};

/// The pinhole model of a 640x480 Kinect (fx = fy = 525, principal point at the centre) scaled to
/// `width` x `height`.
PinholeCamera scaledKinect(int width, int height);

/// Camera pose whose optical axis points from `eye_table` to `target_table`, with the image's
/// "up" as close as possible to the table's +z. Returns T_table_camera.
Transform lookAt(const Vec3& eye_table, const Vec3& target_table);

}  // namespace simstack
