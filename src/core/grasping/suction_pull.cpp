#include "simstack/grasping/suction_pull.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>

#include "simstack/scene/scene.h"

namespace simstack {
namespace {

void requirePositive(double value, const char* name) {
  if (!(value > 0.0) || !std::isfinite(value))
    throw std::invalid_argument(std::string(name) + " must be a positive number, not " +
                                std::to_string(value));
}

void check(const PullConfig& c) {
  requirePositive(c.pull_distance_m, "pull_distance_m");
  requirePositive(c.pull_speed_mps, "pull_speed_mps");
  requirePositive(c.max_force_n, "max_force_n");
  requirePositive(c.cup_radius_m, "cup_radius_m");
  requirePositive(c.cup_stiffness_hz, "cup_stiffness_hz");
  requirePositive(c.topple_rad, "topple_rad");
  requirePositive(c.physics.timestep_s, "physics timestep_s");
  // Bullet's spring joint quietly lowers a stiffer spring to this bound (omega dt <= 1/4), so a
  // higher frequency would not be what is simulated.
  const double most_hz = 0.25 / (2.0 * M_PI * c.physics.timestep_s);
  if (c.cup_stiffness_hz > most_hz)
    throw std::invalid_argument("cup_stiffness_hz must be at most " + std::to_string(most_hz) +
                                " Hz at a " + std::to_string(c.physics.timestep_s) +
                                " s time step (a stiffer spring is not simulated), not " +
                                std::to_string(c.cup_stiffness_hz));
  requirePositive(c.physics.density_kgpm3, "density_kgpm3");
  // Simulated seconds of each phase: a minute at most (more is a unit mistake, and the steps
  // are counted in an int).
  if (!std::isfinite(c.ramp_s) || c.ramp_s < 0.0 || c.ramp_s > 60.0)
    throw std::invalid_argument("ramp_s must lie in [0, 60] s");
  if (!std::isfinite(c.settle_s) || c.settle_s < 0.0 || c.settle_s > 60.0)
    throw std::invalid_argument("settle_s must lie in [0, 60] s");
  if (!std::isfinite(c.presettle_s) || c.presettle_s < 0.0 || c.presettle_s > 60.0)
    throw std::invalid_argument("presettle_s must lie in [0, 60] s");
  if (c.break_steps < 1) throw std::invalid_argument("break_steps must be >= 1");
  if (c.pull_distance_m / c.pull_speed_mps > PullConfig::kMaxPullS)
    throw std::invalid_argument("pull_distance_m / pull_speed_mps is over " +
                                std::to_string(static_cast<int>(PullConfig::kMaxPullS)) + " s");
}

/// The order the objects enter the physics in: from the bottom up (as a pile is built, which
/// Bullet, solving contacts in insertion order, holds most still), then by their other
/// parameters; not by their place in the caller's list, so that a pile listed otherwise is
/// simulated alike.
std::vector<int> canonicalOrder(const std::vector<SuperquadricShape>& scene) {
  std::vector<std::array<double, 19>> keys;
  for (const SuperquadricShape& sq : scene) {
    std::array<double, 19> k{};
    k[0] = sceneBottom({sq});
    const Eigen::Matrix4d m = sq.T_table_object.matrix();
    for (int i = 0; i < 12; ++i) k[1 + i] = m(i % 3, 3 - i / 3);  // position, then rotation
    for (int i = 0; i < 3; ++i) k[13 + i] = sq.scale_m[i], k[16 + i] = sq.exponents[i];
    keys.push_back(k);
  }
  std::vector<int> order(scene.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return keys[a] < keys[b]; });
  return order;
}

double angleBetween(const Transform& a, const Transform& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}

}  // namespace

double sceneBottom(const std::vector<SuperquadricShape>& scene) {
  double bottom = std::numeric_limits<double>::infinity();
  for (const SuperquadricShape& sq : scene)
    for (const Vec3& v : sq.meshObject(16).vertices)
      bottom = std::min(bottom, (sq.T_table_object * v).z());
  return bottom;
}

void PullConfig::validate() const { check(*this); }

PhysicsConfig PullConfig::pullPhysics() {
  PhysicsConfig p;
  p.friction = 1.0;
  p.rolling_friction = 0.01;
  p.spinning_friction = 0.01;
  p.allow_sleeping = true;
  p.friction_direction_caching = true;
  p.split_impulse_depth_m = 0.0;
  p.density_kgpm3 = 200.0;
  return p;
}

int PullConfig::pullSteps() const {
  const double seconds = pull_distance_m / pull_speed_mps + 0.5 * ramp_s;
  return static_cast<int>(std::ceil(seconds / physics.timestep_s));
}

int PullConfig::settleSteps() const {
  return static_cast<int>(std::ceil(settle_s / physics.timestep_s));
}

