#include <gtest/gtest.h>

#include <filesystem>

#include "simstack/offline/piles/household.h"
#include "simstack/offline/piles/mesh_catalogue.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/physics/physics_world.h"
#include "test_scenes.h"

using namespace simstack;

namespace {
double lowestPoint(const SceneObject& o) {
  double z = 1e9;
  for (const auto& v : o.shape->mesh().vertices) z = std::min(z, (o.T_table_object * v).z());
  return z;
}

// Re-simulates a scene from rest and returns the largest centre displacement.
double displacementAfter(const Scene& scene, int steps) {
  PhysicsWorld world(PileConfig::generationPhysics());
  for (const auto& o : scene.objects)
    world.addConvexObject(o.shape->hullPoints(), o.shape->volume(), o.T_table_object);
  world.step(steps);
  double worst = 0.0;
  for (size_t i = 0; i < scene.objects.size(); ++i) {
    worst = std::max(worst, (world.pose(static_cast<int>(i)).translation() -
                             scene.objects[i].T_table_object.translation())
                                .norm());
  }
  return worst;
}
}  // namespace

TEST(Physics, BoxComesToRestOnTheTable) {
  SuperquadricShape box;
  box.scale_m = Vec3(0.08, 0.05, 0.03);
  box.exponents = Vec3::Constant(100);
  const auto shape = ObjectShape::fromSuperquadric(box);
  PhysicsWorld world;
  Transform T = Transform::Identity();
  T.translation() = Vec3(0.1, -0.2, 0.04);
  world.addConvexObject(shape->hullPoints(), shape->volume(), T);
  ASSERT_GT(world.settle(4000), 0);
  // Resting on its largest face: centre at a3 above the table (1 mm collision margin).
  EXPECT_NEAR(world.pose(0).translation().z(), 0.03, 0.002);
  EXPECT_LT((world.pose(0).translation().head<2>() - Vec2(0.1, -0.2)).norm(), 0.002);
  EXPECT_LT(Quat(world.pose(0).linear()).angularDistance(Quat::Identity()), 0.01);
}

// Moving a cup that was never attached is a programmer error: the process stops and says so
// (an internal error, not an exception a caller could take for bad input).
TEST(PhysicsDeathTest, MovingACupNeverAttachedStopsWithTheReason) {
  ::testing::GTEST_FLAG(death_test_style) = "threadsafe";
  EXPECT_DEATH(
      {
        PhysicsWorld world;
        world.moveCup(Vec3(0.0, 0.0, 0.1));
      },
      "simstack internal error: moveCup without attachCup");
}

TEST(ObjectShape, PhysicsHullIsCompactOnTheSurfaceAndSurvivesTinyShapes) {
  // Box-like: the snapped lattice's face points are coplanar and leave the hull.
  SuperquadricShape box;
  box.scale_m = Vec3(0.10, 0.05, 0.08);
  box.exponents = Vec3::Constant(80.0);
  const auto shape = ObjectShape::fromSuperquadric(box);
  EXPECT_LT(shape->hullPoints().size(), 60u);
  for (const Vec3& p : shape->hullPoints())  // the snap moves a point by at most 0.87 mm
    EXPECT_LT((p - box.surfacePointAlong(p)).norm(), 1e-3) << p.transpose();
  // Thinner than the 1 mm snap: the unsnapped lattice is kept instead of a flat hull.
  SuperquadricShape tiny;
  tiny.scale_m = Vec3(0.0003, 0.02, 0.02);
  tiny.exponents = Vec3::Constant(2.0);
  std::shared_ptr<const ObjectShape> thin;
  ASSERT_NO_THROW(thin = ObjectShape::fromSuperquadric(tiny));
  EXPECT_GE(thin->hullPoints().size(), 4u);
}

TEST(PileGenerator, SettledPileIsAtRestAndAboveTheTable) {
  PileGenerator gen{PileConfig()};
  for (uint64_t seed : {1u, 2u, 3u, 4u, 5u}) {
    const Pile pile = gen.generate(seed);
    const Scene& scene = pile.scene;
    ASSERT_GE(scene.objects.size(), 3u) << "seed " << seed;
    ASSERT_LE(scene.objects.size(), 4u) << "seed " << seed;
    for (const auto& o : scene.objects) {
      EXPECT_GT(lowestPoint(o), -0.01) << "seed " << seed;
      const Vec3 a = o.shape->superquadric().scale_m;
      const Vec3 e = o.shape->superquadric().exponents;
      EXPECT_TRUE((a.array() >= 0.025).all() && (a.array() <= 0.15).all()) << "seed " << seed;
      EXPECT_TRUE((e.array() >= 2.0).all() && (e.array() <= 100.0).all()) << "seed " << seed;
    }
    EXPECT_LT(displacementAfter(scene, 240), 0.01)
        << "seed " << seed << ": pile moved within 1 s of re-simulation";
  }
}

