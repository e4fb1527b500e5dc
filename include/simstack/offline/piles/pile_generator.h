#pragma once
/// @file pile_generator.h
/// Random piles settled under physics (paper section 3.1.4): objects are dropped one by one
/// onto the growing pile and Bullet settles each. A drop that sends an object off the table
/// or out of the scene grid is undone and drawn again; piles that are not one stack are
/// drawn again whole.

#include <cstdint>
#include <memory>
#include <random>
#include <vector>

#include "simstack/physics/physics_world.h"
#include "simstack/scene/scene.h"

namespace simstack {

struct PileConfig {
  int min_objects = 3;
  int max_objects = 4;
  double min_exponent = 2.0;  ///< exponents r, s, t drawn log-uniformly in [min, max]
  double max_exponent = 100.0;
  double min_size_m = 0.05;  ///< full extent 2 a_i of each axis, uniform in [min, max]
  double max_size_m = 0.30;
  double drop_radius_m = 0.05;  ///< horizontal scatter of each drop about the pile centre
  /// Each object falls with one of its six faces down, a random yaw and a random tilt up to
  /// this angle; 180 (the default) drops it in a uniformly random orientation, as the paper.
  /// Face-down drops (0) settle in fewer physics steps but give neater, taller piles than the
  /// paper's (docs/experiments.md, "Pile generation").
  double max_tilt_deg = 180.0;
  double drop_gap_m = 0.01;        ///< height of each drop above the top of the pile
  double grid_extent_m = 0.64;     ///< the scene grid that the pile must fit
  double grid_margin_m = 0.04;     ///< free border kept inside the grid
  double table_half_size_m = 0.5;  ///< an object whose centre leaves this square fell off
  bool require_stack = true;       ///< one connected pile with at least one object not on the table
  /// Share of the objects of a superquadric pile drawn from household shapes (household.h):
  /// half of them containers, half flat, thin or small superquadrics. 0 = the paper's piles.
  double household_share = 0.0;
  /// Per drop (8.3 s); the displacement rule of generate() ends most drops well before it.
  int max_settle_steps = 2000;
  /// A drop is abandoned once the new object has touched the table and no other object at this
  /// many consecutive checks (one per 60 steps), moving or not: it has come off the pile.
  int apart_runs = 2;
  /// Re-simulation (from zero velocities) of a finished pile, and the largest centre motion
  /// during it for the pile to be at rest. Their ratio is also the pace below which a drop
  /// counts as settled (see generate()).
  int rest_check_steps = 240;
  double rest_tolerance_m = 0.005;
  int rest_check_rounds = 4;     ///< re-simulations before a creeping pile is drawn again
  int max_drops_per_object = 8;  ///< drops of one object before the pile is drawn again
  int max_attempts = 100;
  PhysicsConfig physics = generationPhysics();

  /// Friction 1 (as the paper's stability test) and rolling friction 0.01, so that rounded
  /// shapes stop rolling within a second.
  static PhysicsConfig generationPhysics() {
    PhysicsConfig p;
    p.friction = 1.0;
    p.rolling_friction = 0.01;
    p.spinning_friction = 0.01;
    p.allow_sleeping = false;  // a sleeping object hides its creep from the rest check
    return p;
  }
};

/// What generate() returns: the settled scene and bookkeeping.
struct Pile {
  Scene scene;
  int attempts = 0;         ///< piles drawn until this one was accepted
  int drops = 0;            ///< object drops simulated in all attempts
  int placed_drops = 0;     ///< drops kept (in all attempts, also of piles rejected later)
  int undone_drops = 0;     ///< drops undone: rolled out of the grid or off the pile, no rest
  int skipped_objects = 0;  ///< objects too thick to lie on top of the pile inside the grid
  int settle_steps = 0;     ///< physics steps of the drops of the accepted pile
  /// Physics work for this pile in object-steps (steps x objects in the world), by what became
  /// of it: the accepted pile's drops and rest checks, undone drops, and the drops and rest
  /// checks of piles drawn again.
  struct {
    long placed = 0, undone_drops = 0, rest_checks = 0, rejected_piles = 0;
  } object_steps;
};

class PileGenerator {
 public:
  /// SuperquadricShape piles.
  explicit PileGenerator(const PileConfig& config);
  /// Piles of the given mesh shapes (e.g. the YCB catalogue), drawn with replacement.
  PileGenerator(const PileConfig& config,
                std::vector<std::shared_ptr<const ObjectShape>> catalogue);

  /// One accepted pile, deterministic for `seed`. Throws std::runtime_error when no pile was
  /// accepted within max_attempts (the message says which rule rejected them).
  Pile generate(uint64_t seed) const;
  /// Whether a settled scene satisfies the acceptance rules; `why` receives the reason.
  bool accept(const Scene& scene, const PhysicsWorld& world, std::string* why) const;
  /// Re-simulates the finished pile from rest (updating its poses) until it stays put; false
  /// when it keeps moving. Adds the object-steps it simulated to `object_steps` and hands over
  /// the last simulated world (whose poses are the scene's) to `last_world`, when given.
  bool verifyRest(Scene* scene, long* object_steps = nullptr,
                  std::unique_ptr<PhysicsWorld>* last_world = nullptr) const;
  /// Whether every object is on the table and the pile fits the scene grid. With
  /// `check_height` false the grid's top is not tested (an object still falling may be above
  /// it).
  bool fits(const Scene& scene, std::string* why, bool check_height = true) const;
  /// The mesh shapes drawn from (the YCB catalogue, or the containers of household piles),
  /// catalogue index = position; empty for the paper's superquadric piles.
  const std::vector<std::shared_ptr<const ObjectShape>>& catalogue() const { return catalogue_; }
  /// A random superquadric shape of this config's ranges.
  SuperquadricShape randomSuperquadric(std::mt19937_64& rng) const;

 private:
  struct Building;  ///< a pile being built (pile_generator.cpp)
  enum class DropEnd { kSettled, kRestless, kEscaped, kApart, kUnfit };
  /// One attempt: draws the object count and drops them one by one; false (the reason in
  /// `pile->why`) when an object could not be placed.
  bool dropAll(Building* pile, std::mt19937_64& rng) const;
  /// Drops `object` onto the pile, up to max_drops_per_object tries; false when none stays.
  bool place(Building* pile, SceneObject object, std::mt19937_64& rng) const;
  /// Settles `trial` (the pile plus the dropped object, index `index`) in short runs; returns
  /// the steps simulated and how the drop ended.
  int settle(PhysicsWorld& trial, const Building& pile, const SceneObject& object,
             const Vec2& centre, DropEnd* end) const;

  PileConfig config_;
  std::vector<std::shared_ptr<const ObjectShape>> catalogue_;
};

}  // namespace simstack
