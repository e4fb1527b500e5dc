#pragma once
/// @file grasp_ranking.h
/// Suction grasps for one target of a superquadric scene, ranked by how little the rest of the
/// pile moves when the target is pulled out (the SIMstack paper's section 4.3), over one or
/// more scene hypotheses (the perception's latent samples): each candidate is simulated in
/// each hypothesis and ranked by its mean and its worst case over them.

#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "simstack/grasping/suction_candidates.h"
#include "simstack/grasping/suction_pull.h"

namespace simstack {

/// Copies of the scene each candidate is also pulled in, each object moved, turned and resized
/// at random by about what an estimate is off (normal draws, these standard deviations; the
/// defaults are `fc`'s estimate errors on the synthetic test piles, robust deviations): a
/// grasp that holds only in the estimate as it is ranks below one that holds in them too.
struct PerturbationConfig {
  int copies = 0;              ///< 0: none
  double position_m = 0.0127;  ///< across the table (x, y)
  double rotation_deg = 7.6;   ///< about a random axis
  double scale_share = 0.146;  ///< of each semi-axis
  uint64_t seed = 0;           ///< the same seed gives the same copies
  /// Throws std::invalid_argument naming the field.
  void validate() const;
};

/// The copies of `scene` as PerturbationConfig draws them (objects in the same order; each
/// lifted, if need be, so that it does not reach below the table).
std::vector<std::vector<SuperquadricShape>> perturbedCopies(
    const std::vector<SuperquadricShape>& scene, const PerturbationConfig& config);

struct GraspRankingConfig {
  CandidateConfig candidates;
  PullConfig pull;
  PerturbationConfig perturbation;  ///< copies of hypothesis 0 pulled in too
  /// Threads simulating candidates (0: all cores). The ranking does not depend on it.
  int threads = 1;
  /// A hypothesis's object matches the target when their centres are this close (metres),
  /// or within the target's largest semi-axis, whichever is larger.
  double match_distance_m = 0.05;
};

/// One candidate and what its pull did in each hypothesis.
struct RankedGrasp {
  SuctionCandidate candidate;         ///< in hypothesis 0 (the scene the robot will act on)
  std::vector<PullOutcome> outcomes;  ///< per hypothesis used
  double mean_displacement_m = 0.0;   ///< mean over hypotheses of the others' mean displacement
  double worst_displacement_m = 0.0;  ///< largest over hypotheses of the same
  double max_displacement_m = 0.0;    ///< largest single object's displacement in any hypothesis
  double mean_toppled = 0.0;          ///< toppled objects, mean over hypotheses
  double failed_share = 0.0;          ///< hypotheses where the seal broke
  double freed_share = 0.0;           ///< hypotheses where the target came free
  double peak_load = 0.0;             ///< largest PullOutcome::peak_load over hypotheses
  /// Share of the perturbed copies in which the seal held (NaN when none were pulled in).
  double copies_held_share = std::numeric_limits<double>::quiet_NaN();
  /// Distance of the pull's line (through the contact along the approach) from the target's
  /// centre of mass in hypothesis 0: the arm of the moment that peels the cup.
  double com_offset_m = 0.0;
  /// What the ranking sorts by after failures, freeing, topples and how upward the pull is
  /// (rankedBefore): (mean + worst) / 2 of the mean displacement, which is the paper's score
  /// for one hypothesis, compared in whole millimetres (finer differences are within the
  /// physics' own drift); ties go to the pull passing nearer the centre of mass (whole
  /// millimetres), then to the lower peak load: the grasps with more margin against a wrong
  /// mass or centre.
  double score_m = 0.0;