TEST(PileGenerator, TallPilesSkipObjectsThatCannotFitAndKeepTheBooks) {
  // Face-down drops build tall piles: objects too thick to lie on top of them inside the grid
  // are skipped unsimulated, accepted piles still fit, and the bookkeeping adds up.
  PileConfig config;
  config.max_tilt_deg = 0.0;
  PileGenerator gen(config);
  int skipped = 0;
  for (uint64_t seed = 1; seed <= 8; ++seed) {
    const Pile pile = gen.generate(seed);
    const int n = static_cast<int>(pile.scene.objects.size());
    double top = 0.0;
    for (const auto& o : pile.scene.objects)
      for (const Vec3& h : o.shape->hullPoints()) top = std::max(top, (o.T_table_object * h).z());
    EXPECT_LE(top, config.grid_extent_m - config.grid_margin_m) << "seed " << seed;
    EXPECT_EQ(pile.drops, pile.placed_drops + pile.undone_drops) << "seed " << seed;
    EXPECT_GE(pile.placed_drops, n) << "seed " << seed;
    // Drop i simulates i + 1 objects: the accepted pile's object-steps lie between its steps
    // and n times its steps.
    EXPECT_GE(pile.object_steps.placed, pile.settle_steps) << "seed " << seed;
    EXPECT_LE(pile.object_steps.placed, static_cast<long>(n) * pile.settle_steps)
        << "seed " << seed;
    EXPECT_EQ(pile.object_steps.rest_checks % config.rest_check_steps, 0) << "seed " << seed;
    EXPECT_GT(pile.object_steps.rest_checks, 0) << "seed " << seed;
    skipped += pile.skipped_objects;
  }
  EXPECT_GT(skipped, 0) << "no object was skipped on 8 tall piles: the pre-check never fired";
}

TEST(PileGenerator, DeterministicForASeed) {
  PileGenerator gen{PileConfig()};
  const Pile a = gen.generate(11), b = gen.generate(11);
  ASSERT_EQ(a.scene.objects.size(), b.scene.objects.size());
  for (size_t i = 0; i < a.scene.objects.size(); ++i) {
    EXPECT_TRUE(a.scene.objects[i].T_table_object.isApprox(b.scene.objects[i].T_table_object, 0.0));
  }
}

TEST(PileGenerator, RejectsScatteredObjects) {
  PileConfig config;
  PileGenerator gen(config);
  SuperquadricShape sq;
  sq.scale_m = Vec3::Constant(0.04);
  sq.exponents = Vec3::Constant(50);
  Scene scene;
  PhysicsWorld world;
  for (int i = 0; i < 2; ++i) {
    SceneObject o;
    o.shape = ObjectShape::fromSuperquadric(sq);
    o.T_table_object.translation() = Vec3(0.15 * i, 0, 0.04);
    world.addConvexObject(o.shape->hullPoints(), o.shape->volume(), o.T_table_object);
    scene.objects.push_back(o);
  }
  world.settle(500);
  std::string why;
  EXPECT_FALSE(gen.accept(scene, world, &why));
  EXPECT_NE(why.find("stack"), std::string::npos) << why;
  config.require_stack = false;
  EXPECT_TRUE(PileGenerator(config).accept(scene, world, &why)) << why;
}

TEST(PileGenerator, FitsTestsTheGridWithOrWithoutItsTop) {
  // A drop under way is checked without the grid's top (its object may still be falling from
  // above it), but a pile pushed out sideways fails either way.
  const PileGenerator gen{PileConfig()};
  SuperquadricShape sq;
  sq.scale_m = Vec3::Constant(0.05);
  sq.exponents = Vec3::Constant(2);
  Scene scene;
  for (int i = 0; i < 2; ++i) {
    SceneObject o;
    o.shape = ObjectShape::fromSuperquadric(sq);
    o.T_table_object.translation() = Vec3(0.0, 0.0, 0.05 + 0.10 * i);
    scene.objects.push_back(o);
  }
  std::string why;
  EXPECT_TRUE(gen.fits(scene, &why)) << why;
  scene.objects[1].T_table_object.translation().z() = 0.70;  // above the 0.60 m top
  EXPECT_FALSE(gen.fits(scene, &why));
  EXPECT_NE(why.find("taller"), std::string::npos) << why;
  why.clear();
  EXPECT_TRUE(gen.fits(scene, &why, false)) << why;
  scene.objects[0].T_table_object.translation() = Vec3(-0.2, 0.0, 0.05);  // spread sideways
  scene.objects[1].T_table_object.translation() = Vec3(0.4, 0.0, 0.05);
  for (bool top : {true, false}) {
    why.clear();
    EXPECT_FALSE(gen.fits(scene, &why, top));
    EXPECT_NE(why.find("wider"), std::string::npos) << why;
  }
}

