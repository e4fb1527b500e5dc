#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/tsdf/projective_tsdf.h"

#include "test_scenes.h"

using namespace simstack;

using test::sphereScene;

TEST(ProjectiveTsdf, ZeroAtTheObservedSurfaceAndPositiveInFront) {
  const PileGenerator gen{PileConfig()};
  const Scene scene = gen.generate(21).scene;
  const Vec3 centre = scene.surfaceCentroid();
  const GridSpec grid = GridSpec::sceneGrid(centre.head<2>(), 0.64, 64);
  const DepthRenderer renderer(scene);
  PinholeCamera camera;
  const Transform T_table_camera = lookAt(centre + Vec3(0.6, -0.4, 0.5), centre);
  const RenderResult r = renderer.render(camera, T_table_camera);
  ProjectiveTsdfConfig config;
  config.truncation_m = 3 * grid.voxel_size_m;
  ProjectiveTsdf tsdf(grid, config);
  tsdf.integrate(r.depth, camera, T_table_camera);
  // Near a depth discontinuity a voxel projects onto the other surface, which no projective
  // TSDF can avoid; those pixels are counted apart and must stay a small minority.
  auto nearEdge = [&](int u, int v) {
    const float d = r.depth.at(u, v);
    for (int dv = -4; dv <= 4; ++dv)
      for (int du = -4; du <= 4; ++du) {
        const int uu = std::clamp(u + du, 0, camera.width - 1),
                  vv = std::clamp(v + dv, 0, camera.height - 1);
        if (!validDepth(r.depth.at(uu, vv)) ||
            std::abs(r.depth.at(uu, vv) - d) > 2 * grid.voxel_size_m)
          return true;
      }
    return false;
  };
  int checked = 0, edge = 0, edge_within = 0;
  for (int v = 0; v < camera.height; v += 5) {
    for (int u = 0; u < camera.width; u += 5) {
      const float d = r.depth.at(u, v);
      if (!validDepth(d)) continue;
      const Vec3 p = T_table_camera * camera.backproject(u, v, d);
      const Vec3 ray = (p - T_table_camera.translation()).normalized();
      const Vec3 front = p - 2.0 * grid.voxel_size_m * ray;
      // Stay a truncation away from the grid's faces, where interpolation sees outside voxels.
      const Vec3 lo = grid.origin_table + Vec3::Constant(config.truncation_m);
      const Vec3 hi = grid.origin_table + Vec3::Constant(grid.extent_m() - config.truncation_m);
      if ((p.array() < lo.array()).any() || (p.array() > hi.array()).any()) continue;
      const double at_surface = std::abs(tsdf.tsdf().sampleTrilinear(p));
      if (nearEdge(u, v)) {
        ++edge;
        edge_within += at_surface < grid.voxel_size_m;
        continue;
      }
      EXPECT_LT(at_surface, grid.voxel_size_m) << "pixel " << u << "," << v;
      EXPECT_GT(tsdf.tsdf().sampleTrilinear(front), 0.0f) << "pixel " << u << "," << v;
      ++checked;
    }
  }
  EXPECT_GT(checked, 300);
  EXPECT_GT(checked + edge_within, 0.9 * (checked + edge))
      << edge_within << " of " << edge << " pixels near depth edges within one voxel";
}

TEST(ProjectiveTsdf, HolesInRealDepthAreIgnored) {
  const Scene scene = sphereScene(0.1, Vec3(0, 0, 0.1));
  const GridSpec grid = GridSpec::sceneGrid(Vec2::Zero(), 0.64, 32);
  const DepthRenderer renderer(scene);
  PinholeCamera camera;
  const Transform T = lookAt(Vec3(0, -0.8, 0.6), Vec3(0, 0, 0.1));
  DepthImage depth = renderer.render(camera, T).depth;
  DepthImage holes = depth;
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      if (u < camera.width / 2)
        holes.at(u, v) = (v % 2) ? std::numeric_limits<float>::quiet_NaN() : 0.0f;
    }
  }
  ProjectiveTsdf full(grid), partial(grid);
  full.integrate(depth, camera, T);
  partial.integrate(holes, camera, T);
  int observed_full = 0, observed_partial = 0;
  for (size_t i = 0; i < partial.tsdf().data.size(); ++i) {
    ASSERT_TRUE(std::isfinite(partial.tsdf().data[i]));
    observed_full += full.weight().data[i] > 0;
    observed_partial += partial.weight().data[i] > 0;
  }
  EXPECT_GT(observed_partial, 1000);
  EXPECT_LT(observed_partial, observed_full);
  DepthImage wrong(320, 240, 1.0f);
  EXPECT_THROW(partial.integrate(wrong, camera, T), std::invalid_argument);
}

