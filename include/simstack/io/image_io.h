#pragma once
/// @file image_io.h
/// Reading and writing depth, masks and pictures (PNG via OpenCV), and view descriptions (YAML).
/// Every function throws std::runtime_error naming the file on failure.

#include <optional>
#include <string>
#include <vector>

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/types.h"

namespace simstack {

/// 16-bit PNG in millimetres (0 = missing), the format of ROS 16UC1 depth.
void writeDepthPng(const std::string& path, const DepthImage& depth);
/// Largest side of a depth image the readers accept (pixels).
constexpr int kMaxDepthImageSide = 4096;
/// Farthest a view description may place its camera from the table's origin (m).
constexpr double kMaxCameraDistanceM = 100.0;

/// A 16-bit depth image's unit when nothing says otherwise: the millimetre.
constexpr double kDefaultDepthScaleM = 0.001;

/// Reads a one-channel 16-bit PNG (units of `depth_scale_m`, else of `default_scale_m`) or
/// 32-bit float TIFF in metres. Throws std::runtime_error naming the file for anything else
/// (colour images included), for a side over kMaxDepthImageSide, and for `depth_scale_m` given
/// with a float image (its unit is the metre; `default_scale_m`, a view file's, is not read).
DepthImage readDepthImage(const std::string& path,
                          std::optional<double> depth_scale_m = std::nullopt,
                          double default_scale_m = kDefaultDepthScaleM);
/// 8-bit PNG of an instance mask.
void writeMaskPng(const std::string& path, const InstanceImage& mask);
/// Reads one; std::runtime_error naming the file for anything but a one-channel 8-bit image and
/// for a side over kMaxDepthImageSide (checked from the header, before decoding).
InstanceImage readMaskPng(const std::string& path);
/// 16-bit PNG of pixel labels: 0 none, k + 1 instance k (`instances` -1 none, k >= 0).
/// std::invalid_argument for an instance above 65534.
void writeLabelsPng(const std::string& path, const Image<int>& instances);
/// Depth as a colour picture (near = warm, missing = black) for people to look at.
void writeDepthPicture(const std::string& path, const DepthImage& depth);
/// Shaded picture: one colour per instance, Lambertian light from the camera.
void writeShadedPicture(const std::string& path, const InstanceImage& instances,
                        const Image<Vec3f>& normals_table, const Transform& T_table_camera);
/// An arrow drawn over a picture (table frame), with an optional label at its tail.
struct PictureArrow {
  Vec3 tail_table = Vec3::Zero(), tip_table = Vec3::Zero();
  Eigen::Vector3f colour{0.0f, 1.0f, 0.0f};  ///< RGB in [0, 1]
  std::string label;
};
/// The shaded picture with arrows projected through `camera` (posed by T_table_camera).
void writeShadedPicture(const std::string& path, const InstanceImage& instances,
                        const Image<Vec3f>& normals_table, const Transform& T_table_camera,
                        const PinholeCamera& camera, const std::vector<PictureArrow>& arrows);
/// RGB colour of instance k (0 = table) used by every picture and marker.
Eigen::Vector3f instanceColour(int k);

/// A rendered view: intrinsics and camera pose, as written beside the PNGs by --views.
struct ViewDescription {
  PinholeCamera camera;
  Transform T_table_camera = Transform::Identity();
  /// Metres per unit of the 16-bit depth PNG the file describes; absent: millimetres.
  std::optional<double> depth_scale_m;
};
void writeViewYaml(const std::string& path, const ViewDescription& view);
ViewDescription readViewYaml(const std::string& path);

}  // namespace simstack
