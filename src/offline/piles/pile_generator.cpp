#include "simstack/offline/piles/pile_generator.h"

#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <sstream>
#include <stdexcept>

#include "simstack/geometry/voxel_grid.h"
#include "simstack/offline/piles/household.h"

namespace simstack {
namespace {

// One of the 24 axis-aligned orientations (a face down), a uniform yaw, and a tilt of at most
// max_tilt_deg about a random horizontal axis; max_tilt_deg >= 180 gives a uniform rotation.
Quat randomDropRotation(double max_tilt_deg, std::mt19937_64& rng) {
  if (max_tilt_deg >= 180.0) {
    std::normal_distribution<double> n(0.0, 1.0);
    return Quat(n(rng), n(rng), n(rng), n(rng)).normalized();
  }
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  static const Vec3 kAxes[6] = {Vec3::UnitX(),  -Vec3::UnitX(), Vec3::UnitY(),
                                -Vec3::UnitY(), Vec3::UnitZ(),  -Vec3::UnitZ()};
  const Vec3 down = kAxes[std::min(5, static_cast<int>(6 * uni(rng)))];
  const Quat face = Quat::FromTwoVectors(down, -Vec3::UnitZ());
  const Quat yaw(Eigen::AngleAxisd(2.0 * M_PI * uni(rng), Vec3::UnitZ()));
  const double a = 2.0 * M_PI * uni(rng);
  const Quat tilt(Eigen::AngleAxisd(max_tilt_deg * M_PI / 180.0 * uni(rng),
                                    Vec3(std::cos(a), std::sin(a), 0.0)));
  return (tilt * yaw * face).normalized();
}

// What object `index` of the world touches: the table, other objects.
struct Touching {
  bool table = false, object = false;
};
Touching touching(const PhysicsWorld& world, int index) {
  Touching t;
  for (const auto& [a, b] : world.contacts()) {  // a < b; the table is -1
    if (a != index && b != index) continue;
    (a < 0 ? t.table : t.object) = true;
  }
  return t;
}

// Lowest point of the object's hull in the table frame.
double minZ(const SceneObject& o) {
  double z = 1e9;
  for (const auto& p : o.shape->hullPoints()) z = std::min(z, (o.T_table_object * p).z());
  return z;
}

}  // namespace

PileGenerator::PileGenerator(const PileConfig& config) : config_(config) {
  if (config.min_objects < 1 || config.max_objects < config.min_objects) {
    throw std::invalid_argument("object count range must satisfy 1 <= min <= max");
  }
  if (!(config.min_exponent > 0.0) || config.max_exponent < config.min_exponent) {
    throw std::invalid_argument("exponent range must satisfy 0 < min <= max");
  }
  if (!(config.min_size_m > 0.0) || config.max_size_m < config.min_size_m) {
    throw std::invalid_argument("size range must satisfy 0 < min <= max");
  }
  if (config.rest_check_steps < 1 || !(config.rest_tolerance_m > 0.0) ||
      config.rest_check_rounds < 1) {
    throw std::invalid_argument("the rest check needs steps >= 1, tolerance > 0 and rounds >= 1");
  }
  if (!(config.household_share >= 0.0 && config.household_share <= 1.0))
    throw std::invalid_argument("household_share must be in [0, 1], got " +
                                std::to_string(config.household_share));
  if (config.household_share > 0.0) catalogue_ = containerCatalogue();
}

PileGenerator::PileGenerator(const PileConfig& config,
                             std::vector<std::shared_ptr<const ObjectShape>> catalogue)
    : PileGenerator(config) {
  if (catalogue.empty()) throw std::invalid_argument("mesh catalogue is empty");
  if (config.household_share > 0.0)
    throw std::invalid_argument(
        "household shapes are drawn into superquadric piles, not mesh piles");
  catalogue_ = std::move(catalogue);
}

SuperquadricShape PileGenerator::randomSuperquadric(std::mt19937_64& rng) const {
  std::uniform_real_distribution<double> size(config_.min_size_m, config_.max_size_m);
  std::uniform_real_distribution<double> log_e(std::log(config_.min_exponent),
                                               std::log(config_.max_exponent));
  SuperquadricShape sq;
  for (int i = 0; i < 3; ++i) {
    sq.scale_m[i] = 0.5 * size(rng);
    sq.exponents[i] = std::exp(log_e(rng));
  }
  return sq;
}

bool PileGenerator::accept(const Scene& scene, const PhysicsWorld& world, std::string* why) const {
  const int n = static_cast<int>(scene.objects.size());
  if (!fits(scene, why)) return false;
  if (!config_.require_stack || n < 2) return true;
  // One connected pile, and at least one object that does not touch the table.
  std::vector<int> parent(n);
  for (int i = 0; i < n; ++i) parent[i] = i;
  std::function<int(int)> find = [&](int i) {
    return parent[i] == i ? i : parent[i] = find(parent[i]);
  };
  std::vector<bool> on_table(n, false);
  for (const auto& [a, b] : world.contacts()) {
    if (a < 0) {
      if (b >= 0) on_table[b] = true;
      continue;
    }
    parent[find(a)] = find(b);
  }
  for (int i = 1; i < n; ++i) {
    if (find(i) != find(0)) {
      *why = "the objects do not form one stack";
      return false;
    }
  }
  for (int i = 0; i < n; ++i) {
    if (!on_table[i]) return true;
  }
  *why = "every object stands on the table (nothing is stacked)";
  return false;
}

bool PileGenerator::fits(const Scene& scene, std::string* why, bool check_height) const {
  for (const auto& o : scene.objects) {
    const Vec3 c = o.T_table_object.translation();
    if (std::abs(c.x()) > config_.table_half_size_m ||
        std::abs(c.y()) > config_.table_half_size_m || minZ(o) < -0.01) {
      *why = "an object left the table";
      return false;
    }
  }
  const Vec3 centre = scene.surfaceCentroid();
  const GridSpec grid = GridSpec::sceneGrid(centre.head<2>(), config_.grid_extent_m, 8);
  // The bottom was tested above (no object below the table).
  const Vec2 lo = grid.origin_table.head<2>() + Vec2::Constant(config_.grid_margin_m);
  const Vec2 hi =
      grid.origin_table.head<2>() + Vec2::Constant(config_.grid_extent_m - config_.grid_margin_m);
  const double top = grid.origin_table.z() + config_.grid_extent_m - config_.grid_margin_m;
  for (const auto& o : scene.objects) {
    for (const auto& p : o.shape->hullPoints()) {
      const Vec3 q = o.T_table_object * p;
      if (check_height && q.z() > top) {
        *why = "the pile is taller than the scene grid";
        return false;
      }
      if ((q.head<2>().array() < lo.array()).any() || (q.head<2>().array() > hi.array()).any()) {
        *why = "the pile is wider than the scene grid";
        return false;
      }
    }
  }
  return true;
}

bool PileGenerator::verifyRest(Scene* scene, long* object_steps,
                               std::unique_ptr<PhysicsWorld>* last_world) const {
  // Velocity thresholds can call a pile at rest while an object creeps down a slope or only
  // starts to tip. The pile is rebuilt from its poses with zero velocities (as anyone loading
  // it will) and simulated for rest_check_steps; it is at rest when no centre moves more than
  // rest_tolerance_m, else the moved poses are tried again.
  for (int round = 0; round < config_.rest_check_rounds; ++round) {
    auto world = std::make_unique<PhysicsWorld>(config_.physics);
    for (const auto& o : scene->objects)
      world->addConvexObject(o.shape->hullPoints(), o.shape->volume(), o.T_table_object);
    world->step(config_.rest_check_steps);
    if (object_steps) *object_steps += long{config_.rest_check_steps} * world->objectCount();
    double moved = 0.0;
    for (size_t k = 0; k < scene->objects.size(); ++k) {
      const Transform T = world->pose(static_cast<int>(k));
      moved = std::max(moved,
                       (T.translation() - scene->objects[k].T_table_object.translation()).norm());
      scene->objects[k].T_table_object = T;
    }
    if (last_world) *last_world = std::move(world);
    if (moved < config_.rest_tolerance_m) return true;
  }
  return false;
}

struct PileGenerator::Building {
  Pile* out;   ///< counters over every attempt
  int* drops;  ///< drops simulated over every attempt
  Scene scene;
  std::unique_ptr<PhysicsWorld> world;  ///< the world of the last kept drop
  int steps = 0;                        ///< physics steps of the kept drops
  long object_steps = 0;                ///< object-steps of the kept drops (and rest checks)
  std::string why;                      ///< why the last drop or attempt failed

