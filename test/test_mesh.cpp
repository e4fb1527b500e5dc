// Marching cubes against analytic surfaces.
#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include "simstack/mesh/marching_cubes.h"

namespace simstack {
namespace {

Grid3<float> sphereTsdf(const GridSpec& g, const Vec3& centre, double radius, double tau) {
  Grid3<float> t(g, 0.0f);
  for (int z = 0; z < g.resolution; ++z)
    for (int y = 0; y < g.resolution; ++y)
      for (int x = 0; x < g.resolution; ++x) {
        const double d = (g.voxelCentre(x, y, z) - centre).norm() - radius;
        t.at(x, y, z) = static_cast<float>(std::clamp(d, -tau, tau));
      }
  return t;
}

TEST(MarchingCubes, SphereAreaVolumeAndOrientation) {
  const GridSpec g = GridSpec::sceneGrid(Vec2(0, 0), 0.64, 32);
  const Vec3 c(0.01, -0.02, 0.25);
  const double radius = 0.2;
  const TriangleMesh mesh = extractSurface(sphereTsdf(g, c, radius, 0.06));
  ASSERT_FALSE(mesh.empty());
  const double area = 4 * M_PI * radius * radius;
  EXPECT_NEAR(mesh.area(), area, 0.02 * area);
  const double volume = 4.0 / 3.0 * M_PI * radius * radius * radius;
  EXPECT_NEAR(mesh.volume(), volume, 0.02 * volume);  // positive: outward triangles
  for (const Vec3& v : mesh.vertices) EXPECT_NEAR((v - c).norm(), radius, 0.01);
}

TEST(MarchingCubes, ObjectOnTheTableGivesAClosedSurface) {
  // A box standing on the grid's bottom face: the padding closes it.
  const GridSpec g = GridSpec::sceneGrid(Vec2(0, 0), 0.64, 32);
  Grid3<float> t(g, 0.06f);
  for (int z = 0; z < 5; ++z)
    for (int y = 10; y < 20; ++y)
      for (int x = 10; x < 20; ++x) t.at(x, y, z) = -0.02f;
  const TriangleMesh mesh = extractSurface(t);
  ASSERT_FALSE(mesh.empty());
  // Closed: every edge is shared by exactly two triangles, in opposite directions.
  std::map<std::pair<int, int>, int> edges;
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) ++edges[{t[k], t[(k + 1) % 3]}];
  for (const auto& [e, n] : edges) {
    EXPECT_EQ(n, 1);
    EXPECT_EQ(edges.count({e.second, e.first}), 1u);
  }
  // 10 x 10 x 5 voxels of 2 cm at -2 cm with +6 cm around: the zero crossing lies a quarter
  // voxel beyond the outer voxel centres, so the box is 9.5 x 9.5 x 4.5 voxels.
  const double expected = 0.19 * 0.19 * 0.09;
  EXPECT_NEAR(mesh.volume(), expected, 0.03 * expected);
  Vec3 lo, hi;
  ASSERT_TRUE(mesh.bounds(&lo, &hi));
  EXPECT_LE(lo.z(), 0.5 * g.voxel_size_m);
}

TEST(MarchingCubes, EmptyGridGivesEmptyMesh) {
  const GridSpec g = GridSpec::sceneGrid(Vec2(0, 0), 0.64, 16);
  EXPECT_TRUE(extractSurface(Grid3<float>(g, 0.06f)).empty());
}

TEST(MarchingCubes, SplitByInstanceLabels) {
  const GridSpec g = GridSpec::sceneGrid(Vec2(0, 0), 0.64, 32);
  Grid3<float> t(g, 0.06f);
  Grid3<int> labels(g, -1);
  const Vec3 a(-0.15, 0, 0.15), b(0.15, 0, 0.15);
  for (int z = 0; z < 32; ++z)
    for (int y = 0; y < 32; ++y)
      for (int x = 0; x < 32; ++x) {
        const Vec3 p = g.voxelCentre(x, y, z);
        const double da = (p - a).norm() - 0.08, db = (p - b).norm() - 0.08;
        t.at(x, y, z) = static_cast<float>(std::clamp(std::min(da, db), -0.06, 0.06));
        if (da <= 0) labels.at(x, y, z) = 0;
        if (db <= 0) labels.at(x, y, z) = 1;
      }
  const TriangleMesh mesh = extractSurface(t);
  const std::vector<int> tl = triangleLabels(mesh, labels);
  const std::vector<TriangleMesh> parts = splitByLabel(mesh, tl, 2);
  ASSERT_EQ(parts.size(), 2u);
  for (int k = 0; k < 2; ++k) {
    const Vec3 centre = k == 0 ? a : b;
    ASSERT_FALSE(parts[k].empty());
    EXPECT_NEAR(parts[k].area(), 0.5 * mesh.area(), 0.02 * mesh.area());
    for (const Vec3& v : parts[k].vertices) EXPECT_LT((v - centre).norm(), 0.1);
  }
  for (int l : tl) EXPECT_GE(l, 0);
}

}  // namespace
}  // namespace simstack
