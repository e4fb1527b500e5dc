#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <locale>
#include <random>

#include "simstack/geometry/container.h"
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

TEST(SuperquadricShape, TheSurfacePointAlongARayLiesOnTheSurface) {
  SuperquadricShape sphere;
  sphere.scale_m = Vec3::Constant(0.1);
  const Vec3 s = sphere.surfacePointAlong(Vec3(1, 1, 1));
  EXPECT_NEAR(s.norm(), 0.1, 1e-12);
}

// The share of the smaller solid inside the other, against volumes known in closed form: a
// box-like cube whose centre sits on a larger one's face has half of itself inside; a sphere
// inside an ellipsoid all of itself; shapes apart none. The order of the arguments does not
// matter.
TEST(SuperquadricShape, SharedVolumeShareIsTheSmallerSolidsShareInsideTheOther) {
  SuperquadricShape big;
  big.scale_m = Vec3(0.10, 0.10, 0.10);
  big.exponents = Vec3::Constant(60.0);  // a cube to within 1.2 % of its volume
  SuperquadricShape small = big;
  small.scale_m = Vec3::Constant(0.03);
  small.T_table_object.translation() = Vec3(0.10, 0.0, 0.0);  // its centre on big's face
  EXPECT_NEAR(sharedVolumeShare(big, small, 4000), 0.5, 0.03);
  EXPECT_DOUBLE_EQ(sharedVolumeShare(big, small, 4000), sharedVolumeShare(small, big, 4000));
  small.T_table_object.translation() = Vec3(0.12, 0.0, 0.0);  // a sixth of it inside
  EXPECT_NEAR(sharedVolumeShare(big, small), 1.0 / 6.0, 0.05);
  const SuperquadricShape e = ellipsoid();
  SuperquadricShape sphere;
  sphere.scale_m = Vec3::Constant(0.03);
  sphere.T_table_object.translation() = e.centroid();
  EXPECT_DOUBLE_EQ(sharedVolumeShare(e, sphere), 1.0);
  EXPECT_DOUBLE_EQ(sharedVolumeShare(e, e), 1.0);
  // Past the ellipsoid's largest semi-axis, but within the bounding spheres' reach: sampled.
  sphere.T_table_object.translation() = e.centroid() + Vec3(0.0, 0.0, 0.15);
  EXPECT_DOUBLE_EQ(sharedVolumeShare(e, sphere), 0.0);
  sphere.T_table_object.translation() = e.centroid() + Vec3(1.0, 0.0, 0.0);
  EXPECT_DOUBLE_EQ(sharedVolumeShare(e, sphere), 0.0);
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

TEST(PinholeCamera, IntrinsicsOfAnotherImageSizeAreRefusedButAWindowIsNot) {
  PinholeCamera kinect;  // 640x480, principal point at the centre
  EXPECT_NO_THROW(kinect.validate());
  PinholeCamera half = kinect;  // a 320x240 image given the 640x480 camera
  half.width = 320, half.height = 240;
  EXPECT_THROW(half.validate(), std::invalid_argument);
  PinholeCamera twice = kinect;  // a 640x480 image given the 320x240 camera
  twice.fx = twice.fy = 262.5, twice.cx = 159.5, twice.cy = 119.5;
  EXPECT_THROW(twice.validate(), std::invalid_argument);
  PinholeCamera off = kinect;  // 20 % of the width off the centre: a camera's
  off.cx = 319.5 + 128.0;
  EXPECT_NO_THROW(off.validate());
  half.window = true;  // a crop of a checked camera's image
  EXPECT_NO_THROW(half.validate());
}

TEST(PinholeCamera, AnUnsetMatrixIsNamedAsSuchNotAsAnotherImageSize) {
  PinholeCamera unset;  // a camera_info whose K is all zeros
  unset.fx = unset.fy = unset.cx = unset.cy = 0.0;
  try {
    unset.validate();
    FAIL() << "an all-zero camera matrix was accepted";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("fx = 0 must be > 0"), std::string::npos) << what;
    EXPECT_NE(what.find("fy = 0 must be > 0"), std::string::npos) << what;
    EXPECT_EQ(what.find("middle half"), std::string::npos) << what;
  }
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

TEST(Container, MeshEnclosesTheSolidItsInsideTestDescribes) {
  ContainerSpec bowl;
  bowl.radius_top_m = 0.08;
  bowl.radius_bottom_m = 0.045;
  bowl.height_m = 0.06;
  bowl.wall_m = 0.006;
  // Outer frustum less the cavity's frustum (from the floor up, radii one wall inside).
  const auto frustum = [](double h, double r0, double r1) {
    return M_PI * h / 3.0 * (r0 * r0 + r0 * r1 + r1 * r1);
  };
  const double inner_bottom = 0.045 + 0.035 * 0.006 / 0.06 - 0.006;
  const double expected = frustum(0.06, 0.045, 0.08) - frustum(0.054, inner_bottom, 0.074);
  const TriangleMesh fine = bowl.mesh(512);
  EXPECT_NEAR(fine.volume(), expected, 1e-3 * expected);
  // The cavity is free, the wall and floor are solid, the rim's outside is free.
  EXPECT_FALSE(bowl.contains(Vec3(0.0, 0.0, 0.03)));
  EXPECT_TRUE(bowl.contains(Vec3(0.0, 0.0, 0.003)));
  const double wall_mid = 0.045 + 0.035 * 0.5 - 0.003;
  EXPECT_TRUE(bowl.contains(Vec3(0.0, wall_mid, 0.03)));
  EXPECT_FALSE(bowl.contains(Vec3(0.0, wall_mid + 0.006, 0.03)));
  EXPECT_FALSE(bowl.contains(Vec3(0.0, 0.0, -0.001)));
  // Monte Carlo volume of the inside test matches the mesh's.
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> xy(-0.08, 0.08), z(0.0, 0.06);
  int inside = 0;
  const int n = 200000;
  for (int i = 0; i < n; ++i) inside += bowl.contains(Vec3(xy(rng), xy(rng), z(rng)));
  const double box = 0.16 * 0.16 * 0.06;
  EXPECT_NEAR(box * inside / n, expected, 0.03 * expected);
  // The name rebuilds the sizes to 0.1 mm.
  const auto parsed = parseContainerName(bowl.name());
  ASSERT_TRUE(parsed.has_value());
  EXPECT_NEAR(parsed->radius_top_m, 0.08, 1e-9);
  EXPECT_NEAR(parsed->wall_m, 0.006, 1e-9);
  {  // a host program's decimal comma changes neither the name nor its reading
    struct Comma : std::numpunct<char> {
      char do_decimal_point() const override { return ','; }
    };
    const std::locale before = std::locale::global(std::locale(std::locale::classic(), new Comma));
    const std::string name = bowl.name();
    const auto read = parseContainerName(name);
    std::locale::global(before);
    EXPECT_EQ(name, parseContainerName(bowl.name())->name());
    ASSERT_TRUE(read.has_value()) << name;
    EXPECT_NEAR(read->height_m, bowl.height_m, 1e-4);
  }
  EXPECT_FALSE(parseContainerName("container 0.08 0.045").has_value());
  EXPECT_FALSE(parseContainerName("003_cracker_box").has_value());
  EXPECT_FALSE(parseContainerName("container 0.08 0.045 0.06 0.006 extra").has_value());
  bowl.wall_m = 0.07;  // thicker than the bowl is high: no cavity
  EXPECT_THROW(bowl.mesh(), std::invalid_argument);
  bowl.wall_m = std::nan("");
  EXPECT_THROW(bowl.validate(), std::invalid_argument);
}
