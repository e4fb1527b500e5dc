#include <gtest/gtest.h>

#include <cmath>

#include "simstack/offline/dataset/viewpoints.h"
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

TEST(DepthRenderer, RefusesMoreObjectsThanItsInstanceImageTellsApart) {
  // Instances are k + 1 in 8 bits beside the table (0) and no surface (255): a 255th object
  // would be drawn as no surface, a 256th as the table.
  Scene many = sphereScene(0.01, Vec3::Zero());
  many.objects.resize(255, many.objects.front());
  EXPECT_THROW(DepthRenderer{many}, std::invalid_argument);
  many.objects.resize(254);
  EXPECT_NO_THROW(DepthRenderer{many});
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

namespace {
/// A camera `height_m` above the table point (0, 0), looking straight down, its x along the
/// table's x.
Transform overheadCamera(double height_m) {
  Transform T = Transform::Identity();
  T.linear() << 1, 0, 0, 0, -1, 0, 0, 0, -1;
  T.translation() = Vec3(0.0, 0.0, height_m);
  return T;
}
}  // namespace

TEST(DepthRenderer, SecondEyeShadowsTheTableBesideABox) {
  // A 10 cm cube (exponents 20) on the table, the camera 0.5 m above its centre, the second eye
  // 0.1 m along the camera's x. A table point (x, 0, 0) left of the cube is seen by the camera
  // for x < -0.0625 m and hidden from the second eye for x > -0.0875 m (the segment to (0.1, 0,
  // 0.5) meets the face x = -0.05 below the top at z = 0.1).
  SuperquadricShape sq;
  sq.scale_m = Vec3::Constant(0.05);
  sq.exponents = Vec3::Constant(20.0);
  SceneObject cube;
  cube.shape = ObjectShape::fromSuperquadric(sq);
  cube.T_table_object.translation() = Vec3(0.0, 0.0, 0.05);
  const DepthRenderer renderer(Scene{{cube}});
  const PinholeCamera camera = test::centredCamera(640, 480, 525.0);
  const Transform T = overheadCamera(0.5);
  SensorNoiseConfig shadow;
  shadow.shadow_baseline_m = 0.1;
  const RenderResult clean = renderer.render(camera, T);
  const RenderResult shadowed = renderer.render(camera, T, shadow);
  int in_band = 0, band_missing = 0, outside = 0, outside_missing = 0, clean_missing = 0;
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      if (clean.instances.at(u, v) != 0) continue;  // table pixels only
      const Vec3 d = T.linear() * camera.ray(u, v);
      const Vec3 hit = T.translation() + (-T.translation().z() / d.z()) * d;
      if (std::abs(hit.y()) > 0.03) continue;
      const bool missing = shadowed.depth.at(u, v) == 0.0f;
      clean_missing += clean.depth.at(u, v) == 0.0f;
      if (hit.x() > -0.084 && hit.x() < -0.066) {
        ++in_band;
        band_missing += missing;
      } else if ((hit.x() < -0.091 && hit.x() > -0.2) || (hit.x() > 0.06 && hit.x() < 0.2)) {
        ++outside;
        outside_missing += missing;
      }
    }
  }
  EXPECT_EQ(clean_missing, 0);
  ASSERT_GT(in_band, 200);
  EXPECT_EQ(band_missing, in_band);
  ASSERT_GT(outside, 2000);
  EXPECT_EQ(outside_missing, 0);
  // The cube's top face is seen by both eyes.
  int top = 0, top_missing = 0;
  for (size_t i = 0; i < clean.instances.pixels.size(); ++i) {
    if (clean.instances.pixels[i] != 1) continue;
    ++top;
    top_missing += shadowed.depth.pixels[i] == 0.0f;
  }
  ASSERT_GT(top, 1000);
  EXPECT_LT(top_missing, top / 100);
}

TEST(DepthRenderer, StereoNoiseGrowsWithTheSquareOfTheDepth) {
  const DepthRenderer renderer(Scene{});
  const PinholeCamera camera = test::centredCamera(640, 480, 525.0);
  SensorNoiseConfig stereo;
  stereo.sigma_stereo_per_m = 0.0025;
  stereo.seed = 3;
  for (const double height : {0.6, 1.0}) {
    const RenderResult r = renderer.render(camera, overheadCamera(height), stereo);
    double sum_sq = 0.0;
    int n = 0;
    for (const float z : r.depth.pixels) {
      if (z <= 0.0f) continue;
      sum_sq += (z - height) * (z - height);
      ++n;
    }
    ASSERT_GT(n, 100000);
    // sigma = 0.0025 z^2: 0.9 mm at 0.6 m, 2.5 mm at 1 m.
    EXPECT_NEAR(std::sqrt(sum_sq / n), 0.0025 * height * height, 0.03 * 0.0025 * height * height)
        << "at " << height << " m";
  }
}

TEST(DepthRenderer, RealSensePresetHasAMinimumRange) {
  const DepthRenderer renderer(Scene{});
  const PinholeCamera camera = test::wideCamera();
  auto returned = [&](double height) {
    const RenderResult r =
        renderer.render(camera, overheadCamera(height), SensorNoiseConfig::realsense(1));
    int n = 0;
    for (const float z : r.depth.pixels) n += z > 0.0f;
    return n;
  };
  EXPECT_EQ(returned(0.25), 0);
  EXPECT_GT(returned(0.5), camera.width * camera.height / 2);
  EXPECT_EQ(parseSensorModel("realsense"), SensorModel::realsense);
  EXPECT_STREQ(sensorModelName(parseSensorModel("kinect")), "kinect");
  try {
    parseSensorModel("kinect2");
    FAIL() << "accepted sensor kinect2";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("kinect2"), std::string::npos) << e.what();
  }
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