  /// The pile as it would be kept if the drop in `trial` ended now.
  Scene withDrop(const SceneObject& o, const PhysicsWorld& trial) const {
    Scene c = scene;
    c.objects.push_back(o);
    for (size_t k = 0; k < c.objects.size(); ++k)
      c.objects[k].T_table_object = trial.pose(static_cast<int>(k));
    return c;
  }
};

// Settle in short runs and give up early on a drop that rolls out of the grid, that has pushed any
// part of the pile out of the grid's sides (checked after every run), or that has come down on the
// table clear of the pile (docs/experiments.md, "Pile generation": what each rule saved). A drop
// has settled when every velocity stays below the rest thresholds for rest_steps steps, or when
// during a whole run (poses sampled every 10 steps) no object got further from where it was at the
// start of the run than the final rest check tolerates for the run's length, nor turned further
// than the angular rest threshold allows: contact jitter keeps the velocities of slowly creeping
// piles above the thresholds.
int PileGenerator::settle(PhysicsWorld& trial, const Building& pile, const SceneObject& o,
                          const Vec2& centre, DropEnd* end) const {
  constexpr int kRun = 60, kSample = 10;
  const double max_shift = config_.rest_tolerance_m * kRun / config_.rest_check_steps;
  const double max_turn = config_.physics.rest_angular_radps * kRun * config_.physics.timestep_s;
  const int index = static_cast<int>(pile.scene.objects.size());
  int s = 0, apart_runs = 0;
  std::vector<Transform> start(trial.objectCount());
  std::string why;
  *end = DropEnd::kRestless;
  while (s < config_.max_settle_steps) {
    for (int k = 0; k < trial.objectCount(); ++k) start[k] = trial.pose(k);
    double shift = 0.0, turn = 0.0;
    const int run = trial.settle(kRun, [&](int i) {
      if (i % kSample) return;
      for (int k = 0; k < trial.objectCount(); ++k) {
        const Transform T = trial.pose(k);
        shift = std::max(shift, (T.translation() - start[k].translation()).norm());
        turn =
            std::max(turn, Eigen::AngleAxisd(T.linear() * start[k].linear().transpose()).angle());
      }
    });
    s += run < 0 ? kRun : run;
    if (run >= 0) {
      *end = DropEnd::kSettled;
      return s;
    }
    if ((trial.pose(index).translation().head<2>() - centre).norm() > 0.5 * config_.grid_extent_m) {
      *end = DropEnd::kEscaped;
      return s;
    }
    if (!fits(pile.withDrop(o, trial), &why, false)) {
      *end = DropEnd::kUnfit;
      return s;
    }
    if (index > 0 && config_.require_stack) {
      const Touching t = touching(trial, index);
      apart_runs = t.table && !t.object ? apart_runs + 1 : 0;
      if (apart_runs >= config_.apart_runs) {
        *end = DropEnd::kApart;
        return s;
      }
    }
    if (shift < max_shift && turn < max_turn) {
      *end = DropEnd::kSettled;
      return s;
    }
  }
  return s;
}

bool PileGenerator::place(Building* pile, SceneObject o, std::mt19937_64& rng) const {
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const Scene& scene = pile->scene;
  Vec2 centre = Vec2::Zero();
  double top = 0.0;
  for (const auto& p : scene.objects) {
    centre += p.T_table_object.translation().head<2>() / static_cast<double>(scene.objects.size());
    for (const auto& h : p.shape->hullPoints()) top = std::max(top, (p.T_table_object * h).z());
  }
  // An object too thick, in every orientation, to lie on top of the pile inside the grid is
  // not dropped (the attempt fails, as after max_drops_per_object failed drops): it could only
  // be kept by sliding down beside the pile.
  Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (const auto& p : o.shape->hullPoints()) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  if (top + (hi - lo).minCoeff() > config_.grid_extent_m - config_.grid_margin_m) {
    pile->why = "the pile is taller than the scene grid";
    ++pile->out->skipped_objects;
    return false;
  }
  for (int drop = 0; drop < config_.max_drops_per_object; ++drop) {
    ++*pile->drops;
    auto trial = std::make_unique<PhysicsWorld>(config_.physics);
    for (const auto& p : scene.objects)
      trial->addConvexObject(p.shape->hullPoints(), p.shape->volume(), p.T_table_object);
    const double r = config_.drop_radius_m * std::sqrt(uni(rng));
    const double phi = 2.0 * M_PI * uni(rng);
    o.T_table_object = Transform::Identity();
    o.T_table_object.linear() = randomDropRotation(config_.max_tilt_deg, rng).toRotationMatrix();
    const double bottom = minZ(o);  // of the rotated shape at the origin
    o.T_table_object.translation() =
        Vec3(centre.x() + r * std::cos(phi), centre.y() + r * std::sin(phi),
             top - bottom + config_.drop_gap_m);
    trial->addConvexObject(o.shape->hullPoints(), o.shape->volume(), o.T_table_object);
    DropEnd end;
    const int s = settle(*trial, *pile, o, centre, &end);
    const long object_steps = long{s} * trial->objectCount();
    const int index = static_cast<int>(scene.objects.size());
    bool kept = end == DropEnd::kSettled;
    if (end == DropEnd::kEscaped) pile->why = "the pile is wider than the scene grid";
    if (end == DropEnd::kApart) pile->why = "the objects do not form one stack";
    if (end == DropEnd::kRestless) pile->why = "the pile did not come to rest";
    if (end == DropEnd::kUnfit) fits(pile->withDrop(o, *trial), &pile->why, false);
    if (kept && index > 0 && config_.require_stack && !touching(*trial, index).object) {
      pile->why = "the objects do not form one stack";
      kept = false;
    }
    Scene candidate;
    if (kept) {
      candidate = pile->withDrop(o, *trial);
      kept = fits(candidate, &pile->why);
    }
    if (!kept) {
      pile->out->object_steps.undone_drops += object_steps;
      ++pile->out->undone_drops;
      continue;
    }
    pile->object_steps += object_steps;
    ++pile->out->placed_drops;
    pile->scene = std::move(candidate);
    pile->world = std::move(trial);
    pile->steps += s;
    return true;
  }
  return false;
}

// Objects are dropped one at a time from just above the pile and settle before the next one
// falls. A drop that knocks the pile out of bounds is undone and tried again from the settled
// state before it (the world is rebuilt from the resting poses), so that one rolling object
// does not cost the whole pile.
bool PileGenerator::dropAll(Building* pile, std::mt19937_64& rng) const {
  std::uniform_int_distribution<int> count(config_.min_objects, config_.max_objects);
  const int n = count(rng);
  for (int i = 0; i < n; ++i) {
    SceneObject o;
    if (catalogue_.empty()) {
      o.shape = ObjectShape::fromSuperquadric(randomSuperquadric(rng));
    } else if (config_.household_share > 0.0) {
      // Household piles: the catalogue holds the containers (PileGenerator's constructor).
      std::uniform_real_distribution<double> u(0.0, 1.0);
      if (u(rng) >= config_.household_share) {
        o.shape = ObjectShape::fromSuperquadric(randomSuperquadric(rng));
      } else if (u(rng) < 0.5) {
        std::uniform_int_distribution<size_t> pick(0, catalogue_.size() - 1);
        o.shape = catalogue_[pick(rng)];
      } else {
        o.shape = ObjectShape::fromSuperquadric(
            householdSuperquadric(rng, config_.min_exponent, config_.max_exponent));
      }
    } else {
      std::uniform_int_distribution<size_t> pick(0, catalogue_.size() - 1);
      o.shape = catalogue_[pick(rng)];
    }
    if (!place(pile, std::move(o), rng)) return false;
  }
  return true;
}

Pile PileGenerator::generate(uint64_t seed) const {
  std::mt19937_64 rng(seed);
  std::map<std::string, int> rejections;
  int drops = 0;
  Pile out;
  for (int attempt = 1; attempt <= config_.max_attempts; ++attempt) {
    Building pile{&out, &drops, {}, nullptr, 0, 0, ""};
    const auto reject = [&](const std::string& reason) {
      ++rejections[reason];
      out.object_steps.rejected_piles += pile.object_steps;
    };
    if (!dropAll(&pile, rng)) {
      reject(pile.why);
      continue;
    }
    long rest_steps = 0;
    // The acceptance rules read the contacts of the world that verified the final poses.
    const bool at_rest = verifyRest(&pile.scene, &rest_steps, &pile.world);
    pile.object_steps += rest_steps;  // counted as rejected unless the pile is accepted
    if (!at_rest) {
      reject("the pile did not come to rest");
      continue;
    }
    if (!accept(pile.scene, *pile.world, &pile.why)) {
      reject(pile.why);
      continue;
    }
    out.scene = std::move(pile.scene);
    out.attempts = attempt;
    out.drops = drops;
    out.settle_steps = pile.steps;
    out.object_steps.placed = pile.object_steps - rest_steps;
    out.object_steps.rest_checks = rest_steps;
    return out;
  }
  std::ostringstream msg;
  msg << "no pile accepted in " << config_.max_attempts << " attempts (seed " << seed << "):";
  const char* separator = " ";
  for (const auto& [reason, k] : rejections)
    msg << separator << k << "x " << reason, separator = "; ";
  throw std::runtime_error(msg.str());
}

}  // namespace simstack