TEST(PileGenerator, RespectsObjectRangeAndBadConfig) {
  PileConfig config;
  config.min_objects = 5;
  config.max_objects = 5;
  config.max_size_m = 0.12;
  const Pile pile = PileGenerator(config).generate(9);
  EXPECT_EQ(pile.scene.objects.size(), 5u);
  config.min_objects = 6;
  EXPECT_THROW(PileGenerator{config}, std::invalid_argument);
  config.min_objects = 5;
  config.rest_check_steps = 0;  // would switch off the settle rule's displacement limit
  EXPECT_THROW(PileGenerator{config}, std::invalid_argument);
}

TEST(YcbPiles, LoadCatalogueAndGenerate) {
  const std::string dir = std::string(SIMSTACK_SHARED_DATA) + "/ycb";
  if (const std::string missing = test::firstMissing(test::ycbMeshFiles(dir, ycbObjectNames()));
      !missing.empty())
    GTEST_SKIP() << missing << " not found (see ../shared/data/README.md)";
  const auto catalogue = loadMeshCatalogue(dir);
  ASSERT_EQ(catalogue.size(), 10u);
  // The cracker box is about 6 x 16 x 21 cm.
  EXPECT_NEAR(catalogue[1]->volume(), 0.06 * 0.158 * 0.21, 0.2 * 0.06 * 0.158 * 0.21);
  EXPECT_TRUE(catalogue[1]->containsObject(Vec3::Zero()));
  EXPECT_FALSE(catalogue[1]->containsObject(Vec3(0.2, 0.0, 0.0)));
  const Pile pile = PileGenerator(PileConfig(), catalogue).generate(4);
  ASSERT_GE(pile.scene.objects.size(), 3u);
  for (const auto& o : pile.scene.objects) EXPECT_GT(lowestPoint(o), -0.01);
  EXPECT_LT(displacementAfter(pile.scene, 240), 0.01);
  EXPECT_THROW(loadMeshCatalogue("/nonexistent"), std::runtime_error);
}

TEST(HouseholdPiles, ContainersKeepTheirCavityAndPilesSettle) {
  const auto containers = containerCatalogue();
  ASSERT_EQ(containers.size(), 32u);
  for (size_t i = 0; i < containers.size(); ++i) {
    const ObjectShape& c = *containers[i];
    EXPECT_EQ(c.catalogueIndex(), static_cast<int>(i));
    const auto spec = parseContainerName(c.name());
    ASSERT_TRUE(spec.has_value()) << c.name();
    // The object frame is centred on the volume; the base is the mesh's lowest point.
    Vec3 lo, hi;
    ASSERT_TRUE(c.mesh().bounds(&lo, &hi));
    EXPECT_NEAR(hi.z() - lo.z(), spec->height_m, 1e-9);
    EXPECT_FALSE(c.containsObject(Vec3(0.0, 0.0, lo.z() + 0.6 * spec->height_m))) << c.name();
    EXPECT_TRUE(c.containsObject(Vec3(0.0, 0.0, lo.z() + 0.5 * spec->wall_m))) << c.name();
  }
  EXPECT_EQ(containerCatalogue()[5]->name(), containers[5]->name());  // the same list each call
  PileConfig config;
  config.household_share = 1.0;
  config.require_stack = false;
  config.min_objects = 4;
  config.max_objects = 6;
  const PileGenerator generator(config);
  int meshes = 0, small = 0, still = 0;
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    const Pile pile = generator.generate(seed);
    for (const auto& o : pile.scene.objects) {
      EXPECT_GT(lowestPoint(o), -0.01);
      if (o.shape->kind() == ObjectShape::Kind::kMesh) {
        ++meshes;
        EXPECT_TRUE(parseContainerName(o.shape->name()).has_value());
      } else {
        small += o.shape->superquadric().scale_m.minCoeff() < 0.025;
      }
    }
    // The generator's rest rule holds; a cup on its side may still creep on (as a real one
    // rolls), so most piles, not all, stay within 1 cm over another 240 steps.
    Scene copy = pile.scene;
    EXPECT_TRUE(generator.verifyRest(&copy));
    still += displacementAfter(pile.scene, 240) < 0.01;
  }
  EXPECT_GE(still, 3);
  EXPECT_GT(meshes, 0);
  EXPECT_GT(small, 0);
  config.household_share = 1.5;
  EXPECT_THROW(PileGenerator{config}, std::invalid_argument);
  config.household_share = 0.5;
  EXPECT_THROW(PileGenerator(config, containers), std::invalid_argument);
}
