#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "simstack/geometry/convex_hull.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/superquadric.h"
#include "simstack/geometry/voxel_grid.h"

using namespace simstack;

namespace {
SuperquadricShape ellipsoid() {
  SuperquadricShape sq;
  sq.scale_m = Vec3(0.10, 0.07, 0.05);
  sq.exponents = Vec3(2, 2, 2);
  sq.T_table_object.translation() = Vec3(0.3, -0.2, 0.1);
  sq.T_table_object.linear() =
      Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  return sq;
}
}  // namespace

TEST(SuperquadricShape, EllipsoidVolumeIsAnalytic) {
  const SuperquadricShape sq = ellipsoid();
  const double analytic = 4.0 / 3.0 * M_PI * 0.10 * 0.07 * 0.05;
  EXPECT_NEAR(sq.volume(), analytic, 1e-12);
  const TriangleMesh mesh = sq.meshObject(24);
  EXPECT_NEAR(mesh.volume(), analytic, 0.01 * analytic);
  EXPECT_LT(mesh.volumeCentroid().norm(), 1e-6);
}

TEST(SuperquadricShape, EllipsoidInsideTestAndNormals) {
  const SuperquadricShape sq = ellipsoid();
  std::mt19937_64 rng(42);
  std::uniform_real_distribution<double> uni(-0.12, 0.12);
  int inside = 0;
  for (int i = 0; i < 10000; ++i) {
    const Vec3 p_object(uni(rng), uni(rng), uni(rng));
    const double q = std::pow(p_object.x() / 0.10, 2) + std::pow(p_object.y() / 0.07, 2) +
                     std::pow(p_object.z() / 0.05, 2);
    const Vec3 p_table = sq.T_table_object * p_object;
    ASSERT_EQ(sq.contains(p_table), q < 1.0) << "point " << p_object.transpose() << " (seed 42)";
    inside += q < 1.0;
  }
  EXPECT_GT(inside, 100);
  for (const auto& s : sq.sampleSurfaceObject(2000, rng)) {
    EXPECT_NEAR(sq.insideOutsideObject(s.position), 1.0, 1e-9);
    const Vec3 expected =
        Vec3(s.position.x() / 0.01, s.position.y() / 0.0049, s.position.z() / 0.0025).normalized();
    EXPECT_NEAR(s.normal.dot(expected), 1.0, 1e-9);
  }
}

TEST(SuperquadricShape, SurfaceSamplesAreNearUniform) {
  SuperquadricShape sphere;
  sphere.scale_m = Vec3::Constant(0.1);
  std::mt19937_64 rng(3);
  const auto samples = sphere.sampleSurfaceObject(40000, rng);
  // A cap of height r/2 holds a quarter of a sphere's area (Archimedes).
  int in_cap = 0;
  Vec3 mean = Vec3::Zero();
  for (const auto& s : samples) {
    in_cap += s.position.z() > 0.05;
    mean += s.position;
  }
  EXPECT_NEAR(in_cap / 40000.0, 0.25, 0.01);
  EXPECT_LT((mean / 40000.0).norm(), 0.002);
}

TEST(SuperquadricShape, MeshVolumeMatchesFormulaForAnyExponents) {
  for (const Vec3& e : {Vec3(2, 5, 40), Vec3(100, 100, 100), Vec3(3, 3, 8), Vec3(1.5, 2, 2)}) {
    SuperquadricShape sq;
    sq.scale_m = Vec3(0.12, 0.05, 0.08);
    sq.exponents = e;
    const double v = sq.volume();
    EXPECT_NEAR(sq.meshObject(32).volume(), v, 0.01 * v) << "exponents " << e.transpose();
  }
  SuperquadricShape box;
  box.scale_m = Vec3(0.1, 0.05, 0.02);
  box.exponents = Vec3::Constant(100);
  EXPECT_NEAR(box.volume(), 8 * 0.1 * 0.05 * 0.02, 0.03 * 8 * 0.1 * 0.05 * 0.02);
}

TEST(SuperquadricShape, RadialDistanceFollowsThePaper) {
  SuperquadricShape sphere;
  sphere.scale_m = Vec3::Constant(0.1);
  sphere.T_table_object.translation() = Vec3(1, 2, 3);
  // f = 4 at twice the radius: d = |OP| (f - 1) / f = 0.2 * 3 / 4.
  EXPECT_NEAR(sphere.radialDistance(Vec3(1.2, 2, 3)), 0.15, 1e-12);
  EXPECT_NEAR(sphere.radialDistance(Vec3(1.1, 2, 3)), 0.0, 1e-12);
  EXPECT_LT(sphere.radialDistance(Vec3(1.05, 2, 3)), 0.0);
  const Vec3 s = sphere.surfacePointAlong(Vec3(1, 1, 1));
  EXPECT_NEAR(s.norm(), 0.1, 1e-12);
}

