#pragma once
/// @file train_config.h
/// How the trainer runs, and the training file that holds it beside the model's config.

#include <cstdint>
#include <string>

#include "simstack/model/cvae_config.h"

namespace simstack {

/// How the trainer runs (simstack_train --config FILE.yaml holds both, under `model:` and
/// `training:`).
struct TrainConfig {
  int batch_size = 8;
  double learning_rate = 1e-3;  ///< Adam step size at step 0
  double final_learning_rate =
      1e-4;              ///< reached at `steps` along a cosine (= learning_rate: constant)
  int64_t steps = 6000;  ///< optimiser steps
  int threads = 2;       ///< torch intra-op threads
  uint64_t seed = 1;
  int checkpoint_every = 200;  ///< steps between checkpoints
  int validate_every = 500;    ///< steps between validations
  /// The last scenes of the dataset, never trained on, each seen from `validation_views`
  /// random viewpoints. Piles differ more than the protocol does: per view the IoU spreads by
  /// about 0.08, so 32 views leave the mean's standard error at 0.014-0.016 (docs/results.md,
  /// "Validation and test").
  int validation_scenes = 128;
  int validation_views = 2;
  int validation_samples = 8;  ///< latent codes per validation view (hypotheses S)
  int image_width = 320;       ///< rendered training views (intrinsics scale with it)
  int image_height = 240;
  bool sensor_noise = true;  ///< sensor noise in training views
  /// Whose noise: "kinect" or "realsense" (SensorNoiseConfig's presets).
  std::string sensor_model = "kinect";
  /// Share of training views from above (ViewpointRange::overhead(), as on pick stations); the
  /// rest in the paper's ranges.
  double overhead_share = 0.0;
  /// Warm start: a model file whose parameters of the same name and shape start this run (the
  /// others keep their random initialisation); empty: all random. Not read when resuming.
  std::string init_from;

  void validate() const;
  std::string toYaml() const;
  static TrainConfig fromYaml(const std::string& text);
};

/// Reads `model:` and `training:` of a YAML file; throws std::runtime_error naming the file.
void loadTrainingYaml(const std::string& path, CvaeConfig* model, TrainConfig* training);

}  // namespace simstack
