#include "simstack/grasping/grasp_request.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "simstack/fitting/superquadric_fit.h"

namespace simstack {

std::string number(double v) {
  if (std::isnan(v)) return "nan";
  std::ostringstream out;
  out << v;
  return out.str();
}

namespace {

bool positiveFinite(double v) { return std::isfinite(v) && v > 0.0; }

/// The scene's lowest surface against the simulation's table at z = 0: throws when it lies
/// below by more than the gap, says so when above.
void checkTable(const std::vector<SuperquadricShape>& scene, double gap_m, std::string* notes) {
  const double bottom = sceneBottom(scene);
  if (std::abs(bottom) <= gap_m) return;
  const std::string where = "the scene's lowest surface is at z = " + number(bottom) +
                            " m in its table frame, where the simulation's table is at z = 0: ";
  const std::string frame =
      " (the table frame: z up, the table at z = 0; the scene's table pose places it in the "
      "scene's frame)";
  if (bottom < -gap_m)
    throw std::invalid_argument(where + "its objects would stand in the table" + frame);
  addNote(notes, where + "its objects fall before any pull" + frame);
}

}  // namespace

void GraspPolicy::validate() const {
  if (max_candidates < 1) throw std::invalid_argument("max_candidates must be >= 1");
  if (max_candidates_limit < max_candidates)
    throw std::invalid_argument("max_candidates_limit must be >= max_candidates");
  if (!positiveFinite(max_pull_distance_m))
    throw std::invalid_argument("max_pull_distance_m must be a positive number");
  if (!positiveFinite(max_pull_speed_mps))
    throw std::invalid_argument("max_pull_speed_mps must be a positive number");
  if (!positiveFinite(max_pregrasp_m))
    throw std::invalid_argument("max_pregrasp_m must be a positive number");
  if (!(pregrasp_distance_m >= 0.0 && pregrasp_distance_m <= max_pregrasp_m))
    throw std::invalid_argument("pregrasp_distance_m must lie in [0, " + number(max_pregrasp_m) +
                                "] m");
  if (!(max_scene_age_s >= 0.0) || !std::isfinite(max_scene_age_s))
    throw std::invalid_argument("max_scene_age_s must be >= 0 (0: any age)");
  if (!(table_gap_m >= 0.0) || !std::isfinite(table_gap_m))
    throw std::invalid_argument("table_gap_m must be >= 0");
}

void checkGraspBounds(const GraspRequest& request, const GraspPolicy& policy) {
  if (!positiveFinite(request.pull_distance_m) ||
      request.pull_distance_m > policy.max_pull_distance_m)
    throw BadGraspRequest("pull_distance_m must lie in (0, " + number(policy.max_pull_distance_m) +
                          "] m, not " + number(request.pull_distance_m) + " (e.g. 0.1)");
  if (!positiveFinite(request.pull_speed_mps) || request.pull_speed_mps > policy.max_pull_speed_mps)
    throw BadGraspRequest("pull_speed_mps must lie in (0, " + number(policy.max_pull_speed_mps) +
                          "] m/s, not " + number(request.pull_speed_mps) + " (e.g. 0.2)");
  if (request.pull_distance_m / request.pull_speed_mps > PullConfig::kMaxPullS)
    throw BadGraspRequest("the pull of " + number(request.pull_distance_m) + " m at " +
                          number(request.pull_speed_mps) + " m/s takes over " +
                          number(PullConfig::kMaxPullS) + " s: are the units m and m/s?");
  if (!std::isfinite(request.pregrasp_m) || request.pregrasp_m < 0.0 ||
      request.pregrasp_m > policy.max_pregrasp_m)
    throw BadGraspRequest("pregrasp_distance_m must lie in [0, " + number(policy.max_pregrasp_m) +
                          "] m, not " + number(request.pregrasp_m) + " (0: the server's " +
                          number(policy.pregrasp_distance_m) + ")");
}

PreparedGrasps prepareGrasps(const GraspRequest& request, const GraspRankingConfig& base,
                             const GraspPolicy& policy) {
  checkGraspBounds(request, policy);
  if (request.scenes.empty() || request.scenes[0].empty())
    throw std::invalid_argument("the scene has no objects");
  if (request.target < 0 || request.target >= static_cast<int>(request.scenes[0].size()))
    throw BadGraspRequest("target " + std::to_string(request.target) + " is not an object of the " +
                          std::to_string(request.scenes[0].size()) + "-object scene");
  if (request.camera_table && !request.camera_table->allFinite())
    throw BadGraspRequest("camera_pose.position is not finite");
  // A camera sees the pile from above: one at or below the table is a pose in another frame,
  // or one left unset (all zeros), not a target with no surface in sight.
  if (request.camera_table && !(request.camera_table->z() > 0.0))
    throw BadGraspRequest("camera_pose.position is " + number(request.camera_table->z() + 0.0) +
                          " m above the table plane, where no camera sees the pile: give "
                          "the camera's position in the scene's frame (it is unset?)");
  PreparedGrasps out;
  const size_t wanted = GraspPolicy::hypothesesFor(request.hypotheses);
  out.scenes.assign(request.scenes.begin(),
                    request.scenes.begin() + std::min(wanted, request.scenes.size()));
  for (size_t h = 0; h < out.scenes.size(); ++h)
    if (const std::string why =
            checkScene(out.scenes[h], h == 0 ? request.ids : std::vector<uint32_t>());
        !why.empty())
      throw std::invalid_argument(
          (h == 0 ? std::string("the scene's ")
                  : "hypothesis " + std::to_string(h) + " (of the scene's hypotheses), ") +
          why);
  checkTable(out.scenes[0], policy.table_gap_m, &out.notes);
  if (request.hypotheses > 0 && out.scenes.size() < wanted)
    addNote(&out.notes, std::to_string(request.hypotheses) +
                            " hypotheses asked for, the scene has " +
                            std::to_string(out.scenes.size()));
  out.config = base;
  int count = request.candidates == 0
                  ? policy.max_candidates
                  : static_cast<int>(std::min<uint32_t>(request.candidates, 1u << 20));
  if (count > policy.max_candidates_limit) {
    addNote(&out.notes, std::to_string(request.candidates) +
                            " candidates asked for, clamped to max_candidates_limit " +
                            std::to_string(policy.max_candidates_limit));
    count = policy.max_candidates_limit;
  }
  out.config.candidates.max_candidates = count;
  out.config.pull.pull_distance_m = request.pull_distance_m;
  out.config.pull.pull_speed_mps = request.pull_speed_mps;
  if (request.camera_table) out.cameras.push_back(*request.camera_table);
  out.pregrasp_m = request.pregrasp_m > 0.0 ? request.pregrasp_m : policy.pregrasp_distance_m;
  return out;
}

namespace {

/// Distance (m) from `q`, an object-frame point outside `sq`, to its surface: the nearest of
/// `vertices` (a fine mesh of sq), then foot-point steps (onto the tangent plane, back onto the
/// surface along the ray from the centre); the least of these and of the ray's own surface
/// point. Each is a surface point, so the figure never understates.
double distanceOutside(const SuperquadricShape& sq, const Vec3& q,
                       const std::vector<Vec3>& vertices) {
  double best = q.norm() - sq.surfacePointAlong(q).norm();
  Vec3 x = Vec3::Zero();
  for (const Vec3& v : vertices)
    if ((v - q).norm() < best) best = (v - q).norm(), x = v;
  if (x.isZero()) return best;
  for (int i = 0; i < 8; ++i) {
    const Vec3 n = sq.normalObject(x).normalized();
    const Vec3 on_plane = q - (q - x).dot(n) * n;
    if (!on_plane.allFinite() || on_plane.isZero()) break;
    x = sq.surfacePointAlong(on_plane);
    best = std::min(best, (x - q).norm());
  }
  return best;
}

/// The mesh distanceOutside starts from.
std::vector<Vec3> distanceMesh(const SuperquadricShape& sq) { return sq.meshObject(24).vertices; }

/// Measured points judged at most: a share needs no more (every n-th, in order).
constexpr size_t kMeasuredJudged = 2000;

}  // namespace

int objectAtPoint(const std::vector<SuperquadricShape>& scene, const Vec3& p, double* distance_m) {
  int best = -1;
  double best_rank = INFINITY, best_distance = INFINITY;
  for (size_t k = 0; k < scene.size(); ++k) {
    const Vec3 q = scene[k].T_table_object.inverse() * p;
    const double f = scene[k].insideOutsideObject(q);
    const double d = f < 1.0 ? 0.0 : distanceOutside(scene[k], q, distanceMesh(scene[k]));
    const double rank = f < 1.0 ? f - 1.0 : d;  // inside (below 0) before outside
    if (rank < best_rank) best_rank = rank, best_distance = d, best = static_cast<int>(k);
  }
  if (distance_m) *distance_m = best_distance;
  return best_distance <= kMaxTargetPointM ? best : -1;
}

std::string measuredOffTarget(const Points3& points, const SuperquadricShape& target) {
  if (points.empty()) return {};
  const size_t stride = (points.size() + kMeasuredJudged - 1) / kMeasuredJudged;
  const Transform T_object_table = target.T_table_object.inverse();
  std::vector<Vec3> mesh;                       // made for the first point the ray leaves undecided
  const double radius = target.scale_m.norm();  // the box of the semi-axes holds the shape
  size_t judged = 0, near = 0;
  for (size_t i = 0; i < points.size(); i += stride, ++judged) {
    // Along the ray from the centre first: never under the true distance, and cheap.
    if (surfaceDistance(target, points[i]) <= kMeasuredNearShapeM) {
      ++near;
      continue;
    }
    const Vec3 q = T_object_table * points[i];
    // Beyond the bounding sphere by more than the limit (another object's cloud): far, no search.
    if (q.norm() - radius > kMeasuredNearShapeM) continue;
    if (mesh.empty()) mesh = distanceMesh(target);
    if (distanceOutside(target, q, mesh) <= kMeasuredNearShapeM) ++near;
  }
  if (near >= kMeasuredNearShare * static_cast<double>(judged)) return {};
  return std::to_string(near) + " of " + std::to_string(judged) +
         (stride > 1 ? " points judged (1 in " + std::to_string(stride) + ")" : " points") +
         " lie inside or within " + number(kMeasuredNearShapeM * 100.0) + " cm of its superquadric";
}

std::string staleScene(double age_s, double max_age_s) {
  if (max_age_s <= 0.0 || !(age_s > max_age_s)) return {};
  return number(age_s) + " s old (max_scene_age_s " + number(max_age_s) + "): " +
         (age_s > 86400.0 ? "a day or more apart: is one of this node and the scene's publisher "
                            "on simulated time (/use_sim_time) and the other not? "
                          : "is the perception still running? ") +
         "Rank on a fresh frame; raise ~max_scene_age_s (0: any age) only where nothing moves "
         "the pile meanwhile";
}

}  // namespace simstack