TEST(VoxelGrid, IndexingAndTrilinear) {
  const GridSpec g = GridSpec::sceneGrid(Vec2(0.1, -0.2), 0.64, 32);
  EXPECT_DOUBLE_EQ(g.voxel_size_m, 0.02);
  EXPECT_TRUE(g.origin_table.isApprox(Vec3(-0.22, -0.52, 0.0)));
  for (const Vec3i& i : {Vec3i(0, 0, 0), Vec3i(5, 17, 31), Vec3i(31, 31, 31)}) {
    const Vec3 c = g.voxelCentre(i.x(), i.y(), i.z());
    EXPECT_EQ(g.voxelIndex(c), i);
    EXPECT_LT((g.continuousIndex(c) - i.cast<double>()).norm(), 1e-9);
    EXPECT_EQ(g.unravel(g.linear(i.x(), i.y(), i.z())), i);
  }
  Grid3<float> f(g, 0.0f);
  auto linear = [](const Vec3& p) {
    return static_cast<float>(1.0 + 2.0 * p.x() - 3.0 * p.y() + 0.5 * p.z());
  };
  for (int z = 0; z < 32; ++z)
    for (int y = 0; y < 32; ++y)
      for (int x = 0; x < 32; ++x) f.at(x, y, z) = linear(g.voxelCentre(x, y, z));
  const Vec3 p(0.0337, -0.1234, 0.3011);
  EXPECT_NEAR(f.sampleTrilinear(p), linear(p), 1e-5);
  EXPECT_THROW(GridSpec::sceneGrid(Vec2::Zero(), 0.0, 32), std::invalid_argument);
  // Far outside (a bad depth pixel's 1e30 m) or NaN: just outside, its neighbours too.
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(g.voxelIndex(Vec3(1e30, -1e30, 0.1)), Vec3i(33, -2, 5));
  EXPECT_EQ(g.voxelIndex(Vec3(nan, 0.0, nan)), Vec3i(-2, 26, -2));
  EXPECT_EQ(g.voxelIndex(Vec3(-0.23, 0.115, 0.65)), Vec3i(-1, 31, 32));  // near: exact
}

TEST(PinholeCamera, ProjectBackprojectAndValidation) {
  PinholeCamera c;
  const Vec3 p = c.backproject(100.25, 400.5, 1.7);
  double u, v;
  ASSERT_TRUE(c.project(p, &u, &v));
  EXPECT_NEAR(u, 100.25, 1e-9);
  EXPECT_NEAR(v, 400.5, 1e-9);
  EXPECT_FALSE(c.project(Vec3(0, 0, -1), &u, &v));
  c.fx = 0.0;
  EXPECT_THROW(c.validate(), std::invalid_argument);
  const Transform T = lookAt(Vec3(1, 0, 0.5), Vec3(0, 0, 0.1));
  EXPECT_TRUE((T.linear().col(2)).isApprox((Vec3(0, 0, 0.1) - Vec3(1, 0, 0.5)).normalized()));
  EXPECT_NEAR(T.linear().col(0).z(), 0.0, 1e-12);         // image x stays horizontal
  EXPECT_GT(T.linear().col(1).dot(-Vec3::UnitZ()), 0.0);  // image y points down
  EXPECT_NEAR(T.linear().determinant(), 1.0, 1e-12);
}

TEST(ConvexHull, CubeInsideTest) {
  std::vector<Vec3> pts;
  for (int i = 0; i < 8; ++i) pts.emplace_back(i & 1 ? 1 : -1, i & 2 ? 1 : -1, i & 4 ? 1 : -1);
  pts.emplace_back(0, 0, 0);  // interior points are ignored
  const ConvexHull hull(pts);
  EXPECT_EQ(hull.vertices().size(), 8u);
  EXPECT_TRUE(hull.contains(Vec3(0.9, -0.9, 0.9)));
  EXPECT_FALSE(hull.contains(Vec3(1.1, 0, 0)));
  EXPECT_THROW(ConvexHull({Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(1, 1, 0)}),
               std::invalid_argument);
}
