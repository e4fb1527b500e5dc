#include "simstack/physics/physics_world.h"

#include <btBulletDynamicsCommon.h>

#include <stdexcept>

namespace simstack {
namespace {

btTransform toBt(const Transform& T) {
  const Quat q(T.linear());
  return btTransform(btQuaternion(q.x(), q.y(), q.z(), q.w()),
                     btVector3(T.translation().x(), T.translation().y(), T.translation().z()));
}

Transform fromBt(const btTransform& t) {
  const btQuaternion q = t.getRotation();
  Transform T = Transform::Identity();
  T.linear() = Quat(q.w(), q.x(), q.y(), q.z()).normalized().toRotationMatrix();
  T.translation() = Vec3(t.getOrigin().x(), t.getOrigin().y(), t.getOrigin().z());
  return T;
}

// Bullet's default pools hold 4096 manifolds and 4096 collision algorithms (about 5 MB that
// the pool constructors touch page by page). Our worlds hold a handful of objects and the pile
// generator builds one per drop; pools sized for them made generation about 4 % faster on one
// thread. Pools overflow to the heap when full.
btDefaultCollisionConstructionInfo smallPools() {
  btDefaultCollisionConstructionInfo info;
  info.m_defaultMaxPersistentManifoldPoolSize = 64;
  info.m_defaultMaxCollisionAlgorithmPoolSize = 64;
  return info;
}

}  // namespace

struct PhysicsWorld::Impl {
  PhysicsConfig config;
  btDefaultCollisionConfiguration collision_config{smallPools()};
  btCollisionDispatcher dispatcher{&collision_config};
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  btDiscreteDynamicsWorld world{&dispatcher, &broadphase, &solver, &collision_config};
  std::unique_ptr<btStaticPlaneShape> table_shape;
  std::unique_ptr<btRigidBody> table;
  std::vector<std::unique_ptr<btConvexHullShape>> shapes;
  std::vector<std::unique_ptr<btDefaultMotionState>> states;
  std::vector<std::unique_ptr<btRigidBody>> bodies;

