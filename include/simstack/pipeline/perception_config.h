#pragma once
/// @file perception_config.h
/// Every parameter of ScenePerception in one plain struct, and its YAML form
/// (config/perception.yaml), shared by the tools and the ROS nodes.

#include <string>

#include "simstack/fitting/superquadric_fit.h"
#include "simstack/instances/hough_voting.h"
#include "simstack/instances/surface_segments.h"
#include "simstack/pipeline/table_plane.h"

namespace simstack {

struct PerceptionConfig {
  std::string model_path;           ///< a model written by simstack_train (required)
  int samples = 3;                  ///< S latent samples per frame
  bool zero_code_first = true;      ///< hypothesis 0 is the mean scene (z = 0)
  uint64_t seed = 0;                ///< latent codes; the same seed gives the same hypotheses
  int decompose_samples = 1;        ///< hypotheses split into instances and fitted (the first ones)
  int points_per_instance = 1000;   ///< mesh samples handed to the fitter
  int min_instance_points = 30;     ///< instances with a smaller surface are dropped
  bool joint_refinement = true;     ///< eqs. 7-9 after the per-instance fits
  double min_pile_height_m = 0.01;  ///< depth points lower than this are table
  int threads = 2;
  HoughConfig hough;
  SurfaceSegmentConfig segments;  ///< the split along the observed surface's convex patches
  FitConfig fit;
  TablePlaneConfig table;
};

/// Reads sections `perception:`, `hough:`, `segments:`, `fitting:` and `table:` (absent fields keep
/// their defaults; unknown fields are errors, so that a typo is not silently ignored). A relative
/// `model` path is taken relative to `base_dir` when given. Throws std::runtime_error naming
/// the file and the field.
PerceptionConfig loadPerceptionYaml(const std::string& path, const std::string& base_dir = "");
/// The YAML text of a config (all five sections).
std::string perceptionYaml(const PerceptionConfig& config);

}  // namespace simstack
