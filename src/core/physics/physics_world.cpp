#include "simstack/physics/physics_world.h"

#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "simstack/assert.h"

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
// generator builds one per drop, so the pools are sized for a handful; they overflow to the
// heap when full.
btDefaultCollisionConstructionInfo smallPools() {
  btDefaultCollisionConstructionInfo info;
  info.m_defaultMaxPersistentManifoldPoolSize = 64;
  info.m_defaultMaxCollisionAlgorithmPoolSize = 64;
  return info;
}

void zero(btJointFeedback* f) {
  f->m_appliedForceBodyA.setZero();
  f->m_appliedTorqueBodyA.setZero();
  f->m_appliedForceBodyB.setZero();
  f->m_appliedTorqueBodyB.setZero();
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
  // The suction cup: a kinematic anchor holding one object through a fixed joint.
  std::unique_ptr<btSphereShape> cup_shape;
  std::unique_ptr<btDefaultMotionState> cup_state;
  std::unique_ptr<btRigidBody> cup;
  std::unique_ptr<btGeneric6DofSpring2Constraint> cup_joint;
  btJointFeedback cup_feedback;
  int cup_object = -1;
  Transform T_object_cup = Transform::Identity();  // the anchor in the held object's frame

  ~Impl() {
    removeCupJoint();
    if (cup) world.removeRigidBody(cup.get());
    for (auto& b : bodies) world.removeRigidBody(b.get());
    if (table) world.removeRigidBody(table.get());
  }
  void removeCupJoint() {
    if (cup_joint) world.removeConstraint(cup_joint.get());
    cup_joint.reset();
    if (cup_object >= 0) bodies[cup_object]->forceActivationState(ACTIVE_TAG);
    cup_object = -1;
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
  impl_->world.getSolverInfo().m_splitImpulse = config.split_impulse ? 1 : 0;
  // Bullet measures penetration as a negative distance.
  impl_->world.getSolverInfo().m_splitImpulsePenetrationThreshold =
      static_cast<btScalar>(-config.split_impulse_depth_m);
  if (config.friction_direction_caching)
    impl_->world.getSolverInfo().m_solverMode |=
        SOLVER_USE_2_FRICTION_DIRECTIONS | SOLVER_ENABLE_FRICTION_DIRECTION_CACHING;
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
  for (int i = 0; i < steps; ++i) {
    // Bullet adds to the joint feedback; cupLoad() reports one step.
    zero(&impl_->cup_feedback);
    impl_->world.stepSimulation(dt, 1, dt);
  }
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

void PhysicsWorld::applyForce(int index, const Vec3& f, const Vec3& point_table) {
  auto& b = impl_->bodies.at(index);
  const btVector3 rel =
      btVector3(point_table.x(), point_table.y(), point_table.z()) - b->getCenterOfMassPosition();
  b->activate(true);
  b->applyForce(btVector3(f.x(), f.y(), f.z()), rel);
}

double PhysicsWorld::mass(int index) const {
  const btScalar inverse = impl_->bodies.at(index)->getInvMass();
  return inverse > 0 ? 1.0 / inverse : 0.0;
}

void PhysicsWorld::attachCup(int index, const Vec3& contact_table, double stiffness_hz) {
  Impl& m = *impl_;
  btRigidBody* object = m.bodies.at(index).get();
  m.removeCupJoint();
  Transform T_table_cup = pose(index);
  T_table_cup.translation() = contact_table;
  if (!m.cup) {
    m.cup_shape = std::make_unique<btSphereShape>(0.005);
    m.cup_state = std::make_unique<btDefaultMotionState>(toBt(T_table_cup));
    btRigidBody::btRigidBodyConstructionInfo info(0.0, m.cup_state.get(), m.cup_shape.get());
    m.cup = std::make_unique<btRigidBody>(info);
    m.cup->setCollisionFlags(m.cup->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT |
                             btCollisionObject::CF_NO_CONTACT_RESPONSE);
    m.cup->setActivationState(DISABLE_DEACTIVATION);
    m.cup->setUserIndex(-2);
    m.world.addRigidBody(m.cup.get(), 0, 0);  // collides with nothing
  }
  m.cup_state->setWorldTransform(toBt(T_table_cup));
  m.cup->setWorldTransform(toBt(T_table_cup));
  m.T_object_cup = pose(index).inverse() * T_table_cup;
  m.cup_joint = std::make_unique<btGeneric6DofSpring2Constraint>(
      *m.cup, *object, btTransform::getIdentity(), toBt(m.T_object_cup));
  const double omega = 2.0 * M_PI * stiffness_hz, mass = 1.0 / object->getInvMass();
  const btVector3 inertia = object->getLocalInertia();
  const double turn = std::max({inertia.x(), inertia.y(), inertia.z()});
  for (int axis = 0; axis < 6; ++axis) {
    const double m_axis = axis < 3 ? mass : turn;
    m.cup_joint->setLimit(axis, 1.0, -1.0);  // free: the spring alone holds
    m.cup_joint->enableSpring(axis, true);
    m.cup_joint->setStiffness(axis, m_axis * omega * omega);
    m.cup_joint->setDamping(axis, 2.0 * m_axis * omega);
    m.cup_joint->setEquilibriumPoint(axis, 0.0);
  }
  zero(&m.cup_feedback);
  m.cup_joint->setJointFeedback(&m.cup_feedback);
  m.cup_joint->enableFeedback(true);
  m.world.addConstraint(m.cup_joint.get(), true);
  object->forceActivationState(DISABLE_DEACTIVATION);
  m.cup_object = index;
}

void PhysicsWorld::moveCup(const Vec3& contact_table) {
  Impl& m = *impl_;
  SIMSTACK_ASSERT(m.cup, "moveCup without attachCup");
  btTransform t = m.cup->getWorldTransform();
  t.setOrigin(btVector3(contact_table.x(), contact_table.y(), contact_table.z()));
  m.cup_state->setWorldTransform(t);
}

CupLoad PhysicsWorld::cupLoad() const {
  const Impl& m = *impl_;
  CupLoad load;
  if (!m.cup_joint) return load;
  const btVector3& f = m.cup_feedback.m_appliedForceBodyB;
  const btVector3& t = m.cup_feedback.m_appliedTorqueBodyB;
  load.force_n = Vec3(f.x(), f.y(), f.z());
  // Bullet reports the torque about the object's centre of mass; the seal feels it about the
  // contact point.
  const Transform T_table_object = pose(m.cup_object);
  const Vec3 contact = T_table_object * m.T_object_cup.translation();
  load.torque_nm =
      Vec3(t.x(), t.y(), t.z()) + (T_table_object.translation() - contact).cross(load.force_n);
  return load;
}

void PhysicsWorld::releaseCup() { impl_->removeCupJoint(); }

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
