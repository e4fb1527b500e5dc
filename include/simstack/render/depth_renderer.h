#pragma once
/// @file depth_renderer.h
/// Depth and instance images of a scene by ray casting with Embree. The table is a finite
/// square at z = 0 (instance 0) as a real sensor sees it; objects are instances 1..K.

#include <cstdint>
#include <memory>
#include <random>
#include <string>

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/scene/scene.h"

namespace simstack {

/// The sensors whose noise the tools can imitate (SensorNoiseConfig's presets).
enum class SensorModel { kinect, realsense };
/// "kinect" or "realsense"; anything else throws std::invalid_argument naming the choices.
SensorModel parseSensorModel(const std::string& name);
const char* sensorModelName(SensorModel model);

/// Sensor imperfections. The defaults are a clean sensor.
struct SensorNoiseConfig {
  /// Axial noise sigma(z) = sigma_base_m + sigma_quadratic_per_m * (z - 0.4 m)^2
  ///   + sigma_stereo_per_m * z^2: the first two the Kinect model of Nguyen et al. (2012) with
  /// 0.0012 and 0.0019, the last a stereo camera's (subpixel disparity error times
  /// z^2 / (focal length x baseline)); 0 disables each.
  double sigma_base_m = 0.0;
  double sigma_quadratic_per_m = 0.0;
  double sigma_stereo_per_m = 0.0;
  /// A second eye this far along the camera's +x axis (a stereo pair's other imager or a
  /// structured-light projector) must see the surface too, else the pixel is missing: the
  /// band of holes beside every depth edge. 0 disables.
  double shadow_baseline_m = 0.0;
  /// Surfaces nearer than this return nothing (a stereo camera's minimum range); 0 disables.
  double min_depth_m = 0.0;
  /// Probability that a pixel is missing (depth 0).
  double dropout_probability = 0.0;
  /// Pixels seen at a larger angle between ray and surface normal are missing (degrees;
  /// >= 90 disables).
  double max_incidence_deg = 90.0;
  uint64_t seed = 0;

  /// The Kinect-like preset used by the tools' --noise flag.
  static SensorNoiseConfig kinect(uint64_t seed);
  /// A RealSense D435-like preset at 1280x720 (--sensor realsense): stereo noise of a
  /// 0.08 px disparity error at 640 px focal length and 50 mm baseline, the right imager's
  /// shadows, 0.28 m minimum range, more speckle holes than the Kinect's.
  static SensorNoiseConfig realsense(uint64_t seed);
  static SensorNoiseConfig preset(SensorModel model, uint64_t seed);
};

struct RenderConfig {
  double table_half_size_m = 0.6;  ///< the table is the square |x|, |y| <= this, at z = 0
  bool with_table = true;
  double max_range_m = 10.0;
};

/// What render() produces. `normals_table` is filled only when asked for.
struct RenderResult {
  DepthImage depth;            ///< metres along the optical axis, 0 = no return
  InstanceImage instances;     ///< 0 table, k object k, kNoSurface none
  Image<Vec3f> normals_table;  ///< unit normals facing the camera, table frame
};

/// Builds the acceleration structure once; render() is const and thread-safe.
class DepthRenderer {
 public:
  /// std::invalid_argument for a scene of more objects than the instance image tells apart
  /// (254).
  DepthRenderer(const Scene& scene, const RenderConfig& config = RenderConfig());
  /// One mesh as instance 1, no table (for visibility tests of arbitrary surfaces).
  explicit DepthRenderer(const TriangleMesh& mesh, double max_range_m = 10.0);
  ~DepthRenderer();
  DepthRenderer(const DepthRenderer&) = delete;
  DepthRenderer& operator=(const DepthRenderer&) = delete;

  RenderResult render(const PinholeCamera& camera, const Transform& T_table_camera,
                      const SensorNoiseConfig& noise = SensorNoiseConfig(),
                      bool with_normals = false) const;
  /// Distance along a table-frame ray to the first surface (inf when none); `instance`
  /// receives what was hit (kNoSurface when none), `triangle` the index of the triangle hit in
  /// its mesh (-1 when none).
  double castRay(const Vec3& origin_table, const Vec3& direction_table, int* instance = nullptr,
                 int* triangle = nullptr) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace simstack
