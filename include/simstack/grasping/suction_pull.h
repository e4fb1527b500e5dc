#pragma once
/// @file suction_pull.h
/// One suction pull simulated in Bullet on a superquadric scene: the cup holds the target at
/// the contact, moves out along the approach axis, then holds while the scene settles; what
/// the other objects did is measured against the same scene left alone for the same time.

#include <vector>

#include "simstack/geometry/superquadric.h"
#include "simstack/physics/physics_world.h"
#include "simstack/types.h"

namespace simstack {

struct PullConfig {
  double pull_distance_m = 0.10;
  double pull_speed_mps = 0.20;
  double ramp_s = 0.05;         ///< the cup accelerates to pull_speed over this time
  double settle_s = 0.25;       ///< held still after the pull while the others settle
  double max_force_n = 30.0;    ///< the seal breaks above this force...
  double cup_radius_m = 0.015;  ///< ...or above max_force x cup radius of moment (peeling)
  /// The cup's compliance: the held object's natural frequency on it (PhysicsWorld::attachCup);
  /// at most 0.25 / (2 pi timestep), 9.55 Hz at 240 Hz, the most Bullet's spring simulates.
  double cup_stiffness_hz = 9.5;
  /// Consecutive steps over the limits that break the seal: one step's impulse spike at an
  /// impact is not a pull the seal feels.
  int break_steps = 3;
  double topple_rad = 30.0 * M_PI / 180.0;  ///< an object turned further has toppled
  /// An estimated scene is not exactly at rest (objects overlap or float by millimetres): it
  /// settles first, for at most this long, and every run starts from the settled state.
  double presettle_s = 1.0;
  PhysicsConfig physics = pullPhysics();
  /// Longest pull (distance / speed, simulated s): beyond it a request mixes up its units.
  static constexpr double kMaxPullS = 60.0;

  /// The generator's physics (friction 1, rolling friction 0.01) with sleeping and cached
  /// friction directions on: objects at rest stay put (true piles left alone move under 2 mm over
  /// a pull; docs/experiments.md); every overlap resolved by split impulse, so that an estimate's
  /// overlapping objects are pushed apart, not shot apart. Density 200 kg/m^3, that of packaged
  /// household goods (a cereal box is about 100, a full can 1000): what the cup must lift, unlike
  /// the stability test, depends on it.
  static PhysicsConfig pullPhysics();
  /// Throws std::invalid_argument naming the first bad value.
  void validate() const;
  /// Physics steps of the pull and of the hold after it.
  int pullSteps() const;
  int settleSteps() const;
};

/// What a pull did to the scene, relative to the scene left alone (translations of the
/// centres, rotations as angles).
struct PullOutcome {
  double mean_displacement_m = 0.0;  ///< over the other objects (the paper's score)
  double max_displacement_m = 0.0;
  double max_rotation_rad = 0.0;
  int toppled = 0;            ///< other objects turned beyond topple_rad
  bool cup_held = true;       ///< the seal held to the end
  bool target_freed = false;  ///< held, and touching no other object at the end
  double peak_force_n = 0.0;  ///< largest force the seal carried
  /// Largest share of the seal's limit used while it held: max of force / max_force_n and
  /// moment / (max_force_n x cup_radius_m). Near 1, a slightly heavier object breaks it; above
  /// 1 only in spikes shorter than break_steps.
  double peak_load = 0.0;
  double target_lift_m = 0.0;  ///< the target's rise (its centre's z) at the end
  /// A failed pull: the seal broke and the target was not freed. Ranked last.
  bool failed() const { return !cup_held; }
};

/// How far the scene moves by itself over a pull's duration, from its settled state.
struct SceneDrift {
  double mean_displacement_m = 0.0;
  double max_displacement_m = 0.0;
  double presettle_displacement_m = 0.0;  ///< largest centre motion while settling first
  bool settled = true;                    ///< came to rest within presettle_s
  /// Settling moved an object further than this: the scene the pulls start from is not the one
  /// given (objects that overlap, float or stand in the table).
  static constexpr double kMovedWhileSettling_m = 0.005;
};

/// A scene's bodies, built once and simulated many times (each run in a fresh world, so runs
/// are independent and deterministic). Thread-safe: run pulls from several threads.
/// The lowest point of the scene's surfaces: z in the table frame, metres (infinity for an
/// empty scene). A pile resting on the table has it near 0; the simulation's table is at z = 0,
/// so a scene far above it falls before any pull, and one below it stands in the table.
double sceneBottom(const std::vector<SuperquadricShape>& scene);

class PullSimulator {
 public:
  /// Throws std::invalid_argument for a bad config or shape. The order of `scene` changes
  /// nothing simulated: objects are indexed as in it.
  PullSimulator(const std::vector<SuperquadricShape>& scene, const PullConfig& config);

  const SceneDrift& drift() const { return drift_; }

  /// Pulls `target` (an index into the scene given) at `contact_table` (of the settled scene)
  /// along `approach_table`.
  PullOutcome pull(int target, const Vec3& contact_table, const Vec3& approach_table) const;
  /// The same for a contact and approach given on the scene as perceived: both move with the
  /// target into the settled scene first.
  PullOutcome pullPerceived(int target, const Vec3& contact_table,
                            const Vec3& approach_table) const;

 private:
  std::unique_ptr<PhysicsWorld> world(const std::vector<Transform>& poses) const;

  /// Index into the simulated order of the given scene's object `target`; throws when out of
  /// range.
  int slot(int target) const;

  PullConfig config_;
  std::vector<int> slot_;  ///< of each object of the given scene, its index as simulated
  std::vector<SuperquadricShape> scene_;  ///< in the simulated order
  std::vector<std::vector<Vec3>> hulls_;
  std::vector<double> volumes_;
  std::vector<Transform> settled_;  ///< after presettling
  std::vector<Transform> alone_;    ///< settled, then left alone for a pull's duration
  SceneDrift drift_;
};

}  // namespace simstack
