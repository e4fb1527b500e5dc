// The grasping module against scenes whose right answer is known from mechanics.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <random>
#include <string>

#include "simstack/grasping/grasp_ranking.h"
#include "simstack/grasping/grasp_request.h"
#include "simstack/grasping/grasp_settings.h"
#include "simstack/offline/piles/pile_generator.h"
#include "test_scenes.h"

namespace simstack {
namespace {

SuperquadricShape box(const Vec3& half_m, const Vec3& centre, double exponent = 20.0) {
  SuperquadricShape sq;
  sq.scale_m = half_m;
  sq.exponents = Vec3::Constant(exponent);
  sq.T_table_object.translation() = centre;
  return sq;
}

// A tall narrow box carrying a wide heavy one (the target). Dragging the target sideways puts
// its friction at the top of the narrow box, whose base is too small to resist the moment:
// mu m_top g h = 4.2 N x 0.12 m against (m_top + m_bottom) g w = 6.4 N x 0.03 m.
std::vector<SuperquadricShape> twoBoxStack() {
  return {box({0.03, 0.03, 0.06}, {0, 0, 0.06}), box({0.06, 0.06, 0.03}, {0, 0, 0.1505})};
}

// A box (the target, 0) beside a support of the same height, bridged by a third box that
// rests mostly on the support: sliding the target out leaves the bridge in place, lifting it
// raises the bridge's edge.
std::vector<SuperquadricShape> bridgedTarget() {
  return {box({0.05, 0.05, 0.03}, {-0.055, 0, 0.03}), box({0.05, 0.05, 0.03}, {0.055, 0, 0.03}),
          box({0.05, 0.04, 0.02}, {0.03, 0, 0.0805})};
}

PullOutcome pullAt(const std::vector<SuperquadricShape>& scene, int target, const Vec3& contact,
                   const Vec3& approach) {
  PullSimulator sim(scene, PullConfig());
  return sim.pullPerceived(target, contact, approach);
}

TEST(SuctionCandidates, RimOfAFlatFaceSealsAndASphereCapDeviatesByItsSagitta) {
  const SuperquadricShape b = box({0.05, 0.05, 0.05}, {0, 0, 0.05});
  EXPECT_LT(rimDeviation(b, {0, 0, 0.1}, Vec3::UnitZ(), 0.015, 16), 1e-4);
  EXPECT_TRUE(std::isinf(rimDeviation(b, {0.045, 0, 0.1}, Vec3::UnitZ(), 0.015, 16)));
  SuperquadricShape sphere;
  sphere.scale_m = Vec3::Constant(0.03);
  const double sagitta = 0.03 - std::sqrt(0.03 * 0.03 - 0.015 * 0.015);
  EXPECT_NEAR(rimDeviation(sphere, {0, 0, 0.03}, Vec3::UnitZ(), 0.015, 16), sagitta, 1e-5);
  const auto hit = enterSuperquadric(sphere, {0, 0, 1}, -Vec3::UnitZ(), 2.0);
  ASSERT_TRUE(hit.has_value());
  EXPECT_NEAR(hit->z(), 0.03, 1e-6);
  EXPECT_FALSE(enterSuperquadric(sphere, {0.05, 0, 1}, -Vec3::UnitZ(), 2.0).has_value());
}

TEST(SuctionCandidates, MeasuredPointsSealOnAFaceAndNotOverAnEdgeOrAGap) {
  // Depth points (2 mm noise) on the top and one side of a 10 cm box whose top is at z = 0.1.
  std::mt19937_64 rng(3);
  std::normal_distribution<double> noise(0.0, 0.002);
  Points3 top, with_side;
  for (double x = -0.05; x <= 0.05; x += 0.003)
    for (double y = -0.05; y <= 0.05; y += 0.003) top.emplace_back(x, y, 0.1 + noise(rng));
  with_side = top;
  for (double y = -0.05; y <= 0.05; y += 0.003)
    for (double z = 0.0; z <= 0.1; z += 0.003) with_side.emplace_back(0.05 + noise(rng), y, z);
  const CandidateConfig config;
  const MeasuredSeal middle = measuredSeal(with_side, {0, 0, 0.1}, Vec3(0.2, 0, 1), config);
  EXPECT_TRUE(middle.seen && middle.seals) << middle.deviation_m;
  EXPECT_GT(middle.normal.z(), 0.999);  // the measured face's normal, not the asked approach
  const MeasuredSeal edge = measuredSeal(with_side, {0.045, 0, 0.1}, Vec3::UnitZ(), config);
  EXPECT_TRUE(edge.seen);
  EXPECT_FALSE(edge.seals) << "over the box's edge: " << edge.deviation_m;
  Points3 holed;  // a gap under part of the rim: nothing for y > 0.008 near x = 0
  for (const Vec3& p : top)
    if (!(p.y() > 0.008 && std::abs(p.x()) < 0.02)) holed.push_back(p);
  const MeasuredSeal gap = measuredSeal(holed, {0, 0, 0.1}, Vec3::UnitZ(), config);
  EXPECT_TRUE(gap.seen);  // its middle was measured
  EXPECT_FALSE(gap.seals);
  // A cloud of layers 3 mm and more off the plane between them (a caller's, not a camera's), so
  // that no point lies within twice a 1 mm tolerance of the middle's plane: seen, and no seal,
  // not a plane of no point (a NaN contact) that seals.
  CandidateConfig strict;
  strict.seal_tolerance_m = 0.001;
  Points3 layers;
  for (int i = -21; i <= 21; ++i)
    for (int j = -21; j <= 21; ++j) {
      const bool middle_zone = std::hypot(i, j) <= 7.5;
      for (int level = -12; level <= 12; level += 3)
        if (level != 0 && (!middle_zone || std::abs(level) == 3))
          layers.emplace_back(0.001 * i, 0.001 * j, 0.1 + 0.001 * level);
    }
  const MeasuredSeal layered = measuredSeal(layers, {0, 0, 0.1}, Vec3::UnitZ(), strict);
  EXPECT_TRUE(layered.seen);
  EXPECT_FALSE(layered.seals) << layered.deviation_m << " at " << layered.centre.transpose();
  // A NaN point in a caller's cloud is no point: the face still seals.
  Points3 with_nan = top;
  with_nan.emplace_back(std::numeric_limits<double>::quiet_NaN(), 0.0, 0.1);
  EXPECT_TRUE(measuredSeal(with_nan, {0, 0, 0.1}, Vec3::UnitZ(), config).seals);
  // Nothing measured under the cup's middle: not seen, judged on the superquadric alone.
  EXPECT_FALSE(measuredSeal(top, {0.2, 0, 0.1}, Vec3::UnitZ(), config).seen);
  EXPECT_FALSE(measuredSeal({}, {0, 0, 0.1}, Vec3::UnitZ(), config).seen);
}

// A mug (radius 4 cm, 3 mm wall, 10 cm tall) estimated as a solid cylinder: looking down its
// mouth, the camera measured its wall's top and its inside bottom 8 cm below. The estimate's
// top face is where the camera looked through: no candidate there. A lid measured at the
// contact, or no camera known to have measured the points, leaves the candidates there.
TEST(SuctionCandidates, NoCandidateWhereTheCameraSawPastTheEstimate) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> noise(0.0, 0.001);
  Points3 mug;
  for (double a = 0; a < 2 * M_PI; a += 0.05)
    for (double r = 0.037; r <= 0.04; r += 0.0015) mug.emplace_back(r * cos(a), r * sin(a), 0.1);
  for (double x = -0.036; x <= 0.036; x += 0.003)
    for (double y = -0.036; y <= 0.036; y += 0.003)
      if (std::hypot(x, y) < 0.036) mug.emplace_back(x, y, 0.02 + noise(rng));
  const std::vector<Vec3> above{Vec3(0.05, 0.0, 1.0)};
  const Vec3 up = Vec3::UnitZ();
  EXPECT_TRUE(seenThrough(mug, {0, 0, 0.1}, up, above.front(), 0.015));
  EXPECT_TRUE(seenThrough(mug, {0.015, 0.01, 0.1}, up, above.front(), 0.015));
  EXPECT_FALSE(seenThrough(mug, {0.0385, 0, 0.1}, up, above.front(), 0.015));  // the wall's top
  Points3 lid = mug;  // a lid measured too: a surface at the contact
  for (double x = -0.036; x <= 0.036; x += 0.003)
    for (double y = -0.036; y <= 0.036; y += 0.003)
      if (std::hypot(x, y) < 0.036) lid.emplace_back(x, y, 0.1 + noise(rng));
  EXPECT_FALSE(seenThrough(lid, {0, 0, 0.1}, up, above.front(), 0.015));

