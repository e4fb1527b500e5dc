#pragma once
/// @file physics_world.h
/// A Bullet rigid-body world with the table plane z = 0 and convex objects. Used to settle
/// generated piles, to test the stability of estimated scenes and to simulate suction pulls
/// (a cup holding one object).
/// Not thread-safe; use one world per thread.

#include <functional>
#include <memory>
#include <utility>
#include <vector>

#include "simstack/types.h"

namespace simstack {

struct PhysicsConfig {
  double gravity_mps2 = 9.81;       ///< along -z of the table frame
  double timestep_s = 1.0 / 240.0;  ///< fixed step
  double friction = 0.8;            ///< objects and table
  double rolling_friction = 0.001;  ///< without it rounded shapes never come to rest
  double spinning_friction = 0.001;
  double restitution = 0.0;
  double linear_damping = 0.04;  ///< PyBullet's default, as the paper's generator used
  double angular_damping = 0.04;
  double collision_margin_m = 0.001;  ///< Bullet's 4 cm default is far too big for 5 cm objects
  double density_kgpm3 = 500.0;       ///< uniform density of every object
  double rest_linear_mps = 0.005;     ///< an object below both thresholds is at rest
  double rest_angular_radps = 0.05;
  int rest_steps = 20;  ///< consecutive steps at rest that end settle()
  bool allow_sleeping = true;
  int solver_iterations = 10;  ///< Bullet's default; more reduce creep on slopes
  /// Bullet's split impulse (its default): overlaps deeper than `split_impulse_depth_m` are
  /// pushed apart by a position correction that adds no velocity; shallower ones by a velocity
  /// (Baumgarte) correction, which gives an object overlapping another by centimetres a speed
  /// of metres per second.
  bool split_impulse = true;
  /// Bullet's 4 cm by default; 0 resolves every overlap without adding velocity.
  double split_impulse_depth_m = 0.04;
  /// Bullet's two friction directions per contact, kept from step to step: objects resting
  /// on slopes hold instead of creeping a few mm/s down them.
  bool friction_direction_caching = false;
};

/// What a suction cup transmitted to its object during the last step (table frame).
struct CupLoad {
  Vec3 force_n = Vec3::Zero();    ///< on the object, at the contact point
  Vec3 torque_nm = Vec3::Zero();  ///< on the object, about the contact point
};

class PhysicsWorld {
 public:
  explicit PhysicsWorld(const PhysicsConfig& config = PhysicsConfig());
  ~PhysicsWorld();
  PhysicsWorld(const PhysicsWorld&) = delete;
  PhysicsWorld& operator=(const PhysicsWorld&) = delete;

  /// Adds a convex object (hull of `hull_points_object`, object frame with origin at its
  /// centroid) of the given volume; returns its index (0, 1, ...).
  int addConvexObject(const std::vector<Vec3>& hull_points_object, double volume_m3,
                      const Transform& T_table_object);
  int objectCount() const;
  /// Advances `steps` fixed time steps.
  void step(int steps = 1);
  /// Steps until every object has been at rest for `rest_steps` steps; returns the number of
  /// steps taken, or -1 when `max_steps` passed first. `after_step(i)`, when given, is called
  /// after step i (1-based) unless that step ended the settling.
  int settle(int max_steps, const std::function<void(int)>& after_step = {});
  bool atRest() const;
  Transform pose(int index) const;
  /// Applies a force (N) at a table-frame point for the next step.
  void applyForce(int index, const Vec3& force_n, const Vec3& point_table);
  /// Mass of an object (kg).
  double mass(int index) const;

  /// A suction cup: object `index` held at table point `contact_table` by a compliant joint
  /// (the cup's bellows) to an anchor that moves only where moveCup() puts it (a kinematic
  /// body that collides with nothing). The joint is a spring in all six directions whose
  /// stiffness gives the held object the natural frequency `stiffness_hz`, critically damped:
  /// the object keeps resting on what supports it until the anchor pulls it away. One cup per
  /// world; attaching again moves the cup to the new object.
  void attachCup(int index, const Vec3& contact_table, double stiffness_hz = 9.5);
  /// Places the anchor for the next step: the contact point is driven to `contact_table`
  /// keeping the object's orientation at attachment.
  void moveCup(const Vec3& contact_table);
  /// Load on the held object during the last step (zero without a cup).
  CupLoad cupLoad() const;
  /// Lets go of the object (a seal that broke).
  void releaseCup();

  /// Pairs of objects in contact (distance below 2 margins); index -1 is the table.
  std::vector<std::pair<int, int>> contacts() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace simstack
