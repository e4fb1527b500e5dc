#pragma once
/// @file training_sample.h
/// Network inputs and targets for one rendered view of a dataset scene, built the way
/// inference sees a real frame: the scene grid is re-centred (by whole voxels) on the visible
/// above-table points, as ScenePerception does, and the ground truth is shifted with it.

#include <random>
#include <vector>

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/model/cvae_config.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/offline/dataset/viewpoints.h"
#include "simstack/render/depth_renderer.h"

namespace simstack {

struct TrainingSample {
  GridSpec grid;  ///< the re-centred grid the arrays live on
  Transform T_table_camera = Transform::Identity();
  std::vector<float> partial;  ///< [2, R, R, R]
  std::vector<float> tsdf;     ///< [R, R, R], full TSDF / tau
  std::vector<float> votes;    ///< [3, R, R, R]
  /// [R, R, R] eq. 2's per-voxel weight (CvaeConfig::vote_boundary_weight); empty when it is 0.
  std::vector<float> vote_weight;
};

/// Eq. 2's per-voxel weights for a label grid ([R, R, R], 0 free, k object k): 1 + `boundary`
/// in a voxel of an object with a voxel of another object at most 2 voxels away in every
/// axis, else 1.
std::vector<float> voteBoundaryWeights(const std::vector<uint8_t>& labels, int resolution,
                                       float boundary);

class TrainingSampleBuilder {
 public:
  /// `overhead_share` of the random viewpoints come from above (ViewpointRange::overhead());
  /// with `sensor_noise`, views have `sensor`'s noise.
  TrainingSampleBuilder(const CvaeConfig& config, const PinholeCamera& camera, bool sensor_noise,
                        double overhead_share = 0.0, SensorModel sensor = SensorModel::kinect);
  /// A random viewpoint in the paper's ranges (or from above, see the constructor).
  TrainingSample build(const SceneRecord& record, std::mt19937_64& rng) const;
  /// A given viewpoint.
  TrainingSample build(const SceneRecord& record, const Transform& T_table_camera,
                       uint64_t noise_seed) const;
  const PinholeCamera& camera() const { return camera_; }

 private:
  CvaeConfig config_;
  PinholeCamera camera_;
  bool noise_;
  double overhead_share_;
  SensorModel sensor_;
};

}  // namespace simstack
