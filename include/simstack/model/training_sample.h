#pragma once
/// @file training_sample.h
/// Network inputs and targets for one rendered view of a dataset scene, built the way
/// inference sees a real frame: the scene grid is re-centred (by whole voxels) on the visible
/// above-table points, as ScenePerception does, and the ground truth is shifted with it.

#include <random>
#include <vector>

#include "simstack/dataset/dataset.h"
#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/model/cvae_config.h"

namespace simstack {

/// x/y centre of the visible pile: the centroid of depth points more than `min_height_m`
/// above the table and within `radius_m` of `near_xy`; `near_xy` when there are none.
Vec2 visiblePileCentre(const DepthImage& depth, const PinholeCamera& camera,
                       const Transform& T_table_camera, const Vec2& near_xy, double radius_m,
                       double min_height_m = 0.01);

/// Network input channels [2][z][y][x]: partial TSDF / tau and observed (weight > 0).
std::vector<float> partialChannels(const Grid3<float>& tsdf_m, const Grid3<float>& weight,
                                   double truncation_m);

struct TrainingSample {
  GridSpec grid;  ///< the re-centred grid the arrays live on
  Transform T_table_camera = Transform::Identity();
  std::vector<float> partial;  ///< [2, R, R, R]
  std::vector<float> tsdf;     ///< [R, R, R], full TSDF / tau
  std::vector<float> votes;    ///< [3, R, R, R]
};

class TrainingSampleBuilder {
 public:
  TrainingSampleBuilder(const CvaeConfig& config, const PinholeCamera& camera, bool sensor_noise);
  /// A random viewpoint in the paper's ranges.
  TrainingSample build(const SceneRecord& record, std::mt19937_64& rng) const;
  /// A given viewpoint.
  TrainingSample build(const SceneRecord& record, const Transform& T_table_camera,
                       uint64_t noise_seed) const;
  const PinholeCamera& camera() const { return camera_; }

 private:
  CvaeConfig config_;
  PinholeCamera camera_;
  bool noise_;
};

/// The pinhole model of a 640x480 Kinect scaled to `width` x `height`.
PinholeCamera scaledKinect(int width, int height);

}  // namespace simstack
