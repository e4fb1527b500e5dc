#pragma once
/// @file grasp_evaluation.h
/// What the grasp ranking is worth: on generated piles, grasps are chosen on each method's
/// estimated scene, then executed in the true pile (Bullet), and the other objects'
/// displacement is measured. Choosers on the same targets: the ranking on the estimate, a
/// random sealable candidate of the estimate, the top-most candidate (what a simple picker
/// does), and the ranking on the true pile itself (the oracle).

#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "simstack/grasping/grasp_ranking.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/offline/eval/evaluator.h"

namespace simstack {

struct GraspEvaluationOptions {
  int scenes = 0;                            ///< the first N scenes (0 = all)
  uint64_t seed = 7;                         ///< viewpoints, sensor noise and the random chooser
  int width = 640, height = 480;             ///< rendered view (a scaled Kinect)
  bool noise = true;                         ///< sensor noise in the rendered view
  SensorModel sensor = SensorModel::kinect;  ///< whose noise (SensorNoiseConfig::preset)
  GraspRankingConfig ranking;                ///< candidates, cup and pull (shared by every chooser)
  /// Hypotheses the ranking simulates each candidate in: the estimate, then up to H - 1 of a
  /// method's further decomposed hypotheses (MethodEstimate::further_superquadrics).
  int hypotheses = 1;
  /// The ranking on an estimate judges seals on the depth points the method measured on the
  /// target (MethodEstimate::measured_surfaces), as the grasp service does; false: on the
  /// superquadrics alone.
  bool measured_seal = true;
  /// A grasp executed in the true pile must also seal on the true surface where its approach
  /// line meets it (the rim within the seal tolerance of the cup's plane, as on the estimate);
  /// false: only the pull's force and moment can break it.
  bool true_seal = false;
  /// Adds the chooser "best in truth": every candidate the ranking kept is executed in the true
  /// pile and the best outcome taken (by the ranking's order). It bounds what any ranking of
  /// the same candidates could do: its gap to "ranked" is the ranking's, to the oracle the
  /// candidates'.
  bool best_in_truth = false;
};

/// How far a method's estimate of a target is off the true object: what the ranking's perturbed
/// copies (PerturbationConfig) should draw their jitter from.
struct EstimateError {
  Vec3 centre_m = Vec3::Zero();  ///< estimate's centre minus the truth's, table frame
  /// Smallest angle turning the truth's axes onto the estimate's, over the 24 turns that map
  /// a box's axes onto themselves (a superquadric looks the same after them, up to its sizes).
  double rotation_deg = 0.0;
  Vec3 scale_ratio = Vec3::Ones();  ///< sorted semi-axes, estimate over truth (smallest first)
};

/// The error of `estimate` as an estimate of `truth`.
EstimateError estimateError(const SuperquadricShape& estimate, const SuperquadricShape& truth);

/// One candidate of a ranking on an estimate, as the ranking judged it and as its pull went in
/// the true pile.
struct CandidateTrial {
  RankedGrasp estimate;
  PullOutcome truth;
};

/// One pick: a chooser's grasp on a method's scene, executed in the true pile.
struct PickResult {
  int scene = 0, target = 0;
  std::string method;   ///< "truth" for the oracle, else the estimating method's name
  std::string chooser;  ///< "ranked", "random", "top-most", "best in truth"
  bool found = true;    ///< the method has an object matching the target
  bool grasped = true;  ///< a sealable candidate existed on its estimate of the target
  PullOutcome outcome;  ///< in the true pile (a failed pull when not found or not grasped)
  EstimateError error;  ///< of the method's object matching the target (when found)
  /// "best in truth" only: every candidate the ranking kept, in its order.
  std::vector<CandidateTrial> trials;
};

/// Every true object of the first scenes as a target, one random view per scene. Scenes must
/// be superquadric piles (std::invalid_argument otherwise).
std::vector<PickResult> evaluateGrasps(const DatasetReader& reader,
                                       const std::vector<EvaluatedMethod*>& methods,
                                       const GraspEvaluationOptions& options,
                                       const std::function<void(int, int)>& progress = {});

/// Per method and chooser: picks, mean and median displacement of the others (mm), the share
/// of picks that toppled something, freed the target, failed.
nlohmann::json graspSummary(const std::vector<PickResult>& picks);
/// That summary as a GitHub markdown table.
std::string graspSummaryTable(const nlohmann::json& summary);

/// Per method, the error of its estimates of the targets it found: the centre's across the
/// table (per axis) and in height, the rotation, and the semi-axes' (the ratio's distance from
/// 1); each as a root mean square and as the deviation of a normal with the same median |error|
/// (robust to estimates off by a whole object): the standard deviations PerturbationConfig
/// takes.
nlohmann::json estimateErrorSummary(const std::vector<PickResult>& picks);

}  // namespace simstack
