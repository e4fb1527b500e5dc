#include <gtest/gtest.h>

#include <cmath>

#include "simstack/render/depth_renderer.h"

#include "test_scenes.h"

using namespace simstack;

using test::sphereScene;

TEST(DepthRenderer, TablePlaneMatchesAnalyticDepth) {
  const DepthRenderer renderer(Scene{});
  PinholeCamera camera;
  const Transform T_table_camera = lookAt(Vec3(0.4, -0.3, 0.7), Vec3(0.0, 0.0, 0.0));
  const RenderResult r = renderer.render(camera, T_table_camera);
  int checked = 0;
  for (int v = 0; v < camera.height; v += 7) {
    for (int u = 0; u < camera.width; u += 7) {
      // Ray o + t d (d with unit camera z) meets z = 0 at t = -o.z / d.z; depth = t.
      const Vec3 d = T_table_camera.linear() * camera.ray(u, v);
      const double t = -T_table_camera.translation().z() / d.z();
      const Vec3 hit = T_table_camera.translation() + t * d;
      const bool on_table = t > 0 && std::abs(hit.x()) < 0.6 && std::abs(hit.y()) < 0.6;
      if (!on_table) {
        EXPECT_EQ(r.instances.at(u, v), kNoSurface);
        continue;
      }
      if (std::abs(std::abs(hit.x()) - 0.6) < 0.005 || std::abs(std::abs(hit.y()) - 0.6) < 0.005)
        continue;  // edge
      EXPECT_NEAR(r.depth.at(u, v), t, 0.001) << "pixel " << u << "," << v;
      EXPECT_EQ(r.instances.at(u, v), 0);
      ++checked;
    }
  }
  EXPECT_GT(checked, 2000);
}

TEST(DepthRenderer, SphereMatchesAnalyticDepth) {
  const Vec3 c(0.02, -0.01, 0.08);
  const double radius = 0.08;
  const DepthRenderer renderer(sphereScene(radius, c));
  PinholeCamera camera;
  const Transform T_table_camera = lookAt(Vec3(0.5, 0.3, 0.45), c);
  const RenderResult r = renderer.render(camera, T_table_camera);
  int sphere_pixels = 0;
  const Vec3 o = T_table_camera.translation();
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      const Vec3 d = T_table_camera.linear() * camera.ray(u, v);
      // |o + t d - c|^2 = r^2
      const double a = d.squaredNorm(), b = 2 * d.dot(o - c),
                   cc = (o - c).squaredNorm() - radius * radius;
      const double disc = b * b - 4 * a * cc;
      if (disc < 0) continue;
      const double t = (-b - std::sqrt(disc)) / (2 * a);
      // Skip the silhouette (grazing rays), where a tessellated sphere and the analytic one
      // differ in coverage.
      const Vec3 n = (o + t * d - c) / radius;
      if (-n.dot(d.normalized()) < 0.25) continue;
      ASSERT_EQ(r.instances.at(u, v), 1) << "pixel " << u << "," << v;
      EXPECT_NEAR(r.depth.at(u, v), t, 0.001) << "pixel " << u << "," << v;
      ++sphere_pixels;
    }
  }
  EXPECT_GT(sphere_pixels, 5000);
}

TEST(DepthRenderer, NoiseIsSeededAndDropsPixels) {
  const DepthRenderer renderer(sphereScene(0.08, Vec3(0, 0, 0.08)));
  PinholeCamera camera;
  const Transform T = lookAt(Vec3(0.6, 0.0, 0.5), Vec3(0, 0, 0.08));
  const RenderResult clean = renderer.render(camera, T);
  const RenderResult a = renderer.render(camera, T, SensorNoiseConfig::kinect(5));
  const RenderResult b = renderer.render(camera, T, SensorNoiseConfig::kinect(5));
  EXPECT_EQ(a.depth.pixels, b.depth.pixels);
  int dropped = 0, changed = 0;
  double sum_sq = 0;
  for (size_t i = 0; i < clean.depth.pixels.size(); ++i) {
    if (clean.depth.pixels[i] <= 0) continue;
    if (a.depth.pixels[i] == 0) {
      ++dropped;
      continue;
    }
    const double e = a.depth.pixels[i] - clean.depth.pixels[i];
    changed += e != 0.0;
    sum_sq += e * e;
  }
  EXPECT_GT(dropped, 100);
  EXPECT_GT(changed, 1000);
  const double rms = std::sqrt(sum_sq / changed);
  EXPECT_GT(rms, 0.0005);
  EXPECT_LT(rms, 0.005);
}

TEST(Viewpoints, WithinThePapersRanges) {
  std::mt19937_64 rng(8);
  const Vec3 centre(0.1, -0.1, 0.1);
  for (int i = 0; i < 500; ++i) {
    const Transform T = sampleViewpoint(centre, ViewpointRange(), rng);
    const Vec3 eye = T.translation();
    EXPECT_GE((eye - centre).norm(), 0.5);
    EXPECT_GE(eye.z(), 0.1);
    EXPECT_LE(eye.z(), 1.0);
    EXPECT_LE(std::abs(eye.x() - centre.x()), 1.0);
    EXPECT_NEAR(T.linear().col(2).dot((centre - eye).normalized()), 1.0, 1e-9);
  }
}