TEST(ProjectiveTsdf, FusesSeveralViews) {
  const Scene scene = sphereScene(0.1, Vec3(0, 0, 0.1));
  const GridSpec grid = GridSpec::sceneGrid(Vec2::Zero(), 0.64, 32);
  const DepthRenderer renderer(scene);
  PinholeCamera camera;
  ProjectiveTsdf tsdf(grid);
  const Transform a = lookAt(Vec3(0.8, 0, 0.5), Vec3(0, 0, 0.1));
  const Transform b = lookAt(Vec3(-0.8, 0.1, 0.5), Vec3(0, 0, 0.1));
  tsdf.integrate(renderer.render(camera, a).depth, camera, a);
  int one_view = 0;
  for (float w : tsdf.weight().data) one_view += w > 0;
  tsdf.integrate(renderer.render(camera, b).depth, camera, b);
  int two_views = 0, twice = 0;
  for (float w : tsdf.weight().data) {
    two_views += w > 0;
    twice += w >= 2;
  }
  EXPECT_GT(two_views, one_view);
  EXPECT_GT(twice, 100);
  // The sphere's far side (seen only by b) is now within one voxel of zero.
  EXPECT_LT(std::abs(tsdf.tsdf().sampleTrilinear(Vec3(-0.1, 0, 0.1))), grid.voxel_size_m);
}

TEST(GroundTruth, SphereDistancesAreExact) {
  const Vec3 c(0.01, 0.02, 0.1);
  const double radius = 0.1;
  const GridSpec grid = GridSpec::sceneGrid(Vec2::Zero(), 0.64, 32);
  const double tau = 3 * grid.voxel_size_m;
  const GroundTruthGrids gt = computeGroundTruth(sphereScene(radius, c), grid, tau);
  int inside = 0;
  for (int i = 0; i < grid.voxelCount(); ++i) {
    const Vec3i idx = grid.unravel(i);
    const Vec3 p = grid.voxelCentre(idx.x(), idx.y(), idx.z());
    const double expected = std::clamp((p - c).norm() - radius, -tau, tau);
    ASSERT_NEAR(gt.tsdf.data[i], expected, 0.002) << "voxel " << idx.transpose();
    if (gt.labels.data[i] == 1) {
      ++inside;
      EXPECT_NEAR(gt.votes.data[i].norm(), 1.0f, 1e-5);
      EXPECT_GT(gt.votes.data[i].cast<double>().dot((c - p).normalized()), 0.9999);
    } else {
      EXPECT_EQ(gt.votes.data[i].norm(), 0.0f);
    }
  }
  // Voxel count of a ball: volume / voxel volume.
  EXPECT_NEAR(inside, 4.0 / 3.0 * M_PI * std::pow(radius / grid.voxel_size_m, 3), 30);
}

TEST(GroundTruth, SignAgreesWithInsideTestOnRandomPoints) {
  const uint64_t seed = 5;
  const Scene scene = PileGenerator(PileConfig()).generate(seed).scene;
  const GridSpec grid = GridSpec::sceneGrid(scene.surfaceCentroid().head<2>(), 0.64, 32);
  const double tau = 3 * grid.voxel_size_m;
  const GroundTruthGrids gt = computeGroundTruth(scene, grid, tau);
  const SceneDistanceField field(scene, tau);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, grid.extent_m());
  const double margin = std::sqrt(3.0) * grid.voxel_size_m;  // interpolation reaches this far
  int tested = 0;
  for (int i = 0; i < 10000; ++i) {
    const Vec3 p = grid.origin_table + Vec3(uni(rng), uni(rng), uni(rng));
    bool inside = false;
    for (const auto& o : scene.objects) inside |= o.contains(p);
    if (std::abs(field.signedDistance(p)) <= margin) continue;
    ++tested;
    ASSERT_EQ(gt.tsdf.sampleTrilinear(p) < 0.0f, inside)
        << "point " << p.transpose() << " seed " << seed;
  }
  EXPECT_GT(tested, 8000);
}
