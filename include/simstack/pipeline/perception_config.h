#pragma once
/// @file perception_config.h
/// Every parameter of ScenePerception in one plain struct, and its YAML forms: the pipeline's
/// settings in config/perception.yaml, and the settings that belong to one model (its sample
/// count and Hough setting) in the `perception:` section of its card, models/<name>.yaml beside
/// models/<name>.pt, read with the model.

#include <string>
#include <vector>

#include "simstack/fitting/superquadric_fit.h"
#include "simstack/instances/hough_voting.h"
#include "simstack/instances/instance_finder.h"  // CrowdedConfig
#include "simstack/instances/surface_instances.h"
#include "simstack/instances/surface_segments.h"
#include "simstack/model/cvae_config.h"  // modelCardPath
#include "simstack/pipeline/table_plane.h"
#include "simstack/pipeline/workspace.h"

namespace simstack {

/// The most latent samples a frame may ask for.
constexpr int kMaxSamples = 64;

/// The scene grid's side. The network works in voxels: a grid of another side shows it the same
/// scene scaled, so small objects seen in a finer grid look as large as the ones it was trained
/// on. The Hough radii (hough.bandwidth_m, crowded.bandwidth_m) and workspace.tile_overlap_m
/// scale with the side; every other length is the world's.
struct GridConfig {
  double side_m = 0.0;  ///< one tile's side (0 = the model's extent_m)
  /// When the first pass's objects look smaller than this to the network (the median over
  /// them of the cube root of their voxels), the frame is perceived again in a finer grid
  /// (0 = off: one pass).
  double object_voxels = 7.0;
  /// ... or when the smallest of them looks smaller than this (0 = only the median; used only
  /// with object_voxels above 0). The first pass's merges make the median object look larger,
  /// so a pile of small neighbours can hide behind it; an object near the grid's resolution
  /// cannot.
  double smallest_object_voxels = 4.5;
  double fine_side_share = 0.625;  ///< ... of this share of the first pass's side
  /// Throws std::invalid_argument naming the field ("grid.side_m ...").
  void validate() const;
};

struct PerceptionConfig {
  std::string model_path;       ///< a model written by simstack_train (required)
  std::string model_card_path;  ///< the card samples and hough came from ("" = defaults)
  /// Where the settings were read (a file, or the node's parameters): named, with the card,
  /// when validatePerceptionConfig refuses a value ("" = built in code).
  std::string source;
  int samples = 3;              ///< S latent samples per frame (model card)
  bool zero_code_first = true;  ///< hypothesis 0 is the mean scene (z = 0)
  uint64_t seed = 0;            ///< latent codes; the same seed gives the same hypotheses
  int decompose_samples = 1;    ///< hypotheses split into instances and fitted (the first ones)
  /// Network passes averaged: the view as seen and turned about the vertical (2: by a half
  /// turn, 4: by every quarter turn) and mirrored (8), each output turned back (1, 2, 4 or 8;
  /// CvaeInference::predict).
  int symmetries = 4;
  int points_per_instance = 1000;  ///< points per instance handed to the fitter
  /// The part of an instance's surface the views saw is represented by their depth points
  /// (measured) instead of samples of the network's mesh (up to a voxel off); the unseen part
  /// keeps the mesh samples.
  bool observed_points = true;
  int min_instance_points = 30;     ///< instances with a smaller surface are dropped
  bool joint_refinement = true;     ///< eqs. 7-9 after the per-instance fits
  double min_pile_height_m = 0.01;  ///< depth points lower than this are table
  double min_depth_m = 0.1;         ///< the sensor's range: depth outside [min, max] is missing
  double max_depth_m = 10.0;
  int threads = 2;  ///< capped at the machine's cores
  /// Given several posed views: Adam steps on the S codes so that the decoded TSDF agrees with
  /// each view's own partial TSDF (the paper's section 4.2, CvaeInference::refine); 0 = off.
  int refine_iterations = 0;
  double refine_learning_rate = 0.3;
  double refine_prior_weight = 1.0;  ///< RefineOptions::prior_weight
  /// Prior draws scored against the views before the fitting, the best `samples` kept
  /// (RefineOptions::starts); more than `samples` chooses codes by the evidence even without
  /// refine_iterations.
  int refine_starts = 0;
  std::string refine_evidence = "sign";  ///< RefineOptions::evidence
  bool refine_on_passes = true;          ///< RefineOptions::fit_on_passes
  /// Given several posed views, the ones the network is conditioned on: "all" (their fused
  /// partial TSDF: the paper's multi-view conditioning) or "first" (the first view alone, the
  /// others reaching the codes only through refine_iterations: the paper's multi-view
  /// optimisation).
  std::string condition_views = "all";
  HoughConfig hough;              ///< the model's (model card)
  SurfaceSegmentConfig segments;  ///< the split along the observed surface's convex patches
  SurfaceInstanceConfig surface_instances;  ///< objects found on the measured surface alone
  CrowdedConfig crowded;                    ///< the second split of crowded piles
  /// The fitter's settings, but without its one-sided solve: on the pipeline's instances
  /// (network surfaces cut where objects touch, the classical baseline's visible points) it
  /// does not pay (docs/experiments.md, "Fitting").
  FitConfig fit = [] {
    FitConfig f;
    f.one_sided_volume_exponent = 0.5;
    return f;
  }();
  TablePlaneConfig table;
  WorkspaceConfig workspace;  ///< where to look, and the tiles covering it
  GridConfig grid;            ///< the scene grid's side
};

/// The sections of a perception config (maps at its top level), in file order.
const std::vector<std::string>& perceptionConfigSections();
/// The pipeline's own fields, at the top level of a perception config (model, samples, ...).
const std::vector<std::string>& perceptionConfigFields();

struct RefineOptions;  // simstack/model/cvae_inference.h
/// The code fitting's options (CvaeInference::refine) of a perception config.
RefineOptions refineOptions(const PerceptionConfig& config);

/// Throws std::invalid_argument naming the first field out of its range, and the config's
/// source and model card. `latent`: the model has a latent code; without one every sample is
/// the same scene, so the sample counts only need to be in range (ScenePerception takes them
/// as 1). ScenePerception checks every config it is given; a tool that lays options over a
/// loaded config checks the result.
void validatePerceptionConfig(const PerceptionConfig& config, bool latent = false);

/// Reads a perception config: the pipeline's own fields at the top level (model, symmetries,
/// ...) and the sections of perceptionConfigSections() (`hough:`, `segments:`,
/// `surface_instances:`, `crowded:`, `fitting:`, `table:`, `workspace:`, `grid:`); absent fields
/// keep their defaults, unknown fields are errors, so that a typo is not silently ignored.
/// `model_path`, when given, replaces the file's `model`. A relative model path is taken
/// relative to `base_dir` when given. Then the model's card is read (applyModelCard), and last
/// the file's own `samples` and `hough:` section, which override the card's when present
/// (normally they are absent). Throws std::runtime_error naming the file and the field; values
/// out of range are left to validatePerceptionConfig (`source` names the file).
PerceptionConfig loadPerceptionYaml(const std::string& path, const std::string& base_dir = "",
                                    const std::string& model_path = "");

/// The same from YAML text (`source` names it in errors), as the ROS node reads its parameters.
PerceptionConfig parsePerceptionYaml(const std::string& text, const std::string& source,
                                     const std::string& base_dir = "",
                                     const std::string& model_path = "");

/// The config file at `defaults_path` with `overrides` (YAML text of the same form, `source`
/// naming it in errors) laid over it field by field: a section given in both keeps the file's
/// fields the overrides leave out. What the ROS node reads: the package's config with the
/// node's parameters on top.
PerceptionConfig overlayPerceptionYaml(const std::string& defaults_path,
                                       const std::string& overrides, const std::string& source,
                                       const std::string& base_dir);

/// Reads `samples` and `hough` from the `perception:` section of the card of
/// `config->model_path` into `config`. Returns the card's path, or "" when the model has no card
/// or the card no such section (the values in `config` stay). Throws std::runtime_error naming
/// the card and the field for an unknown or malformed field.
std::string applyModelCard(PerceptionConfig* config);
/// A model card's `perception:` section (YAML text) for these settings.
std::string modelCardPerceptionYaml(int samples, const HoughConfig& hough);
/// The YAML text of a config (every field and section).
std::string perceptionYaml(const PerceptionConfig& config);

}  // namespace simstack
