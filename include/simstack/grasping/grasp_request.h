#pragma once
/// @file grasp_request.h
/// What a request to rank grasps may ask, checked once for every caller (the grasp service, its
/// action and simstack_rank_grasps): the pull's bounds, the number of candidates, the scenes'
/// validity, that the scene rests on the simulation's table, the hypotheses used, how old a
/// scene may be. The callers add only what their own form of the request needs (ids, frames).

#include <algorithm>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "simstack/grasping/grasp_ranking.h"

namespace simstack {

/// The bounds a request is held to.
struct GraspPolicy {
  int max_candidates = 64;            ///< candidates ranked when a request asks for 0
  int max_candidates_limit = 256;     ///< requests for more are clamped to this (and told)
  double max_pull_distance_m = 0.5;   ///< longer pulls are refused
  double max_pull_speed_mps = 2.0;    ///< faster pulls are refused
  double max_pregrasp_m = 1.0;        ///< longest pre-grasp stand-off a request may ask for
  double pregrasp_distance_m = 0.05;  ///< the stand-off of requests that ask for 0
  /// A scene older than this is refused (the camera or the perception stopped); 0: any age.
  double max_scene_age_s = 10.0;
  /// How far the scene's lowest surface may lie from z = 0 of its table frame, where the
  /// simulation's table is, for the scene to rest on it; further below is refused (a wrong
  /// table pose: its objects would stand in the table), further above is said (they fall).
  double table_gap_m = 0.05;
  static constexpr int kMaxHypotheses = 64;  ///< hypotheses simulated at most
  /// Hypotheses a request for `asked` uses at most (0: all, up to kMaxHypotheses).
  static int hypothesesFor(uint32_t asked) {
    return asked == 0 ? kMaxHypotheses
                      : static_cast<int>(std::min<uint32_t>(asked, kMaxHypotheses));
  }
  /// Throws std::invalid_argument naming the field.
  void validate() const;
};

/// A request, in the table frame.
struct GraspRequest {
  /// The scene, then its further hypotheses (as many as the caller has).
  std::vector<std::vector<SuperquadricShape>> scenes;
  int target = 0;  ///< index of the target in scenes[0]
  double pull_distance_m = 0.1;
  double pull_speed_mps = 0.2;
  uint32_t candidates = 0;           ///< 0: GraspPolicy::max_candidates
  uint32_t hypotheses = 0;           ///< scenes used, the first counted; 0: all of them
  double pregrasp_m = 0.0;           ///< 0: GraspPolicy::pregrasp_distance_m
  std::optional<Vec3> camera_table;  ///< candidates are what this camera sees (else five views)
  /// The ids of scenes[0]'s objects, which messages name them by (empty: their indices).
  std::vector<uint32_t> ids;
};

/// A request checked and turned into a ranking's input.
struct PreparedGrasps {
  std::vector<std::vector<SuperquadricShape>> scenes;  ///< the hypotheses to rank in
  GraspRankingConfig config;  ///< the caller's, with the request's pull and candidates
  std::vector<Vec3> cameras;  ///< empty: the default five
  double pregrasp_m = 0.05;
  std::string notes;  ///< what the caller should be told, "; "-joined (empty when nothing)
};

/// A refusal of what the request itself asks (a pull, stand-off or camera out of bounds, a
/// target not in the scene), as against the scene it is about: the caller can tell the two
/// apart (the grasp service's BAD_REQUEST and BAD_SCENE).
class BadGraspRequest : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// The request's own numbers against `policy` (pull distance and speed, pre-grasp stand-off):
/// throws BadGraspRequest saying which and the allowed range. prepareGrasps runs it
/// first; a caller may run it before the work of converting the scene.
void checkGraspBounds(const GraspRequest& request, const GraspPolicy& policy);

/// Checks `request` against `policy` and prepares the ranking on `base`'s cup, seal, physics and
/// threads. Throws saying what is wrong and the allowed range: BadGraspRequest for a pull
/// distance or speed, a pre-grasp stand-off or a camera out of bounds, or an unknown target;
/// std::invalid_argument for a scene or hypothesis checkScene refuses (the scene's objects
/// named by their ids, a hypothesis's by index) or a scene below the table.
PreparedGrasps prepareGrasps(const GraspRequest& request, const GraspRankingConfig& base,
                             const GraspPolicy& policy);

/// How far from every object's surface a point naming the target may lie (m).
constexpr double kMaxTargetPointM = 0.1;

/// The object of `scene` a point `p` (in the scene's frame) names: of the objects containing
/// it, the one it lies deepest in (the lowest inside-outside value); else the object whose
/// surface is nearest (Euclidean, to within a millimetre). -1 when no surface
/// lies within kMaxTargetPointM; `distance_m` (if given) is the chosen or nearest object's
/// distance, 0 inside.
int objectAtPoint(const std::vector<SuperquadricShape>& scene, const Vec3& p,
                  double* distance_m = nullptr);

/// Measured points further than this outside the target's superquadric are not its (m).
constexpr double kMeasuredNearShapeM = 0.02;
/// At least this share of the points measured on a target must lie near its superquadric.
constexpr double kMeasuredNearShare = 0.25;

/// Why `points` (table frame), said to be measured on `target`, are not its: "" when there are
/// none or at least kMeasuredNearShare of them lie inside it or within kMeasuredNearShapeM of its
/// surface (a cup's inner wall lies inside the superquadric that closes it; a point just above
/// a flat book's edge is near it); else "K of N points ...". At most 2000 points are judged,
/// evenly through the list. Another scene's cloud, or one labelled otherwise, would judge the
/// seals on a surface the cup never meets.
std::string measuredOffTarget(const Points3& points, const SuperquadricShape& target);

/// A number as a person writes it in a request's message: 0.1, 2, nan (std::to_string gives
/// 0.100000 and -nan).
std::string number(double v);

/// Why a scene `age_s` old is refused under `max_age_s` (0: any age), "" when it is not. A
/// stamp ahead of now (a replayed bag that loops) is never stale.
std::string staleScene(double age_s, double max_age_s);

}  // namespace simstack