  /// The seal held through the pull in every hypothesis pulled in.
  bool held() const { return !outcomes.empty() && failed_share == 0.0; }
  /// The target came free in every hypothesis pulled in.
  bool freed() const { return !outcomes.empty() && freed_share == 1.0; }
};

/// What a grasp's pulls did: held and freed the target in every hypothesis; held in every one
/// but did not always free it; or the seal broke in some.
enum class GraspOutcome { kHeldAndFreed, kHeld, kFailed };
GraspOutcome graspOutcome(const RankedGrasp& grasp);
/// The colour every picture and marker of a grasp takes (r, g, b in [0, 1]): green held and
/// freed, yellow held, red the seal broke.
Vec3 outcomeColour(GraspOutcome outcome);

struct GraspRanking {
  std::vector<RankedGrasp> grasps;   ///< best first
  CandidateSet candidates;           ///< the candidate search (counts) on hypothesis 0
  std::vector<SceneDrift> baseline;  ///< per hypothesis used: the scene left alone
  std::vector<int> hypotheses;       ///< indices of the hypotheses used (0 first); the
                                     ///< perturbed copies follow, numbered on from the last
  int pulls = 0;                     ///< pulls simulated
  bool stopped = false;  ///< the progress callback asked to stop: grasps holds what finished
  /// What the caller should know, notes joined by "; " (empty when all is well): hypotheses
  /// left out, no sealable surface, objects that moved more than
  /// SceneDrift::kMovedWhileSettling_m while settling, no grasp that held (in any hypothesis, or
  /// in every one), no grasp that freed the target, no grasp that both held and freed it in
  /// every hypothesis (outcomeNote).
  std::string message;
};

/// The index of the object of `scene` that matches `reference` (nearest centre within the
/// match distance), or -1.
int matchObject(const SuperquadricShape& reference, const std::vector<SuperquadricShape>& scene,
                double match_distance_m);

/// The candidate as a robot would execute it on another estimate of its target (a further
/// hypothesis, or the true object): the same approach line, onto `target`. std::nullopt when
/// the line misses it.
std::optional<Vec3> carryCandidate(const SuctionCandidate& candidate,
                                   const SuperquadricShape& target, double tool_length_m);

/// Executes a grasp chosen on some estimate of scene[target] in `simulator`'s scene (built
/// from `scene`): carried onto the target along its approach line, then pulled. A miss is a
/// failed pull (cup_held false).
PullOutcome executeGrasp(const PullSimulator& simulator,
                         const std::vector<SuperquadricShape>& scene, int target,
                         const SuctionCandidate& candidate, double tool_length_m);

/// Ranks grasps on hypotheses[0][target]. The target of each further hypothesis is its object
/// matching it (hypotheses without one are left out, said in the message); a candidate is
/// carried into a hypothesis along its approach axis onto that hypothesis's target (a miss is
/// a failed pull there). `camera_positions` empty: the five default cameras. Throws
/// std::invalid_argument for a bad target, shape or config, or a camera position or measured
/// point that is not finite.
/// Called after each pull with the pulls done, their total and the best grasp among the
/// candidates whose every pull is done (nullptr before the first); from the threads simulating,
/// one call at a time. Returning false stops the ranking: pulls not yet begun are not
/// simulated, so it ends within one pull per thread.
using RankingProgress = std::function<bool(int done, int total, const RankedGrasp* best)>;

/// What the caller should know of ranked grasps as a whole ("" when nothing): that none held
/// (in any hypothesis, or in all of them), that none freed the target, or that none both held
/// and freed it in every hypothesis. Each grasp's shares say it too, but a list ranked best
/// first reads as if its first grasp were a good one. rankGrasps adds it to its message.
std::string outcomeNote(const std::vector<RankedGrasp>& grasps);

/// Appends `note` to a ranking's or a request's message; notes are joined by "; ".
void addNote(std::string* message, const std::string& note);

/// Whether grasp `a` ranks before grasp `b`: fewer seal failures, then more often freed, fewer
/// topples, a seal measured on the camera's points before one judged on the superquadric alone, a
/// more upward pull (the approach's z in tenths), less displacement (whole millimetres), a pull
/// nearer the centre of mass (whole millimetres), lower peak load.
bool rankedBefore(const RankedGrasp& a, const RankedGrasp& b);

/// `measured_target`: depth points measured on hypotheses[0][target] (table frame), where the
/// seal is judged and the approach taken (suctionCandidates); empty: the superquadric alone.
/// `measured_from`: the position of the one camera that measured them (table frame), where
/// known: no candidate where it saw past the estimate's surface.
GraspRanking rankGrasps(const std::vector<std::vector<SuperquadricShape>>& hypotheses, int target,
                        const std::vector<Vec3>& camera_positions, const GraspRankingConfig& config,
                        const RankingProgress& progress = {}, const Points3& measured_target = {},
                        const std::optional<Vec3>& measured_from = std::nullopt);

/// Objects in a scene the grasp simulation accepts at most (a pile's labels are 8-bit).
constexpr size_t kMaxGraspSceneObjects = 255;
/// Measured points of the target the seals are judged on; more (a request's cloud, or the
/// perception's fused views of a large target: a 1280x720 view at its pixel stride of 2 holds
/// 230,400 points) are thinned to every k-th.
constexpr size_t kMaxMeasuredPoints = 500000;
/// The target's measured points the seal tests read: `measured` itself, or every k-th of more
/// than kMaxMeasuredPoints, kept in `thinned` and said in `message` (addNote).
const Points3& sealPoints(const Points3& measured, Points3* thinned, std::string* message);

/// Farthest an object of a simulated scene may lie from the table frame's origin (m).
constexpr double kMaxGraspSceneReachM = 100.0;

/// Empty when no id of `ids` appears twice, else which one does.
std::string checkIds(const std::vector<uint32_t>& ids);

/// A scene that the grasp simulation accepts: at most kMaxGraspSceneObjects objects, finite
/// poses with unit rotations within kMaxGraspSceneReachM of the origin, semi-axes in (0, 1] m
/// and exponents in [1, 200], and `ids` (one per object, when given) unique. Empty string when
/// valid, else what is wrong, naming the object by its id in `ids`, else by its index.
std::string checkScene(const std::vector<SuperquadricShape>& scene,
                       const std::vector<uint32_t>& ids = {});

}  // namespace simstack