  SuperquadricShape cylinder = box({0.04, 0.04, 0.05}, {0, 0, 0.05}, 2.0);
  cylinder.exponents.z() = 20.0;
  CandidateConfig config;
  config.max_candidates = 256;
  const CandidateSet open = suctionCandidates({cylinder}, 0, above, config, mug, above.front());
  const CandidateSet closed = suctionCandidates({cylinder}, 0, above, config, lid, above.front());
  // Without the camera that measured the points, or with one at the table's origin (a pose
  // left at the identity), nothing is known to be seen through.
  const CandidateSet unknown = suctionCandidates({cylinder}, 0, above, config, mug);
  const CandidateSet origin =
      suctionCandidates({cylinder}, 0, above, config, mug, Vec3(0.0, 0.0, 0.0));
  const auto on_mouth = [](const CandidateSet& set) {
    int n = 0;
    for (const SuctionCandidate& c : set.candidates)
      n += c.contact_table.z() > 0.095 && c.contact_table.head<2>().norm() < 0.03;
    return n;
  };
  EXPECT_EQ(on_mouth(open), 0);
  EXPECT_GT(open.seen_through, 0);
  EXPECT_GT(on_mouth(closed), 0);
  EXPECT_GT(on_mouth(unknown), 0);
  EXPECT_GT(on_mouth(origin), 0);
  EXPECT_EQ(origin.seen_through, 0);
  // The ranking says how many it left out.
  GraspRankingConfig ranking;
  ranking.candidates.max_candidates = 4;
  const GraspRanking r = rankGrasps({{cylinder}}, 0, above, ranking, {}, mug, above.front());
  EXPECT_NE(r.message.find(std::to_string(r.candidates.seen_through) +
                           " sealable places left out where the camera saw past the shape"),
            std::string::npos)
      << r.message;
}

// A solid box (10 cm) seen from the side and above, its faces measured 2.5 mm apart.
// A contact on the fit, 8 mm proud of the front face and seen at 60 degrees, has a dozen of
// that face's points beyond it along the line of sight, but none a cup's radius inside the
// surface: not seen through. Nor
// is a contact on a side face the line of sight grazes, whose own points lie beyond it.
TEST(SuctionCandidates, ASolidObjectsOwnFacesAreNotSeenThrough) {
  Points3 box;
  for (double u = -0.05; u <= 0.05; u += 0.0025)
    for (double v = 0.0; v <= 0.1; v += 0.0025) {
      box.emplace_back(0.05, u, v);  // the front face, x = 0.05
      box.emplace_back(u, 0.05, v);  // a side face, y = 0.05
    }
  for (double u = -0.05; u <= 0.05; u += 0.0025)
    for (double v = -0.05; v <= 0.05; v += 0.0025) box.emplace_back(u, v, 0.1);  // the top
  const Vec3 front = Vec3::UnitX(), side = Vec3::UnitY();
  const Vec3 contact(0.058, 0.0, 0.05);
  const Vec3 at_60 = contact + 0.8 * Vec3(std::cos(M_PI / 3), 0.0, std::sin(M_PI / 3));
  EXPECT_FALSE(seenThrough(box, contact, front, at_60, 0.015));
  const Vec3 on_side(0.0, 0.05, 0.05);
  const Vec3 grazing = on_side + 0.8 * Vec3(0.99, 0.0, 0.14).normalized();
  EXPECT_FALSE(seenThrough(box, on_side, side, grazing, 0.015));
  // A line of sight through the closed top of an estimate whose object is open, only its floor
  // 9 cm below measured (an open box): seen through, the floor lies inside the surface.
  Points3 hollow;
  for (double u = -0.05; u <= 0.05; u += 0.0025)
    for (double v = -0.05; v <= 0.05; v += 0.0025) hollow.emplace_back(u, v, 0.01);
  EXPECT_TRUE(seenThrough(hollow, Vec3(0.0, 0.0, 0.1), Vec3::UnitZ(), Vec3(0.3, 0.0, 0.9), 0.015));
}

TEST(GraspRanking, CandidatesOnMeasuredSurfaceTakeItsNormal) {
  // The top box of the stack, its top face measured 4 degrees off the superquadric's (the
  // fit's error): candidates there approach along the measured face's normal.
  const std::vector<SuperquadricShape> stack = twoBoxStack();
  const SuperquadricShape& target = stack[1];
  const Vec3 top = target.T_table_object.translation() + Vec3(0, 0, target.scale_m.z());
  const Mat3 tilt = Eigen::AngleAxisd(4.0 * M_PI / 180.0, Vec3::UnitX()).toRotationMatrix();
  Points3 measured;
  for (double x = -target.scale_m.x(); x <= target.scale_m.x(); x += 0.003)
    for (double y = -target.scale_m.y(); y <= target.scale_m.y(); y += 0.003)
      measured.push_back(top + tilt * Vec3(x, y, 0));
  GraspRankingConfig config;
  config.candidates.max_candidates = 8;
  const GraspRanking r = rankGrasps({stack}, 1, {}, config, {}, measured);
  ASSERT_FALSE(r.grasps.empty()) << r.message;
  EXPECT_GT(r.candidates.measured, 0);
  int measured_grasps = 0;
  for (const RankedGrasp& g : r.grasps) {
    if (!g.candidate.measured) continue;
    ++measured_grasps;
    EXPECT_GT(g.candidate.approach_table.dot(tilt * Vec3::UnitZ()), std::cos(0.5 * M_PI / 180));
  }
  EXPECT_GT(measured_grasps, 0);
  // The ranking reads a cloud of over kMaxMeasuredPoints thinned, and says so (few surface
  // samples: every seal test reads every point kept).
  Points3 dense;
  while (dense.size() <= kMaxMeasuredPoints)
    dense.insert(dense.end(), measured.begin(), measured.end());
  GraspRankingConfig quick = config;
  quick.candidates.surface_samples = 100;
  const GraspRanking thinned = rankGrasps({stack}, 1, {}, quick, {}, dense);
  EXPECT_NE(thinned.message.find("seals judged on one in 2 of the"), std::string::npos)
      << thinned.message;
  EXPECT_GT(thinned.candidates.measured, 0);
  // Without the points, the same candidates keep the superquadric's normal.
  const GraspRanking plain = rankGrasps({stack}, 1, {}, config);
  ASSERT_FALSE(plain.grasps.empty());
  EXPECT_FALSE(plain.grasps.front().candidate.measured);
}

TEST(GraspRanking, ACloudOfMillionsIsThinnedForTheSealsAndSaid) {
  // Up to kMaxMeasuredPoints the seals read every point; a cloud of more (a request's, or fused
  // HD views) is read every k-th point, spread over all of it, and the message says so.
  Points3 cloud(kMaxMeasuredPoints);
  for (size_t i = 0; i < cloud.size(); ++i) cloud[i] = Vec3(1e-6 * i, 0, 0);
  Points3 thinned;
  std::string message;
  EXPECT_EQ(&sealPoints(cloud, &thinned, &message), &cloud);
  EXPECT_TRUE(message.empty()) << message;
  cloud.resize(3 * kMaxMeasuredPoints - 1);
  for (size_t i = kMaxMeasuredPoints; i < cloud.size(); ++i) cloud[i] = Vec3(1e-6 * i, 0, 0);
  const Points3& read = sealPoints(cloud, &thinned, &message);
  EXPECT_EQ(&read, &thinned);
  EXPECT_EQ(read.size(), kMaxMeasuredPoints);
  EXPECT_EQ(read[1], cloud[3]);
  EXPECT_EQ(read.back(), cloud[3 * (kMaxMeasuredPoints - 1)]);
  EXPECT_NE(message.find("seals judged on one in 3 of the 1499999 measured points"),
            std::string::npos)
      << message;
}

TEST(GraspRanking, PerturbedCopiesMoveEveryObjectAndStayOnTheTable) {
  const std::vector<SuperquadricShape> stack = twoBoxStack();
  PerturbationConfig p;
  p.copies = 3;
  const auto copies = perturbedCopies(stack, p);
  ASSERT_EQ(copies.size(), 3u);
  for (const auto& copy : copies) {
    ASSERT_EQ(copy.size(), stack.size());
    EXPECT_GE(sceneBottom(copy), sceneBottom(stack) - 1e-9);  // nothing pushed into the table
    for (size_t i = 0; i < copy.size(); ++i)
      EXPECT_FALSE(copy[i].T_table_object.isApprox(stack[i].T_table_object, 1e-9)) << i;
  }
  EXPECT_TRUE(perturbedCopies(stack, p)[1][0].T_table_object.isApprox(
      copies[1][0].T_table_object));  // the same seed, the same copies
  // Ranked with them: every candidate is pulled in the scene and in each copy.
  GraspRankingConfig config;
  config.candidates.max_candidates = 4;
  config.perturbation = p;
  const GraspRanking r = rankGrasps({stack}, 1, {}, config);
  ASSERT_FALSE(r.grasps.empty()) << r.message;
  EXPECT_EQ(r.hypotheses.size(), 4u);
  EXPECT_EQ(r.grasps.front().outcomes.size(), 4u);
  for (const RankedGrasp& g : r.grasps) {
    int held = 0;
    for (size_t k = 1; k < g.outcomes.size(); ++k) held += g.outcomes[k].cup_held ? 1 : 0;
    EXPECT_DOUBLE_EQ(g.copies_held_share, held / 3.0);
  }
  config.perturbation.copies = 0;
  EXPECT_TRUE(std::isnan(rankGrasps({stack}, 1, {}, config).grasps.front().copies_held_share));
  p.copies = 65;
  EXPECT_THROW(p.validate(), std::invalid_argument);
}

TEST(SuctionCandidates, ASphereSealsLessThanABoxFace) {
  CandidateConfig config;
  // A 6 cm ball: the cap under a 15 mm cup is 4 mm high, over the 3 mm tolerance.
  const std::vector<SuperquadricShape> sphere{box({0.03, 0.03, 0.03}, {0, 0, 0.03}, 2.0)};
  const std::vector<SuperquadricShape> cube{box({0.03, 0.03, 0.03}, {0, 0, 0.03}, 20.0)};
  const CandidateSet s = suctionCandidates(sphere, 0, defaultCameraPositions(sphere), config);
  const CandidateSet c = suctionCandidates(cube, 0, defaultCameraPositions(cube), config);
  EXPECT_GT(s.visible, 0);
  EXPECT_GT(c.sealable, 2 * s.sealable) << s.sealable << " of " << s.visible << " on the sphere, "
                                        << c.sealable << " of " << c.visible << " on the box";
  for (const SuctionCandidate& k : c.candidates) {
    EXPECT_GT((k.contact_table + config.tool_length_m * k.approach_table).z(), 0.0);
    EXPECT_LE(k.rim_deviation_m, config.seal_tolerance_m);
  }
}

TEST(SuctionPull, LiftingTheTopBoxBeatsDraggingItSideways) {
  const auto scene = twoBoxStack();
  const PullOutcome up = pullAt(scene, 1, {0, 0, 0.1805}, Vec3::UnitZ());
  const PullOutcome side = pullAt(scene, 1, {0.06, 0, 0.1505}, Vec3::UnitX());
  EXPECT_TRUE(up.cup_held);
  EXPECT_TRUE(up.target_freed);
  EXPECT_LT(up.mean_displacement_m, 0.005);
  EXPECT_GT(side.mean_displacement_m, 3.0 * up.mean_displacement_m);
}

TEST(SuctionPull, SlidingASupportOutBeatsLiftingIt) {
  const auto scene = bridgedTarget();
  const PullOutcome lift = pullAt(scene, 0, {-0.08, 0, 0.06}, Vec3::UnitZ());
  const PullOutcome slide = pullAt(scene, 0, {-0.105, 0, 0.03}, -Vec3::UnitX());
  EXPECT_TRUE(slide.cup_held);
  EXPECT_LT(slide.mean_displacement_m, lift.mean_displacement_m);
}

TEST(GraspRanking, RanksAStraightLiftFirstOnTheStack) {
  GraspRankingConfig config;
  config.candidates.max_candidates = 16;
  const GraspRanking r = rankGrasps({twoBoxStack()}, 1, {}, config);
  ASSERT_FALSE(r.grasps.empty()) << r.message;
  EXPECT_GT(r.grasps.front().candidate.approach_table.z(), 0.9);
}

TEST(SuctionCandidates, ThePullsThroughTheCentreOfMassAreAmongThem) {
  // A wide box: the spread keeps the candidates whose pull passes through its centre, or a
  // cup's radius from it, on every face in sight and in reach (not the bottom), the centres
  // first.
  const std::vector<SuperquadricShape> stack = twoBoxStack();
  CandidateConfig config;
  config.max_candidates = 32;
  const CandidateSet set = suctionCandidates(stack, 1, defaultCameraPositions(stack), config);
  int through = 0, near = 0;
  for (const SuctionCandidate& c : set.candidates) {
    const Vec3 arm = stack[1].centroid() - c.contact_table;
    const double offset = arm.cross(c.approach_table).norm();
    through += offset < 1e-6 ? 1 : 0;
    near += std::abs(offset - config.cup_radius_m) < 1e-3 ? 1 : 0;
  }
  EXPECT_EQ(through, 5) << "the top and four sides";
  EXPECT_GE(near, 4) << "a cup's radius around the top's middle";
  EXPECT_EQ(set.candidates.size(), 32u);
  config.max_candidates = 5;
  const CandidateSet few = suctionCandidates(stack, 1, defaultCameraPositions(stack), config);
  EXPECT_EQ(few.candidates.size(), 5u);
  for (const SuctionCandidate& c : few.candidates) {
    const Vec3 arm = stack[1].centroid() - c.contact_table;
    EXPECT_LT(arm.cross(c.approach_table).norm(), 1e-6) << "a few candidates: the centres";
  }
  config.max_candidates = 64;
  int top_ring = 0;
  for (const SuctionCandidate& c :
       suctionCandidates(stack, 1, defaultCameraPositions(stack), config).candidates) {
    const Vec3 arm = stack[1].centroid() - c.contact_table;
    const double offset = arm.cross(c.approach_table).norm();
    top_ring += c.approach_table.z() > 0.99 && std::abs(offset - 2.0 * config.cup_radius_m) < 1e-3;
  }
  EXPECT_EQ(top_ring, 8) << "two cup radii around the top's middle, all round";
}

TEST(SuctionCandidates, FewCandidatesAreTheUpperFacesMiddlesWhateverTheAxesOrder) {
  // The top box of the stack, turned so that each of its axes in turn points up: one or two
  // candidates are the top's middle, then the most upward side's, not the sides of the axes
  // listed first.
  for (int up = 0; up < 3; ++up)
    for (double sign : {1.0, -1.0}) {
      std::vector<SuperquadricShape> stack = twoBoxStack();
      SuperquadricShape& top = stack[1];
      // A cube, so that the turn changes no contact: only which axis is up.
      top.scale_m = Vec3::Constant(0.03);
      top.T_table_object.translation().z() = 0.15;
      top.T_table_object.linear() =
          Eigen::Quaterniond::FromTwoVectors(sign * Vec3::Unit(up), Vec3::UnitZ())
              .toRotationMatrix();
      CandidateConfig config;
      config.max_candidates = 1;
      const CandidateSet one = suctionCandidates(stack, 1, defaultCameraPositions(stack), config);
      ASSERT_EQ(one.candidates.size(), 1u);
      EXPECT_GT(one.candidates[0].approach_table.z(), 0.99) << "axis " << up << " sign " << sign;
      EXPECT_NEAR(one.candidates[0].contact_table.z(), 0.18, 1e-4);
    }
}

TEST(SuctionCandidates, APlateThinnerThanTheSealSearchSeals) {
  // The rim search reaches 4 mm below the cup's plane: a plate thinner than that lies between
  // its start and its end.
  for (double half_mm : {0.5, 1.0, 1.5, 2.5}) {
    const std::vector<SuperquadricShape> plate{
        box({0.05, 0.05, half_mm * 1e-3}, {0, 0, half_mm * 1e-3})};
    const CandidateSet set =
        suctionCandidates(plate, 0, defaultCameraPositions(plate), CandidateConfig());
    int top = 0;
    for (const SuctionCandidate& c : set.candidates) top += c.approach_table.z() > 0.99;
    EXPECT_GT(top, 0) << half_mm << " mm: " << set.sealable << " of " << set.visible << " seal";
  }
}

TEST(GraspRanking, ACandidateCarriedOntoATallerEstimateLandsOnItsTop) {
  // The same footprint 10 and 30 cm tall: the top's middle of the low one, carried along its
  // approach, lands on the tall one's top, not inside it.
  const SuperquadricShape low = box({0.2, 0.2, 0.05}, {0, 0, 0.05});
  const SuperquadricShape tall = box({0.2, 0.2, 0.15}, {0, 0, 0.15});
  SuctionCandidate c;
  c.contact_table = Vec3(0.02, 0.01, 0.1);
  c.approach_table = Vec3::UnitZ();
  for (const auto& [shape, top] : {std::pair{low, 0.1}, std::pair{tall, 0.3}}) {
    const std::optional<Vec3> at = carryCandidate(c, shape, 0.05);
    ASSERT_TRUE(at);
    EXPECT_NEAR(at->z(), top, 1e-4);
    EXPECT_NEAR(at->x(), 0.02, 1e-9);
  }
  c.contact_table.x() = 0.5;  // beside both
  EXPECT_FALSE(carryCandidate(c, tall, 0.05));
}

TEST(SuctionPull, OverlappingEstimatesArePushedApartNotShotApart) {
  // Two boxes side by side, overlapping by 2 cm (an estimate's): settling separates them by
  // about the overlap, each moving half of it (a correction that added velocity would throw
  // each 2.5 cm), and the ranking says how far they moved.
  const std::vector<SuperquadricShape> overlap{box({0.04, 0.04, 0.03}, {-0.03, 0, 0.03}),
                                               box({0.04, 0.04, 0.03}, {0.03, 0, 0.03})};
  PullSimulator sim(overlap, PullConfig());
  EXPECT_GT(sim.drift().presettle_displacement_m, 0.008);
  EXPECT_LT(sim.drift().presettle_displacement_m, 0.015);
  GraspRankingConfig config;
  config.candidates.max_candidates = 2;
  const GraspRanking r = rankGrasps({overlap}, 0, {}, config);
  EXPECT_NE(r.message.find("moved up to"), std::string::npos) << r.message;
  EXPECT_NE(r.message.find("while settling before the pulls"), std::string::npos) << r.message;
  // A scene at rest as given: no such note, also when the perturbed copies (shifted, turned and
  // resized at random: overlapping or floating) move as they settle.
  const GraspRanking apart = rankGrasps({twoBoxStack()}, 1, {}, config);
  EXPECT_EQ(apart.message.find("while settling"), std::string::npos) << apart.message;
  config.perturbation.copies = 4;
  const GraspRanking copied = rankGrasps({twoBoxStack()}, 1, {}, config);
  EXPECT_EQ(copied.message.find("while settling"), std::string::npos) << copied.message;
  double copies_moved = 0.0;
  for (size_t k = 1; k < copied.baseline.size(); ++k)
    copies_moved = std::max(copies_moved, copied.baseline[k].presettle_displacement_m);
  EXPECT_GT(copies_moved, SceneDrift::kMovedWhileSettling_m);
}

TEST(GraspRanking, TiesGoToThePullNearerTheCentreOfMass) {
  GraspRankingConfig config;
  config.candidates.max_candidates = 16;
  const std::vector<SuperquadricShape> stack = twoBoxStack();
  const GraspRanking r = rankGrasps({stack}, 1, {}, config);
  ASSERT_FALSE(r.grasps.empty()) << r.message;
  for (const RankedGrasp& g : r.grasps) {  // the arm: the centre's distance from the pull line
    const Vec3 arm = stack[1].centroid() - g.candidate.contact_table;
    EXPECT_NEAR(g.com_offset_m, arm.cross(g.candidate.approach_table).norm(), 1e-9);
  }
  RankedGrasp near = r.grasps.front(), far = near;
  near.com_offset_m = 0.004, far.com_offset_m = 0.02;
  near.peak_load = 0.9, far.peak_load = 0.1;  // the centre decides before the load
  EXPECT_TRUE(rankedBefore(near, far));
  EXPECT_FALSE(rankedBefore(far, near));
  far.com_offset_m = 0.0042;  // within the same millimetre: the lower load
  EXPECT_TRUE(rankedBefore(far, near));
}

TEST(GraspRanking, AnUpwardPullRanksBeforeASidewaysOneThatDoesAsWell) {
  RankedGrasp up, side;
  up.outcomes.resize(1), side.outcomes.resize(1);
  up.freed_share = side.freed_share = 1.0;
  up.candidate.approach_table = Vec3(0.3, 0.0, 0.954).normalized();  // 0.95 up: tenth 10
  side.candidate.approach_table = Vec3(1.0, 0.0, 0.0);
  up.score_m = 0.02, side.score_m = 0.001;  // the sideways pull moves the others less
  up.com_offset_m = 0.03, side.com_offset_m = 0.0;
  EXPECT_TRUE(rankedBefore(up, side));
  EXPECT_FALSE(rankedBefore(side, up));
  // Within one tenth the displacement decides.
  side.candidate.approach_table = Vec3(0.25, 0.0, 0.968).normalized();
  EXPECT_TRUE(rankedBefore(side, up));
  // Freeing the target and fewer topples come first.
  side.candidate.approach_table = Vec3(1.0, 0.0, 0.0);
  up.freed_share = 0.0;
  EXPECT_TRUE(rankedBefore(side, up));
  up.freed_share = 1.0, up.mean_toppled = 1.0;
  EXPECT_TRUE(rankedBefore(side, up));
}

TEST(GraspRanking, ASealTheCameraSawRanksBeforeAGuessedOneThatDoesAsWell) {
  RankedGrasp seen, guessed;
  seen.outcomes.resize(1), guessed.outcomes.resize(1);
  seen.freed_share = guessed.freed_share = 1.0;
  seen.candidate.measured = true;
  seen.candidate.approach_table = Vec3(1.0, 0.0, 0.0);  // sideways, and it moves the others more
  guessed.candidate.approach_table = Vec3::UnitZ();
  seen.score_m = 0.02, guessed.score_m = 0.001;
  EXPECT_TRUE(rankedBefore(seen, guessed));
  EXPECT_FALSE(rankedBefore(guessed, seen));
  // The pull's predicted outcome comes first: a guessed seal that frees the target ranks before
  // a seen one that does not.
  seen.freed_share = 0.0;
  EXPECT_TRUE(rankedBefore(guessed, seen));
}

TEST(GraspRanking, RanksASlideOutFirstUnderABridge) {
  GraspRankingConfig config;
  config.candidates.max_candidates = 16;
  const GraspRanking r = rankGrasps({bridgedTarget()}, 0, {}, config);
  ASSERT_FALSE(r.grasps.empty()) << r.message;
  EXPECT_LT(std::abs(r.grasps.front().candidate.approach_table.z()), 0.5);
}

// 33 of 40 generated piles (docs/experiments.md, "Grasp ranking"); these eight all do.
TEST(GraspRanking, TruePilesLeftAloneMoveUnderTwoMillimetres) {
  PileGenerator gen{PileConfig()};
  for (uint64_t seed : {1, 2, 3, 4, 5, 6, 8, 9}) {
    std::vector<SuperquadricShape> shapes;
    for (const SceneObject& o : gen.generate(seed).scene.objects)
      shapes.push_back(o.superquadricTable());
    PullSimulator sim(shapes, PullConfig());
    EXPECT_LT(sim.drift().max_displacement_m, 0.002) << "pile " << seed;
  }
}

std::vector<SuperquadricShape> fourObjects() {
  std::vector<SuperquadricShape> shapes;
  for (const SceneObject& o : test::fourObjectPile().objects)
    shapes.push_back(o.superquadricTable());
  return shapes;
}

bool sameRanking(const GraspRanking& a, const GraspRanking& b) {
  if (a.grasps.size() != b.grasps.size()) return false;
  for (size_t i = 0; i < a.grasps.size(); ++i) {
    const RankedGrasp &x = a.grasps[i], &y = b.grasps[i];
    if (x.candidate.contact_table != y.candidate.contact_table || x.score_m != y.score_m ||
        x.max_displacement_m != y.max_displacement_m || x.failed_share != y.failed_share)
      return false;
  }
  return true;
}

TEST(GraspRanking, IdenticalAcrossRunsAndThreadCounts) {
  GraspRankingConfig config;
  config.candidates.max_candidates = 12;
  auto other = fourObjects();
  other[2].T_table_object.translation() += Vec3(0.01, -0.005, 0.002);  // a second hypothesis
  const std::vector<std::vector<SuperquadricShape>> scenes{fourObjects(), other};
  config.threads = 1;
  const GraspRanking one = rankGrasps(scenes, 2, {}, config);
  config.threads = 2;
  const GraspRanking two = rankGrasps(scenes, 2, {}, config);
  const GraspRanking again = rankGrasps(scenes, 2, {}, config);
  ASSERT_EQ(one.grasps.size(), 12u);
  EXPECT_EQ(one.pulls, 24);
  EXPECT_TRUE(sameRanking(one, two));
  EXPECT_TRUE(sameRanking(two, again));
  for (const RankedGrasp& g : one.grasps) {
    ASSERT_EQ(g.outcomes.size(), 2u);
    EXPECT_GE(g.worst_displacement_m, g.mean_displacement_m);
  }
  for (size_t i = 1; i < one.grasps.size(); ++i)
    EXPECT_LE(one.grasps[i - 1].failed_share, one.grasps[i].failed_share);
}

TEST(GraspRanking, IdenticalWhateverTheOrderTheObjectsAreListedIn) {
  // The perception lists a still pile's objects in another order from frame to frame.
  GraspRankingConfig config;
  config.candidates.max_candidates = 12;
  const std::vector<SuperquadricShape> listed = fourObjects();
  const std::vector<SuperquadricShape> reversed(listed.rbegin(), listed.rend());
  const GraspRanking a = rankGrasps({listed}, 2, {}, config);
  const GraspRanking b = rankGrasps({reversed}, 1, {}, config);
  ASSERT_EQ(a.grasps.size(), 12u);
  EXPECT_TRUE(sameRanking(a, b));
}

TEST(GraspRanking, ProgressCountsEveryPullAndAStopEndsTheRankingWithinOnePullPerThread) {
  GraspRankingConfig config;
  config.candidates.max_candidates = 12;
  config.threads = 2;
  auto other = fourObjects();
  other[2].T_table_object.translation() += Vec3(0.01, -0.005, 0.002);
  const std::vector<std::vector<SuperquadricShape>> scenes{fourObjects(), other};
  int calls = 0, last_done = 0, total = 0;
  std::optional<RankedGrasp> last_best;
  const GraspRanking full =
      rankGrasps(scenes, 2, {}, config, [&](int done, int all, const RankedGrasp* best) {
        ++calls;
        EXPECT_GT(done, last_done);
        last_done = done, total = all;
        if (best) last_best = *best;
        return true;
      });
  EXPECT_FALSE(full.stopped);
  EXPECT_EQ(calls, 24);
  EXPECT_EQ(total, 24);
  ASSERT_TRUE(last_best.has_value());
  EXPECT_TRUE(last_best->candidate.contact_table.isApprox(full.grasps[0].candidate.contact_table));
  // Stopped at the fifth pull: at most one more pull per thread finishes, and only candidates
  // whose every pull was done are ranked.
  const GraspRanking cut =
      rankGrasps(scenes, 2, {}, config, [](int done, int, const RankedGrasp*) { return done < 5; });
  EXPECT_TRUE(cut.stopped);
  EXPECT_GE(cut.pulls, 5);
  EXPECT_LE(cut.pulls, 5 + config.threads);
  EXPECT_LE(cut.grasps.size(), static_cast<size_t>(cut.pulls / 2));
  EXPECT_NE(cut.message.find("stopped after"), std::string::npos) << cut.message;
}

TEST(GraspRanking, AHypothesisWithoutTheTargetIsLeftOutAndSaidSo) {
  GraspRankingConfig config;
  config.candidates.max_candidates = 4;
  auto far = fourObjects();
  far.erase(far.begin() + 2);  // the target is missing from this hypothesis
  const GraspRanking r = rankGrasps({fourObjects(), far}, 2, {}, config);
  EXPECT_EQ(r.hypotheses, std::vector<int>{0});
  EXPECT_NE(r.message.find("left out"), std::string::npos) << r.message;
  EXPECT_EQ(r.baseline.size(), 1u);
}

TEST(GraspRanking, ATargetTooHeavyForTheCupSaysThatNoGraspHeld) {
  // A 60 cm cube of the simulation's density is far beyond a 30 N cup: a list ranked best first
  // must not read as if its first grasp were a good one.
  GraspRankingConfig config;
  config.candidates.max_candidates = 4;
  const std::vector<SuperquadricShape> crate{box({0.3, 0.3, 0.3}, {0, 0, 0.3})};
  const GraspRanking r = rankGrasps({crate}, 0, {}, config);
  ASSERT_EQ(r.grasps.size(), 4u);
  for (const RankedGrasp& g : r.grasps) EXPECT_EQ(g.failed_share, 1.0);
  EXPECT_NE(r.message.find("none of the 4 grasps held"), std::string::npos) << r.message;
  // The same light box in one hypothesis and a slab of 7 kg of the same height in another: pulls
  // that hold in the first break in the second, and no grasp held in every hypothesis.
  const std::vector<SuperquadricShape> slab{box({0.3, 0.3, 0.02}, {0, 0, 0.02})};
  const std::vector<SuperquadricShape> small{box({0.04, 0.03, 0.02}, {0, 0, 0.02})};
  const GraspRanking mixed = rankGrasps({small, slab}, 0, {}, config);
  ASSERT_FALSE(mixed.grasps.empty());
  EXPECT_LT(mixed.grasps.front().failed_share, 1.0);
  for (const RankedGrasp& g : mixed.grasps) EXPECT_GT(g.failed_share, 0.0);
  EXPECT_NE(mixed.message.find("no grasp held in every hypothesis"), std::string::npos)
      << mixed.message;
  EXPECT_EQ(mixed.message.find("none of the"), std::string::npos) << mixed.message;
  // A light box on its own comes free: nothing to say.
  const std::vector<SuperquadricShape> light{box({0.04, 0.03, 0.02}, {0, 0, 0.02})};
  const GraspRanking ok = rankGrasps({light}, 0, {}, config);
  ASSERT_FALSE(ok.grasps.empty());
  EXPECT_GT(ok.grasps.front().freed_share, 0.0);
  EXPECT_EQ(ok.message, "");
  // Six hypotheses (three scenes and three copies, say): a grasp that fails, or frees the target,
  // in all six does so with a share of exactly 1 (six sixths added up make 0.9999999999999999).
  const GraspRanking heavy6 =
      rankGrasps(std::vector<std::vector<SuperquadricShape>>(6, crate), 0, {}, config);
  ASSERT_EQ(heavy6.grasps.size(), 4u);
  for (const RankedGrasp& g : heavy6.grasps) EXPECT_EQ(g.failed_share, 1.0);
  EXPECT_NE(heavy6.message.find("none of the 4 grasps held"), std::string::npos) << heavy6.message;
  const GraspRanking light6 =
      rankGrasps(std::vector<std::vector<SuperquadricShape>>(6, light), 0, {}, config);
  ASSERT_FALSE(light6.grasps.empty());
  EXPECT_EQ(light6.grasps.front().freed_share, 1.0);
  EXPECT_TRUE(light6.grasps.front().freed());
}

TEST(GraspRanking, AListWhoseHeldGraspsFreeTheTargetInFewerHypothesesSaysSo) {
  const auto grasp = [](double failed, double freed) {
    RankedGrasp g;
    g.outcomes.resize(3);
    g.failed_share = failed;
    g.freed_share = freed;
    return g;
  };
  // Held everywhere but freeing in no hypothesis, before one that frees in two of three and
  // slips in the third: the first grasp with held true would leave the target in place.
  const std::string note = outcomeNote({grasp(0.0, 0.0), grasp(1.0 / 3, 2.0 / 3)});
  EXPECT_NE(note.find("no grasp both held and freed the target in every hypothesis"),
            std::string::npos)
      << note;
  // One that holds and frees everywhere: nothing to say.
  EXPECT_EQ(outcomeNote({grasp(0.0, 1.0), grasp(0.0, 0.0)}), "");
  // None freed anywhere, or none held everywhere: the notes of their own, not this one.
  EXPECT_EQ(outcomeNote({grasp(0.0, 0.0)}).find("both held and freed"), std::string::npos);
  EXPECT_EQ(outcomeNote({grasp(1.0 / 3, 2.0 / 3)}).find("both held and freed"), std::string::npos);
}

TEST(GraspRanking, TheSceneBottomIsItsLowestSurface) {
  std::vector<SuperquadricShape> pile = fourObjects();
  EXPECT_NEAR(sceneBottom(pile), 0.0, 1e-3);
  for (SuperquadricShape& sq : pile) sq.T_table_object.translation().z() += 0.7;
  EXPECT_NEAR(sceneBottom(pile), 0.7, 1e-3);
  EXPECT_EQ(sceneBottom({}), std::numeric_limits<double>::infinity());
}

TEST(GraspRanking, ATargetWithNoSealableSurfaceGivesNoGraspsAndSaysWhy) {
  const std::vector<SuperquadricShape> ball{box({0.02, 0.02, 0.02}, {0, 0, 0.02}, 2.0)};
  const GraspRanking r = rankGrasps({ball}, 0, {}, GraspRankingConfig());
  EXPECT_TRUE(r.grasps.empty());
  EXPECT_NE(r.message.find("no sealable surface"), std::string::npos) << r.message;
}

TEST(GraspRanking, RejectsBadScenesAndSettings) {
  const auto good = fourObjects();
  const GraspRankingConfig config;
  const auto rejects = [&](const std::vector<SuperquadricShape>& scene, int target,
                           const GraspRankingConfig& c, const std::string& expected) {
    try {
      rankGrasps({scene}, target, {}, c);
      ADD_FAILURE() << "accepted: " << expected;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  };
  rejects(good, 7, config, "target 7");
  rejects(good, -1, config, "target -1");
  auto bad = good;
  bad[1].scale_m.x() = std::nan("");
  rejects(bad, 0, config, "object 1: semi-axes");
  bad = good, bad[1].scale_m.y() = 0.0;
  rejects(bad, 0, config, "object 1: semi-axes");
  bad = good, bad[3].scale_m.z() = -0.1;
  rejects(bad, 0, config, "object 3: semi-axes");
  bad = good, bad[0].exponents.x() = 0.5;
  rejects(bad, 1, config, "object 0: exponents");
  bad = good, bad[0].exponents.y() = std::numeric_limits<double>::infinity();
  rejects(bad, 1, config, "object 0: exponents");
  bad = good, bad[2].T_table_object.linear() *= 1.5;
  rejects(bad, 0, config, "object 2: orientation");
  bad = good, bad[2].T_table_object.translation().x() = std::nan("");
  rejects(bad, 0, config, "object 2: pose");
  bad = std::vector<SuperquadricShape>(1000, good[0]);  // hours of pulls for one request
  rejects(bad, 0, config, "the scene's 1000 objects: at most");
  GraspRankingConfig c = config;
  c.pull.pull_distance_m = 0.0;
  rejects(good, 0, c, "pull_distance_m");
  c = config, c.pull.pull_distance_m = -0.1;
  rejects(good, 0, c, "pull_distance_m");
  c = config, c.pull.pull_speed_mps = std::nan("");
  rejects(good, 0, c, "pull_speed_mps");
  c = config, c.pull.settle_s = 1e7;  // steps beyond an int
  rejects(good, 0, c, "settle_s");
  // Bullet would quietly simulate a softer cup than this (its spring bound at 240 Hz steps).
  c = config, c.pull.cup_stiffness_hz = 10.0;
  rejects(good, 0, c, "cup_stiffness_hz must be at most 9.5");
  EXPECT_THROW(rankGrasps({}, 0, {}, config), std::invalid_argument);
  // Cameras and measured points that are not finite name themselves.
  const auto rejectsInput = [&](const std::vector<Vec3>& cameras, const Points3& measured,
                                const std::optional<Vec3>& from, const std::string& expected) {
    try {
      rankGrasps({good}, 0, cameras, config, {}, measured, from);
      ADD_FAILURE() << "accepted: " << expected;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  };
  const Vec3 nan_point(std::nan(""), 0.0, 1.0);
  rejectsInput({Vec3(0, 0, 1), nan_point}, {}, std::nullopt, "camera position 1 is not finite");
  rejectsInput({}, {}, nan_point, "measuring camera's position is not finite");
  rejectsInput({}, {Vec3(0, 0, 0.1), nan_point}, std::nullopt, "measured point 1 of 2");
}

// config/grasps.yaml holds every setting at its default (the server without the file ranks as
// with it); a setting given replaces its default, the cup's radius both where the seal is
// judged and where the pull peels it; a misspelt key, a mistyped or bad value names itself.
TEST(GraspSettings, TheShippedFileHoldsTheDefaultsAndEveryKeyIsChecked) {
  const std::set<std::string> server_keys{"objects_topic", "rank_grasps_action"};
  const GraspSettings shipped =
      loadGraspSettingsYaml(std::string(SIMSTACK_SOURCE_DIR) + "/config/grasps.yaml", server_keys);
  const GraspSettings defaults;
  EXPECT_EQ(shipped.ranking.threads, defaults.ranking.threads);
  EXPECT_EQ(shipped.policy.max_candidates, defaults.policy.max_candidates);
  EXPECT_EQ(shipped.policy.max_candidates_limit, defaults.policy.max_candidates_limit);
  EXPECT_EQ(shipped.policy.pregrasp_distance_m, defaults.policy.pregrasp_distance_m);
  EXPECT_EQ(shipped.ranking.candidates.cup_radius_m, defaults.ranking.candidates.cup_radius_m);
  EXPECT_EQ(shipped.ranking.candidates.seal_tolerance_m,
            defaults.ranking.candidates.seal_tolerance_m);
  EXPECT_EQ(shipped.ranking.pull.max_force_n, defaults.ranking.pull.max_force_n);
  EXPECT_EQ(shipped.ranking.pull.cup_stiffness_hz, defaults.ranking.pull.cup_stiffness_hz);
  EXPECT_NEAR(shipped.ranking.pull.topple_rad, defaults.ranking.pull.topple_rad, 1e-12);
  EXPECT_EQ(shipped.ranking.pull.physics.density_kgpm3,
            defaults.ranking.pull.physics.density_kgpm3);
  EXPECT_EQ(shipped.ranking.perturbation.copies, defaults.ranking.perturbation.copies);
  EXPECT_EQ(shipped.ranking.perturbation.position_m, defaults.ranking.perturbation.position_m);
  EXPECT_EQ(shipped.ranking.match_distance_m, defaults.ranking.match_distance_m);

  const GraspSettings set = parseGraspSettingsYaml(
      "cup_radius_m: 0.02\ntopple_deg: 45\nperturbed_copies: 3\nthreads: 1.0\n", "text");
  EXPECT_EQ(set.ranking.candidates.cup_radius_m, 0.02);
  EXPECT_EQ(set.ranking.pull.cup_radius_m, 0.02);
  EXPECT_NEAR(set.ranking.pull.topple_rad, M_PI / 4, 1e-12);
  EXPECT_EQ(set.ranking.perturbation.copies, 3);
  EXPECT_EQ(set.ranking.threads, 1);
  EXPECT_EQ(parseGraspSettingsYaml("", "empty").ranking.threads, defaults.ranking.threads);

  const auto message = [](const std::string& text) {
    try {
      parseGraspSettingsYaml(text, "here.yaml");
    } catch (const std::exception& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_NE(message("max_force: 3\n").find("unknown key 'max_force'"), std::string::npos);
  EXPECT_NE(message("objects_topic: x\n").find("unknown key 'objects_topic'"), std::string::npos);
  EXPECT_NE(message("surface_samples: 2.5\n").find("here.yaml: surface_samples"),
            std::string::npos);
  EXPECT_NE(message("cup_radius_m: -0.01\n").find("cup_radius_m"), std::string::npos);
  EXPECT_NE(message("topple_deg: 0\n").find("topple_deg"), std::string::npos);
  EXPECT_NE(message("perturb_rotation_deg: 90\n").find("perturb_rotation_deg"), std::string::npos);
  EXPECT_NE(message("max_force_n: .nan\n").find("max_force_n"), std::string::npos);
  EXPECT_NE(message("[1, 2]\n").find("map"), std::string::npos);
}

TEST(GraspRequest, TheSceneMustRestOnTheTableAndThePullStayInBounds) {
  GraspRequest request;
  request.scenes = {twoBoxStack()};
  request.target = 1;
  const GraspPolicy policy;
  const PreparedGrasps ok = prepareGrasps(request, GraspRankingConfig(), policy);
  EXPECT_TRUE(ok.notes.empty()) << ok.notes;
  EXPECT_EQ(ok.config.candidates.max_candidates, policy.max_candidates);
  EXPECT_EQ(ok.config.pull.pull_distance_m, request.pull_distance_m);
  EXPECT_EQ(ok.pregrasp_m, policy.pregrasp_distance_m);
  // The request's own faults are BadGraspRequest, the scene's plain invalid_argument.
  const auto refused = [&](GraspRequest r, const std::string& says, bool the_requests = true) {
    try {
      prepareGrasps(r, GraspRankingConfig(), policy);
      ADD_FAILURE() << "accepted; expected: " << says;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(says), std::string::npos) << e.what();
      EXPECT_EQ(dynamic_cast<const BadGraspRequest*>(&e) != nullptr, the_requests) << e.what();
    }
  };
  GraspRequest sunk = request, raised = request;
  for (SuperquadricShape& sq : sunk.scenes[0]) sq.T_table_object.translation().z() -= 0.3;
  refused(sunk, "would stand in the table", false);
  for (SuperquadricShape& sq : raised.scenes[0]) sq.T_table_object.translation().z() += 0.3;
  EXPECT_NE(prepareGrasps(raised, GraspRankingConfig(), policy).notes.find("fall before any pull"),
            std::string::npos);
  GraspRequest far = request, fast = request, standoff = request, target = request;
  far.pull_distance_m = 0.6;
  refused(far, "pull_distance_m must lie in (0, 0.5] m, not 0.6");
  fast.pull_speed_mps = std::numeric_limits<double>::quiet_NaN();
  refused(fast, "pull_speed_mps must lie in (0, 2] m/s, not nan");
  standoff.pregrasp_m = -0.1;
  refused(standoff, "pregrasp_distance_m must lie in [0, 1] m");
  GraspRequest slow = request;  // each bound kept, together over a minute: mm/s taken for m/s
  slow.pull_distance_m = 0.5;
  slow.pull_speed_mps = 0.005;
  refused(slow, "the pull of 0.5 m at 0.005 m/s takes over 60 s");
  target.target = 2;
  refused(target, "target 2 is not an object of the 2-object scene");
  // A bad shape is named by its object's id where the request gives the ids.
  GraspRequest named = request;
  named.scenes[0][1].scale_m.x() = std::numeric_limits<double>::quiet_NaN();
  refused(named, "the scene's object 1: semi-axes", false);
  named.ids = {12, 7};
  refused(named, "the scene's object 7: semi-axes", false);
  GraspRequest twice = request;
  twice.ids = {7, 7};
  refused(twice, "the scene's object id 7 appears twice", false);
  GraspRequest many = request;
  many.candidates = 1000;
  many.hypotheses = 3;
  many.scenes.push_back(twoBoxStack());
  const PreparedGrasps clamped = prepareGrasps(many, GraspRankingConfig(), policy);
  EXPECT_EQ(clamped.config.candidates.max_candidates, policy.max_candidates_limit);
  EXPECT_NE(clamped.notes.find("1000 candidates asked for, clamped"), std::string::npos);
  EXPECT_NE(clamped.notes.find("3 hypotheses asked for, the scene has 2"), std::string::npos);
  EXPECT_EQ(clamped.scenes.size(), 2u);
  GraspRequest bad_hypothesis = many;
  bad_hypothesis.scenes[1][0].scale_m.x() = -1.0;
  refused(bad_hypothesis, "hypothesis 1 (of the scene's hypotheses), object 0: semi-axes", false);
}

TEST(GraspRequest, APointNamesTheObjectItIsDeepestInOrTheNearestSurface) {
  // bridgedTarget: boxes 0 and 1 side by side (x = -0.055 and 0.055, 5 cm half-widths, tops at
  // 6 cm); box 2 on top across both, centred at x = 0.03, 8.05 cm up.
  const std::vector<SuperquadricShape> scene = bridgedTarget();
  double distance = -1.0;
  EXPECT_EQ(objectAtPoint(scene, Vec3(-0.055, 0, 0.03), &distance), 0);
  EXPECT_EQ(distance, 0.0);
  EXPECT_EQ(objectAtPoint(scene, Vec3(0.03, 0, 0.075)), 2);
  // Two estimates that overlap: a point inside both belongs to the one it lies deeper in.
  const std::vector<SuperquadricShape> overlapping = {box({0.05, 0.05, 0.05}, {0, 0, 0.05}),
                                                      box({0.03, 0.03, 0.03}, {0.06, 0, 0.03})};
  EXPECT_EQ(objectAtPoint(overlapping, Vec3(0.04, 0, 0.03)), 1);  // 4/5 out in 0, 2/3 in 1
  EXPECT_EQ(objectAtPoint(overlapping, Vec3(0.02, 0, 0.03)), 0);  // outside 1
  // Outside all: 3 cm beyond the left box's outer face is 3 cm from it, not from the others.
  EXPECT_EQ(objectAtPoint(scene, Vec3(-0.135, 0, 0.03), &distance), 0);
  EXPECT_NEAR(distance, 0.03, 0.002);
  // Beyond kMaxTargetPointM from every surface: none, with the nearest's distance.
  EXPECT_EQ(objectAtPoint(scene, Vec3(-0.3, 0, 0.03), &distance), -1);
  EXPECT_NEAR(distance, 0.195, 0.005);
  EXPECT_EQ(objectAtPoint({}, Vec3::Zero()), -1);
  // 5 mm off a large box's face and 2 cm off a small neighbour's: the large box, 5 mm away.
  const std::vector<SuperquadricShape> large_and_small = {
      box({0.1, 0.1, 0.1}, {0, 0, 0.1}), box({0.02, 0.02, 0.02}, {0.145, 0, 0.02})};
  EXPECT_EQ(objectAtPoint(large_and_small, Vec3(0.105, 0, 0.1), &distance), 0);
  EXPECT_NEAR(distance, 0.005, 1e-6);
  EXPECT_EQ(objectAtPoint(large_and_small, Vec3(0.105, 0, 0.02), &distance), 0);
  EXPECT_NEAR(distance, 0.005, 0.001);
  // 1 cm above a book near its edge, 3.6 cm from a small box: the book, 1 cm away (along the
  // ray from the book's centre its surface is 4.6 cm off). 7 cm above its corner: within reach
  // (along the ray, 13 cm).
  const std::vector<SuperquadricShape> book_and_box = {box({0.1, 0.1, 0.01}, {0, 0, 0.01}),
                                                       box({0.02, 0.02, 0.02}, {0.145, 0, 0.02})};
  EXPECT_EQ(objectAtPoint(book_and_box, Vec3(0.09, 0, 0.03), &distance), 0);
  EXPECT_NEAR(distance, 0.01, 0.001);
  EXPECT_EQ(objectAtPoint({book_and_box[0]}, Vec3(0.095, 0.095, 0.09), &distance), 0);
  EXPECT_NEAR(distance, 0.07, 0.001);
}

TEST(GraspRequest, MeasuredPointsAreTheTargetsWhenEnoughLieNearItsShape) {
  // A 1 cm plate whose fitted top lies 4 mm under the measured one: every point is 4 mm off
  // (along the ray from the centre, those beyond 4.5 cm of the middle are over 2 cm off).
  const SuperquadricShape plate = box({0.1, 0.1, 0.005}, {0, 0, 0.005});
  Points3 top;
  for (int i = -10; i <= 10; ++i)
    for (int j = -10; j <= 10; ++j) top.emplace_back(0.0095 * i, 0.0095 * j, 0.014);
  EXPECT_EQ(measuredOffTarget(top, plate), "");
  EXPECT_EQ(measuredOffTarget({}, plate), "");
  // Another object's cloud, 25 cm aside: refused, with the count.
  Points3 aside = top;
  for (Vec3& p : aside) p.x() += 0.25;
  EXPECT_EQ(measuredOffTarget(aside, plate),
            "0 of 441 points lie inside or within 2 cm of its superquadric");
  // A quarter near is enough; fewer is not.
  Points3 mixed(aside.begin(), aside.begin() + 300);
  mixed.insert(mixed.end(), top.begin(), top.begin() + 100);
  EXPECT_EQ(measuredOffTarget(mixed, plate), "");
  mixed.insert(mixed.end(), aside.begin(), aside.begin() + 10);
  EXPECT_NE(measuredOffTarget(mixed, plate).find("100 of 410 points"), std::string::npos);
  // A large cloud is judged on every n-th point, and says so.
  Points3 many;
  for (int k = 0; k < 10; ++k) many.insert(many.end(), aside.begin(), aside.end());
  EXPECT_NE(measuredOffTarget(many, plate).find("0 of 1470 points judged (1 in 3)"),
            std::string::npos);
}

TEST(GraspRequest, AStaleSceneIsRefusedUnlessAnyAgeIsAllowed) {
  EXPECT_TRUE(staleScene(5.0, 10.0).empty());
  EXPECT_TRUE(staleScene(-3.0, 10.0).empty());  // a looping bag's stamp ahead of now
  EXPECT_TRUE(staleScene(1e6, 0.0).empty());    // 0: any age
  EXPECT_NE(staleScene(12.0, 10.0).find("12 s old (max_scene_age_s 10)"), std::string::npos);
  EXPECT_NE(staleScene(2e5, 10.0).find("simulated time"), std::string::npos);
}

TEST(SuctionCandidates, ToolPoseLooksIntoTheSurfaceAndThePregraspStandsBackAlongTheApproach) {
  std::mt19937_64 rng(11);
  std::normal_distribution<double> n(0.0, 1.0);
  for (int i = 0; i < 200; ++i) {
    SuctionCandidate c;
    c.contact_table = Vec3(n(rng), n(rng), n(rng));
    c.approach_table = i == 0 ? Vec3::UnitX() : Vec3(n(rng), n(rng), n(rng)).normalized();
    const Transform T = toolPose(c);
    const Eigen::Matrix3d R = T.linear();
    EXPECT_TRUE((R.transpose() * R).isIdentity(1e-9));
    EXPECT_NEAR(R.determinant(), 1.0, 1e-9);
    EXPECT_NEAR(R.col(2).dot(c.approach_table), -1.0, 1e-9);  // z into the surface
    EXPECT_TRUE(T.translation().isApprox(c.contact_table));
    const Transform P = pregraspPose(T, 0.07);
    EXPECT_TRUE(P.linear().isApprox(R));
    EXPECT_TRUE(P.translation().isApprox(c.contact_table + 0.07 * c.approach_table, 1e-9));
  }
  SuctionCandidate up;
  up.approach_table = Vec3::UnitZ();
  EXPECT_TRUE(toolPose(up).linear().col(0).isApprox(Vec3::UnitX()));  // x keeps the table's x
  EXPECT_THROW(pregraspPose(Transform::Identity(), -0.01), std::invalid_argument);
  EXPECT_THROW(pregraspPose(Transform::Identity(), std::nan("")), std::invalid_argument);
}

}  // namespace
}  // namespace simstack
