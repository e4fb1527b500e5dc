#pragma once
/// @file suction_candidates.h
/// Where a suction cup can hold an object of a superquadric scene: points of the target's
/// surface that a camera sees, approached along the surface normal, where the cup's rim lands
/// close enough to flat to seal (the seal model of Dex-Net 3.0, in spirit), spread over the
/// surface by farthest-point sampling.

#include <cstdint>
#include <limits>
#include <optional>
#include <vector>

#include "simstack/geometry/superquadric.h"
#include "simstack/types.h"

namespace simstack {

struct CandidateConfig {
  double cup_radius_m = 0.015;      ///< radius of the suction cup's rim
  double seal_tolerance_m = 0.003;  ///< how far the rim may lie off the cup's plane and seal
  int rim_points = 16;              ///< points of the rim checked
  int max_candidates = 64;          ///< candidates kept (farthest-point spread)
  int surface_samples = 3000;       ///< points drawn on the target's surface before filtering
  /// The gripper stands along the approach axis: this far out from the contact it must be
  /// above the table (an approach from below the table is impossible).
  double tool_length_m = 0.05;
  uint64_t seed = 0;  ///< surface samples; the same seed gives the same candidates
};

/// A place to hold the target. The cup comes in along -approach and pulls along +approach.
struct SuctionCandidate {
  Vec3 contact_table = Vec3::Zero();
  Vec3 approach_table = Vec3::UnitZ();  ///< unit outward surface normal at the contact
  double rim_deviation_m = 0.0;         ///< largest distance of the rim from the cup's plane
  double seal_score = 1.0;              ///< 1 - rim_deviation / seal_tolerance, in [0, 1]
  /// The camera measured the surface under the cup and it seals there (measuredSeal): the
  /// approach is the measured surface's normal. False: judged on the superquadric alone.
  bool measured = false;
};

/// What the depth points measured on a target say of a cup placed at a contact.
struct MeasuredSeal {
  bool seen = false;           ///< the points cover the middle of the cup's footprint
  bool seals = false;          ///< ... and the rim's zone, on one plane within the seal tolerance
  Vec3 normal = Vec3::Zero();  ///< that plane's normal, on the side of the approach
  Vec3 centre = Vec3::Zero();  ///< a point of the plane
  double deviation_m = std::numeric_limits<double>::infinity();  ///< worst sector's offset
};

/// The seal judged on `measured_table` (depth points on the target, table frame), of the points
/// near the approach axis through `contact` (within its radius along it). Seen: at least six
/// lie within half the cup's radius of the axis. Their plane (refitted on the points under the
/// cup near it) is the surface the cup lands on; at each of 16 points of the rim, the measured
/// points within 0.4 radii of it must exist (no hole, no edge with nothing of the target beyond
/// it, nothing in front) and their mean offset from the plane must lie within the seal
/// tolerance (a mean, so that the sensor's noise on single points does not break a flat face's
/// seal while a bend or an edge still does).
MeasuredSeal measuredSeal(const Points3& measured_table, const Vec3& contact, const Vec3& approach,
                          const CandidateConfig& config);

/// Whether the camera at `camera` (table frame) saw past `contact`, a point of the estimated
/// surface with outward `normal`: at least three of `measured_table` (depth points on the
/// target) lie on its line of sight through the contact (within a third of `cup_radius_m` of
/// it), further than `cup_radius_m` beyond the contact and deeper than `cup_radius_m` inside
/// the surface's tangent plane there, and none lies at the contact (within a third of
/// `cup_radius_m` along the line). The estimate puts a surface where the camera looked through:
/// a cup's mouth, a bowl's inside. False where the line of sight meets the surface at more than
/// 70 degrees from its normal (it runs along the face, whose own points lie beyond the contact).
bool seenThrough(const Points3& measured_table, const Vec3& contact, const Vec3& normal,
                 const Vec3& camera, double cup_radius_m);

/// The suction tool's pose at a candidate, as a motion planner takes it (MoveIt's convention:
/// the tool's z along its approach): origin at the contact, z along -approach_table (into the
/// surface), x the table's x projected onto the contact plane (its y where x is within 10
/// degrees of the normal), y = z x x.
Transform toolPose(const SuctionCandidate& candidate);

/// The pre-grasp pose: `tool` moved `distance_m` back along its own -z (out of the surface),
/// same orientation. Throws std::invalid_argument for a negative or non-finite distance.
Transform pregraspPose(const Transform& tool, double distance_m);

struct CandidateSet {
  std::vector<SuctionCandidate> candidates;
  int surface_samples = 0;  ///< drawn on the target (the 78 at the centre of mass too)
  int visible = 0;          ///< of them seen by a camera
  int reachable = 0;        ///< of those, approachable from above the table
  int sealable = 0;         ///< of those, where the rim seals (on the superquadric and, where
                            ///< the camera measured the surface, on the measured points)
  int measured = 0;         ///< of those, on surface the camera measured
  int seen_through = 0;     ///< sealable ones dropped where the camera saw past the estimate
};

/// The five virtual cameras of the paper's section 4.3: one above the scene's centre and four
/// around it at 45 degrees elevation, `distance_m` from the centre.
std::vector<Vec3> defaultCameraPositions(const std::vector<SuperquadricShape>& scene,
                                         double distance_m = 1.0);

/// Where the line origin + t direction (t >= 0) first enters `sq`, if it does within
/// `max_distance_m` (table frame). Exact for the convex superquadrics (exponents >= 1): the
/// inside-outside function is convex along any line.
std::optional<Vec3> enterSuperquadric(const SuperquadricShape& sq, const Vec3& origin,
                                      const Vec3& direction, double max_distance_m);

/// The rim's largest distance from the plane of the cup (through the contact, normal to the
/// approach axis) once projected onto `sq` along the axis; infinity when part of the rim lands
/// deeper than `limit_m` (or twice the cup's radius) or misses the object (the cup overhangs
/// an edge).
double rimDeviation(const SuperquadricShape& sq, const Vec3& contact_table,
                    const Vec3& approach_table, double cup_radius_m, int rim_points,
                    double limit_m = std::numeric_limits<double>::infinity());

/// Candidates on scene[target] seen from any of `camera_positions` (table frame; the other
/// objects and the table occlude): where the pull passes through the centre of mass or one or two
/// cups' radii from it (the six ends of the target's axes, four points around each at one radius
/// and eight at two), kept first, then random surface samples spread by farthest-point sampling.
/// With `measured_table` (depth points on the target): a candidate on measured surface must seal
/// there too (measuredSeal) and takes its normal; with `measured_from`, the position of the one
/// camera that measured them all (above the table), a candidate on no measured surface where
/// that camera saw past the estimate's surface is none (seenThrough; counted in `seen_through`).
/// Throws std::invalid_argument for a bad target or config.
CandidateSet suctionCandidates(const std::vector<SuperquadricShape>& scene, int target,
                               const std::vector<Vec3>& camera_positions,
                               const CandidateConfig& config, const Points3& measured_table = {},
                               const std::optional<Vec3>& measured_from = std::nullopt);

}  // namespace simstack