PullSimulator::PullSimulator(const std::vector<SuperquadricShape>& given, const PullConfig& config)
    : config_(config), slot_(given.size()) {
  config.validate();
  for (const SuperquadricShape& sq : given)
    if (!sq.T_table_object.matrix().allFinite())
      throw std::invalid_argument("an object's pose is not finite");
  const std::vector<int> order = canonicalOrder(given);
  for (size_t k = 0; k < order.size(); ++k) {
    slot_[order[k]] = static_cast<int>(k);
    scene_.push_back(given[order[k]]);
  }
  for (const SuperquadricShape& sq : scene_) {
    const auto shape = ObjectShape::fromSuperquadric(sq);
    hulls_.push_back(shape->hullPoints());
    volumes_.push_back(shape->volume());
    settled_.push_back(sq.T_table_object);
  }
  // Settle first: every run starts from the state this physics holds at rest.
  auto w = world(settled_);
  const int max_steps = static_cast<int>(std::ceil(config.presettle_s / config.physics.timestep_s));
  drift_.settled = max_steps == 0 || w->settle(max_steps) >= 0;
  for (size_t i = 0; i < scene_.size(); ++i) {
    const Transform p = w->pose(static_cast<int>(i));
    drift_.presettle_displacement_m = std::max(
        drift_.presettle_displacement_m, (p.translation() - settled_[i].translation()).norm());
    settled_[i] = p;
  }
  // The reference every pull is measured against: the same time, no pull.
  w = world(settled_);
  w->step(config.pullSteps() + config.settleSteps());
  for (size_t i = 0; i < scene_.size(); ++i) {
    alone_.push_back(w->pose(static_cast<int>(i)));
    const double d = (alone_[i].translation() - settled_[i].translation()).norm();
    drift_.mean_displacement_m += d / scene_.size();
    drift_.max_displacement_m = std::max(drift_.max_displacement_m, d);
  }
}

std::unique_ptr<PhysicsWorld> PullSimulator::world(const std::vector<Transform>& poses) const {
  auto w = std::make_unique<PhysicsWorld>(config_.physics);
  for (size_t i = 0; i < hulls_.size(); ++i) w->addConvexObject(hulls_[i], volumes_[i], poses[i]);
  return w;
}

int PullSimulator::slot(int target) const {
  if (target < 0 || target >= static_cast<int>(slot_.size()))
    throw std::invalid_argument("pull target out of range");
  return slot_[target];
}

PullOutcome PullSimulator::pullPerceived(int given_target, const Vec3& contact,
                                         const Vec3& approach) const {
  const int target = slot(given_target);
  const Transform moved = settled_[target] * scene_[target].T_table_object.inverse();
  return pull(given_target, moved * contact, moved.linear() * approach);
}

PullOutcome PullSimulator::pull(int given_target, const Vec3& contact, const Vec3& approach) const {
  const int target = slot(given_target);
  const Vec3 a = approach.normalized();
  auto w = world(settled_);
  w->attachCup(target, contact, config_.cup_stiffness_hz);
  const double dt = config_.physics.timestep_s, v = config_.pull_speed_mps;
  const double ramp = config_.ramp_s, max_torque = config_.max_force_n * config_.cup_radius_m;
  PullOutcome out;
  int over = 0;
  const int pull_steps = config_.pullSteps(), steps = pull_steps + config_.settleSteps();
  for (int i = 1; i <= steps; ++i) {
    const double t = std::min(i, pull_steps) * dt;
    const double s = t < ramp ? 0.5 * v * t * t / ramp : 0.5 * v * ramp + v * (t - ramp);
    if (out.cup_held) w->moveCup(contact + std::min(s, config_.pull_distance_m) * a);
    w->step(1);
    if (!out.cup_held) continue;
    const CupLoad load = w->cupLoad();
    const bool too_much =
        load.force_n.norm() > config_.max_force_n || load.torque_nm.norm() > max_torque;
    over = too_much ? over + 1 : 0;
    if (over >= config_.break_steps) {
      w->releaseCup();
      out.cup_held = false;
    } else {
      out.peak_force_n = std::max(out.peak_force_n, load.force_n.norm());
      out.peak_load = std::max({out.peak_load, load.force_n.norm() / config_.max_force_n,
                                load.torque_nm.norm() / max_torque});
    }
  }
  int others = 0;
  for (int i = 0; i < static_cast<int>(scene_.size()); ++i) {
    if (i == target) continue;
    const Transform end = w->pose(i);
    const double d = (end.translation() - alone_[i].translation()).norm();
    const double angle = angleBetween(alone_[i], end);
    out.mean_displacement_m += d, ++others;
    out.max_displacement_m = std::max(out.max_displacement_m, d);
    out.max_rotation_rad = std::max(out.max_rotation_rad, angle);
    out.toppled += angle > config_.topple_rad ? 1 : 0;
  }
  if (others > 0) out.mean_displacement_m /= others;
  bool touching = false;
  for (const auto& [p, q] : w->contacts())
    touching |= (p == target && q >= 0) || (q == target && p >= 0);
  out.target_freed = out.cup_held && !touching;
  out.target_lift_m = w->pose(target).translation().z() - settled_[target].translation().z();
  return out;
}

}  // namespace simstack