  ~Impl() {
    for (auto& b : bodies) world.removeRigidBody(b.get());
    if (table) world.removeRigidBody(table.get());
  }
  void configure(btRigidBody* body) const {
    body->setFriction(config.friction);
    body->setRollingFriction(config.rolling_friction);
    body->setSpinningFriction(config.spinning_friction);
    body->setRestitution(config.restitution);
  }
};

PhysicsWorld::PhysicsWorld(const PhysicsConfig& config) : impl_(std::make_unique<Impl>()) {
  impl_->config = config;
  impl_->world.setGravity(btVector3(0, 0, -config.gravity_mps2));
  impl_->world.getSolverInfo().m_numIterations = config.solver_iterations;
  impl_->table_shape = std::make_unique<btStaticPlaneShape>(btVector3(0, 0, 1), 0.0);
  impl_->table_shape->setMargin(config.collision_margin_m);
  btRigidBody::btRigidBodyConstructionInfo info(0.0, nullptr, impl_->table_shape.get());
  impl_->table = std::make_unique<btRigidBody>(info);
  impl_->table->setUserIndex(-1);
  impl_->configure(impl_->table.get());
  impl_->world.addRigidBody(impl_->table.get());
}

PhysicsWorld::~PhysicsWorld() = default;

int PhysicsWorld::addConvexObject(const std::vector<Vec3>& hull_points_object, double volume_m3,
                                  const Transform& T_table_object) {
  if (hull_points_object.size() < 4)
    throw std::invalid_argument("a convex object needs >= 4 hull points");
  if (!(volume_m3 > 0.0)) throw std::invalid_argument("object volume must be > 0");
  auto shape = std::make_unique<btConvexHullShape>();
  for (const auto& p : hull_points_object) shape->addPoint(btVector3(p.x(), p.y(), p.z()), false);
  shape->recalcLocalAabb();
  shape->setMargin(impl_->config.collision_margin_m);
  const double mass = impl_->config.density_kgpm3 * volume_m3;
  btVector3 inertia(0, 0, 0);
  shape->calculateLocalInertia(mass, inertia);
  auto state = std::make_unique<btDefaultMotionState>(toBt(T_table_object));
  btRigidBody::btRigidBodyConstructionInfo info(mass, state.get(), shape.get(), inertia);
  auto body = std::make_unique<btRigidBody>(info);
  impl_->configure(body.get());
  body->setDamping(impl_->config.linear_damping, impl_->config.angular_damping);
  // Bullet's default sleeping thresholds (0.8 m/s, 1 rad/s) freeze objects that are still
  // tipping over; only what is at rest by our own thresholds may sleep.
  body->setSleepingThresholds(impl_->config.rest_linear_mps, impl_->config.rest_angular_radps);
  if (!impl_->config.allow_sleeping) body->setActivationState(DISABLE_DEACTIVATION);
  const int index = static_cast<int>(impl_->bodies.size());
  body->setUserIndex(index);
  impl_->world.addRigidBody(body.get());
  impl_->shapes.push_back(std::move(shape));
  impl_->states.push_back(std::move(state));
  impl_->bodies.push_back(std::move(body));
  return index;
}

int PhysicsWorld::objectCount() const { return static_cast<int>(impl_->bodies.size()); }

void PhysicsWorld::step(int steps) {
  const double dt = impl_->config.timestep_s;
  for (int i = 0; i < steps; ++i) impl_->world.stepSimulation(dt, 1, dt);
}

bool PhysicsWorld::atRest() const {
  for (const auto& b : impl_->bodies) {
    if (!b->isActive()) continue;
    if (b->getLinearVelocity().length() > impl_->config.rest_linear_mps) return false;
    if (b->getAngularVelocity().length() > impl_->config.rest_angular_radps) return false;
  }
  return true;
}

int PhysicsWorld::settle(int max_steps, const std::function<void(int)>& after_step) {
  int quiet = 0;
  for (int i = 1; i <= max_steps; ++i) {
    step(1);
    quiet = atRest() ? quiet + 1 : 0;
    if (quiet >= impl_->config.rest_steps) return i;
    if (after_step) after_step(i);
  }
  return -1;
}

Transform PhysicsWorld::pose(int index) const {
  return fromBt(impl_->bodies.at(index)->getWorldTransform());
}

void PhysicsWorld::setPose(int index, const Transform& T_table_object) {
  auto& b = impl_->bodies.at(index);
  b->setWorldTransform(toBt(T_table_object));
  b->getMotionState()->setWorldTransform(toBt(T_table_object));
  b->activate(true);
}

Vec3 PhysicsWorld::linearVelocity(int index) const {
  const btVector3 v = impl_->bodies.at(index)->getLinearVelocity();
  return {v.x(), v.y(), v.z()};
}

void PhysicsWorld::setVelocity(int index, const Vec3& v, const Vec3& w) {
  auto& b = impl_->bodies.at(index);
  b->setLinearVelocity(btVector3(v.x(), v.y(), v.z()));
  b->setAngularVelocity(btVector3(w.x(), w.y(), w.z()));
  b->activate(true);
}

void PhysicsWorld::applyForce(int index, const Vec3& f, const Vec3& point_table) {
  auto& b = impl_->bodies.at(index);
  const btVector3 rel =
      btVector3(point_table.x(), point_table.y(), point_table.z()) - b->getCenterOfMassPosition();
  b->activate(true);
  b->applyForce(btVector3(f.x(), f.y(), f.z()), rel);
}

std::vector<std::pair<int, int>> PhysicsWorld::contacts() const {
  std::vector<std::pair<int, int>> out;
  const double limit = 2.0 * impl_->config.collision_margin_m + 1e-3;
  const int n = impl_->dispatcher.getNumManifolds();
  for (int m = 0; m < n; ++m) {
    const btPersistentManifold* mf = impl_->dispatcher.getManifoldByIndexInternal(m);
    bool touching = false;
    for (int c = 0; c < mf->getNumContacts(); ++c) {
      if (mf->getContactPoint(c).getDistance() < limit) touching = true;
    }
    if (!touching) continue;
    int a = mf->getBody0()->getUserIndex();
    int b = mf->getBody1()->getUserIndex();
    if (a > b) std::swap(a, b);
    out.emplace_back(a, b);
  }
  return out;
}

}  // namespace simstack
