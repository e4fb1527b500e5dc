// Scene metrics, the classical baseline and the scene files, against known answers.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <numeric>
#include <optional>
#include <random>
#include <set>
#include <tuple>

#include "simstack/io/scene_io.h"
#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/offline/eval/classical_baseline.h"
#include "simstack/offline/eval/evaluated_methods.h"
#include "simstack/offline/eval/evaluator.h"
#include "simstack/offline/eval/grasp_evaluation.h"
#include "simstack/offline/eval/real_scenes.h"
#include "simstack/offline/eval/scene_metrics.h"
#include "simstack/offline/eval/segmentation.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/scene/scene.h"
#include "test_scenes.h"

namespace simstack {
namespace {

SuperquadricShape box(const Vec3& half, const Vec3& centre, double yaw = 0.0) {
  SuperquadricShape sq;
  sq.scale_m = half;
  sq.exponents = Vec3::Constant(10.0);
  sq.T_table_object = Transform::Identity();
  sq.T_table_object.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
  sq.T_table_object.translation() = centre;
  return sq;
}

TEST(GraspEvaluation, EstimateErrorTurnsOnlyBetweenAxesOfAlikeLengths) {
  SuperquadricShape truth;
  truth.scale_m = Vec3(0.10, 0.04, 0.02);
  truth.T_table_object.translation() = Vec3(0.1, 0.0, 0.05);
  const auto turned = [&](const Vec3& scale, double deg) {
    SuperquadricShape e = truth;
    e.scale_m = scale;
    e.T_table_object.linear() = Eigen::AngleAxisd(deg * M_PI / 180.0, Vec3::UnitZ()).matrix();
    e.T_table_object.translation() += Vec3(0.003, -0.004, 0.001);
    return e;
  };
  // A long box estimated a quarter turn off is 90 degrees off, not 0.
  EstimateError e = estimateError(turned(truth.scale_m, 90.0), truth);
  EXPECT_NEAR(e.rotation_deg, 90.0, 1e-6);
  EXPECT_NEAR(e.centre_m.x(), 0.003, 1e-12);
  EXPECT_NEAR(e.scale_ratio.maxCoeff(), 1.0, 1e-12);
  // Its axes swapped with their lengths: the same shape, a small turn.
  e = estimateError(turned(Vec3(0.04, 0.10, 0.02), 95.0), truth);
  EXPECT_NEAR(e.rotation_deg, 5.0, 1e-6);
  // A square-sided box is alike after a quarter turn about its square face's normal.
  truth.scale_m = Vec3(0.05, 0.05, 0.02);
  EXPECT_NEAR(estimateError(turned(truth.scale_m, 87.0), truth).rotation_deg, 3.0, 1e-6);
  EXPECT_NEAR(estimateError(turned(Vec3(0.06, 0.05, 0.02), 7.0), truth).scale_ratio.z(), 1.2,
              1e-12);
}

TEST(Chamfer, ZeroForIdenticalSetsAndTwiceTheShiftForAPlane) {
  Points3 a, b;
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 40; ++j) {
      a.emplace_back(0.01 * i, 0.01 * j, 0.0);
      b.emplace_back(0.01 * i, 0.01 * j, 0.003);
    }
  EXPECT_NEAR(chamferDistance(a, a), 0.0, 1e-12);
  EXPECT_NEAR(chamferDistance(a, b), 0.006, 1e-9);  // 3 mm each way
  EXPECT_TRUE(std::isinf(chamferDistance(a, Points3{})));
}

TEST(Visibility, AboutHalfOfASphereFacesTheCamera) {
  SuperquadricShape sphere;
  sphere.scale_m = Vec3::Constant(0.1);
  sphere.T_table_object.translation() = Vec3(0, 0, 0.2);
  const TriangleMesh mesh = sphere.meshObject(24).transformed(sphere.T_table_object);
  PinholeCamera camera;
  const Transform T = lookAt(Vec3(2.0, 0, 0.2), Vec3(0, 0, 0.2));  // far: nearly orthographic
  const TriangleMesh seen = subMesh(mesh, visibleTriangles(mesh, camera, T));
  EXPECT_NEAR(seen.area() / mesh.area(), 0.5 * (1 - 0.1 / 2.0), 0.03);  // cap seen from 2 m
}

TEST(Occupancy, SuperquadricVoxelsMatchTheVolume) {
  const SuperquadricShape b = box(Vec3(0.1, 0.06, 0.04), Vec3(0.01, 0.0, 0.04), 0.3);
  const GridSpec g = GridSpec::sceneGrid(Vec2(0, 0), 0.64, 64);
  const std::vector<float> occ = superquadricOccupancy({b}, g);
  int inside = 0;
  for (float v : occ) inside += v < 0;
  const double volume = inside * std::pow(g.voxel_size_m, 3);
  EXPECT_NEAR(volume, b.volume(), 0.08 * b.volume());
}

TEST(Stability, ARestingPileIsStableAndAFloatingTowerFalls) {
  const std::vector<SuperquadricShape> resting = {
      box(Vec3(0.08, 0.06, 0.04), Vec3(0, 0, 0.04)),
      box(Vec3(0.05, 0.05, 0.03), Vec3(0.0, 0.0, 0.111))};
  const StabilityResult r = simulateStability(resting);
  EXPECT_TRUE(r.stable);
  EXPECT_LT(r.mean_displacement_m, 0.01);
  // A thin slab balanced on its edge, tilted: it falls over.
  SuperquadricShape slab = box(Vec3(0.01, 0.1, 0.15), Vec3(0, 0, 0.151));
  slab.T_table_object.linear() = Eigen::AngleAxisd(0.2, Vec3::UnitY()).toRotationMatrix();
  slab.T_table_object.translation().z() = 0.16;
  const StabilityResult f = simulateStability({slab});
  EXPECT_FALSE(f.stable);
  EXPECT_GT(f.max_rotation_rad, 0.5);
}

TEST(Stability, GeneratedPilesPassTheTestOverTheSecondTheGeneratorVerified) {
  // The test simulates with the physics that settled the piles (rolling friction included): a
  // generated pile, verified at rest for one second, must pass one second of the test, and a
  // scene of superquadrics must score the same as its shapes.
  const PileGenerator generator{PileConfig()};
  StabilityConfig one_second;
  one_second.steps = 240;
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    const Scene scene = generator.generate(seed).scene;
    const StabilityResult r = simulateStability(scene, one_second);
    EXPECT_TRUE(r.stable) << r.max_displacement_m << " m, " << r.max_rotation_rad << " rad";
    EXPECT_LT(r.max_displacement_m, 0.02);
    std::vector<SuperquadricShape> shapes;
    for (const SceneObject& o : scene.objects) shapes.push_back(o.superquadricTable());
    EXPECT_DOUBLE_EQ(simulateStability(shapes, one_second).mean_displacement_m,
                     r.mean_displacement_m);
  }
}

TEST(ClassicalBaseline, SeparatedBoxesGiveOneShapeEach) {
  const std::vector<SuperquadricShape> truth = {
      box(Vec3(0.05, 0.05, 0.05), Vec3(-0.12, 0, 0.05)),
      box(Vec3(0.04, 0.06, 0.03), Vec3(0.12, 0.02, 0.03), 0.5)};
  const Scene scene = Scene::fromSuperquadrics(truth);
  PinholeCamera camera;
  const Transform T = lookAt(Vec3(0.5, -0.4, 0.6), Vec3(0, 0, 0.03));
  const RenderResult r = DepthRenderer(scene).render(camera, T);
  ClassicalConfig config;
  const std::vector<Points3> clusters = clusterVisiblePoints(r.depth, camera, T, config);
  ASSERT_EQ(clusters.size(), 2u);
  const std::vector<SuperquadricShape> shapes = classicalBaseline(r.depth, camera, T, config);
  ASSERT_EQ(shapes.size(), 2u);
  for (const SuperquadricShape& t : truth) {
    double best = 1e9;
    for (const SuperquadricShape& s : shapes)
      best = std::min(best, (s.centroid() - t.centroid()).norm());
    EXPECT_LT(best, 0.03);  // visible points only: the hidden half is a guess
  }
  // Nothing above the table: no clusters, no shapes.
  const RenderResult empty = DepthRenderer(Scene{}).render(camera, T);
  EXPECT_TRUE(classicalBaseline(empty.depth, camera, T, config).empty());
}

TEST(Segmentation, OneToOneMatchingByLargestOverlap) {
  // Objects 0 (6 elements) and 1 (4); instance 7 covers object 0 and half of object 1, instance
  // 8 the other half: 7 goes to object 0 (overlap 6), 8 to object 1 (2 of its 4 elements).
  const std::vector<int> truth = {0, 0, 0, 0, 0, 0, 1, 1, 1, 1, -1, -1};
  const std::vector<int> found = {7, 7, 7, 7, 7, 7, 7, 7, 8, 8, 8, -1};
  const SegmentationAgreement s = segmentationAgreement(truth, found);
  EXPECT_NEAR(s.agreement, 8.0 / 10.0, 1e-12);
  EXPECT_EQ(s.objects, 2);
  EXPECT_EQ(s.instances, 2);
  // One instance for everything: only the larger object is matched.
  EXPECT_NEAR(segmentationAgreement(truth, std::vector<int>(12, 3)).agreement, 0.6, 1e-12);
  // Relabelling the instances changes nothing; unassigned elements never agree.
  std::vector<int> renamed = found;
  for (int& f : renamed) f = f < 0 ? f : 20 - f;
  EXPECT_NEAR(segmentationAgreement(truth, renamed).agreement, 0.8, 1e-12);
  EXPECT_NEAR(segmentationAgreement(truth, std::vector<int>(12, -1)).agreement, 0.0, 1e-12);
  EXPECT_NEAR(segmentationAgreement(truth, truth).agreement, 1.0, 1e-12);
  EXPECT_THROW(segmentationAgreement(truth, std::vector<int>(3, 0)), std::invalid_argument);
}

TEST(Segmentation, TheAssignmentHasTheLargestTotalWeightOfAnyShape) {
  // Against every one-to-one assignment (a brute force over permutations of the padded square).
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> weight(0.0, 1.0);
  for (const auto& [rows, columns] : std::vector<std::pair<int, int>>{{4, 6}, {6, 4}, {5, 5}}) {
    for (int trial = 0; trial < 20; ++trial) {
      std::vector<std::vector<double>> w(rows, std::vector<double>(columns));
      for (auto& row : w)
        for (double& x : row) x = weight(rng);
      const std::vector<int> match = maximumWeightAssignment(w);
      ASSERT_EQ(match.size(), static_cast<size_t>(rows));
      double total = 0;
      std::vector<bool> used(columns, false);
      int assigned = 0;
      for (int i = 0; i < rows; ++i) {
        if (match[i] < 0) continue;
        ASSERT_LT(match[i], columns);
        EXPECT_FALSE(used[match[i]]) << "column " << match[i] << " used twice";
        used[match[i]] = true;
        total += w[i][match[i]];
        ++assigned;
      }
      EXPECT_EQ(assigned, std::min(rows, columns));
      const int n = std::max(rows, columns);
      std::vector<int> perm(n);
      std::iota(perm.begin(), perm.end(), 0);
      double best = 0;
      do {
        double t = 0;
        for (int i = 0; i < rows; ++i)
          if (perm[i] < columns) t += w[i][perm[i]];
        best = std::max(best, t);
      } while (std::next_permutation(perm.begin(), perm.end()));
      EXPECT_NEAR(total, best, 1e-9);
    }
  }
  EXPECT_TRUE(maximumWeightAssignment({}).empty());
  EXPECT_THROW(maximumWeightAssignment({{1, 2}, {3}}), std::invalid_argument);
}

TEST(Segmentation, OverlapScoresPairObjectsAndInstancesByTheirFMeasure) {
  // Object 0 (10 elements) and object 1 (2). Instance 5 covers 6 of object 0 and all of
  // object 1, instance 6 the other 4 of object 0; two table elements are left unlabelled.
  // F(0,5) = 0.667, F(0,6) = 0.571, F(1,5) = 0.4: the largest sum pairs 0 with 6 and 1 with 5
  // (0.971 against 0.667), where the largest overlap would pair 0 with 5.
  std::vector<int> truth(14, -1), found(14, -1);
  for (int i = 0; i < 10; ++i) truth[i] = 0;
  truth[10] = truth[11] = 1;
  for (int i = 0; i < 6; ++i) found[i] = 5;
  for (int i = 6; i < 10; ++i) found[i] = 6;
  found[10] = found[11] = 5;
  OverlapScores s = overlapScores(truth, found);
  EXPECT_EQ(s.objects, 2);
  EXPECT_EQ(s.instances, 2);
  EXPECT_NEAR(s.precision, 6.0 / 12.0, 1e-12);  // 4 + 2 matched of 12 found
  EXPECT_NEAR(s.recall, 6.0 / 12.0, 1e-12);
  EXPECT_NEAR(s.f_measure, 0.5, 1e-12);
  EXPECT_NEAR(s.detected_075, 0.0, 1e-12);
  // The truth itself, under other names: every score 1.
  std::vector<int> renamed = truth;
  for (int& t : renamed) t = t < 0 ? -1 : 40 - t;
  s = overlapScores(truth, renamed);
  EXPECT_NEAR(s.f_measure, 1.0, 1e-12);
  EXPECT_NEAR(s.detected_075, 1.0, 1e-12);
  // An instance that spills onto the table loses precision only; above 0.75 it is detected.
  renamed[12] = renamed[13] = renamed[11];
  s = overlapScores(truth, renamed);
  EXPECT_NEAR(s.precision, 12.0 / 14.0, 1e-12);
  EXPECT_NEAR(s.recall, 1.0, 1e-12);
  EXPECT_NEAR(s.detected_075, 0.5, 1e-12);  // object 1: F = 2 x 0.5 x 1 / 1.5 = 0.667
  // Nothing found, nothing there, or both (UOIS-Net's conventions).
  s = overlapScores(truth, std::vector<int>(14, -1));
  EXPECT_EQ(std::make_tuple(s.precision, s.recall, s.f_measure), std::make_tuple(1.0, 0.0, 0.0));
  s = overlapScores(std::vector<int>(14, -1), found);
  EXPECT_EQ(std::make_tuple(s.precision, s.recall, s.f_measure), std::make_tuple(0.0, 1.0, 0.0));
  s = overlapScores(std::vector<int>(3, -1), std::vector<int>(3, -1));
  EXPECT_EQ(std::make_tuple(s.precision, s.recall, s.f_measure, s.detected_075),
            std::make_tuple(1.0, 1.0, 1.0, 1.0));
  EXPECT_THROW(overlapScores(truth, std::vector<int>(3, 0)), std::invalid_argument);
}

TEST(RealScenes, MosdFileNamesGiveTheirCategory) {
  const std::vector<std::pair<std::string, std::string>> names = {
      {"learn0.pcd", "boxes"},
      {"learn16.pcd", "boxes"},
      {"learn17.pcd", "stacked boxes"},
      {"learn32.pcd", "occluded"},
      {"learn33.pcd", "cylindrical"},
      {"/a/b/learn44.pcd", "cylindrical"},
      {"learn45.pcd", ""},
      {"test15.pcd", "boxes"},
      {"test16.pcd", "stacked boxes"},
      {"test30.pcd", "occluded"},
      {"test31.pcd", "cylindrical"},
      {"test42.pcd", "cylindrical"},
      {"test43.pcd", "mixed"},
      {"test54.pcd", "mixed"},
      {"test55.pcd", "complex"},
      {"TEST64.PCD", "complex"},
      {"test66.pcd", ""},
      {"test.pcd", ""},
      {"learn3x.pcd", ""},
      {"scene_12.pcd", ""}};
  for (const auto& [name, category] : names) EXPECT_EQ(mosdCategory(name), category) << name;
}

/// A labelled cloud as mOSD stores one, from a rendered view: the camera-frame points of the
/// valid pixels, label 1 on the table and 10 (k + 1) + (v % 2) on object k (two parts each).
void writeMosdLikeCloud(const std::string& path, const RenderResult& r, const PinholeCamera& camera,
                        bool organized, double z_noise_m = 0.0) {
  Points3 points;
  std::vector<int> labels;
  for (int v = 0; v < r.depth.height; ++v)
    for (int u = 0; u < r.depth.width; ++u) {
      const float d = r.depth.at(u, v);
      const int k = r.instances.at(u, v);
      const bool valid = validDepth(d) && k != kNoSurface;
      if (!valid && !organized) continue;
      points.push_back(valid ? camera.backproject(u, v, d) : Vec3::Constant(std::nan("")));
      // z filtered after x and y were taken: moved up and down in a checkerboard.
      points.back().z() += (u + v) % 2 ? z_noise_m : -z_noise_m;
      labels.push_back(!valid ? 0 : k == 0 ? 1 : 10 * (k + 1) + v % 2);
    }
  writeLabelledCloudPcd(path, points, labels);
  if (!organized) return;
  // writeLabelledCloudPcd writes one row: make the header say width x height.
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  const std::string width = "WIDTH " + std::to_string(points.size()) + "\nHEIGHT 1\n";
  const size_t at = text.find(width);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, width.size(),
               "WIDTH " + std::to_string(r.depth.width) + "\nHEIGHT " +
                   std::to_string(r.depth.height) + "\n");
  f.close();
  std::ofstream(path, std::ios::binary | std::ios::trunc) << text;
}

TEST(RealScenes, AnUnorganizedCloudIsPlacedOnThePixelsOfTheCamera) {
  const Scene scene =
      Scene::fromSuperquadrics({box(Vec3(0.05, 0.05, 0.05), Vec3(-0.12, 0, 0.05)),
                                box(Vec3(0.04, 0.06, 0.03), Vec3(0.12, 0.02, 0.03))});
  const PinholeCamera camera;  // mOSD's Kinect
  const RenderResult r =
      DepthRenderer(scene).render(camera, lookAt(Vec3(0.5, -0.4, 0.6), Vec3(0, 0, 0.03)));
  const auto dir = test::tempPath("simstack_test_unorganized");
  std::filesystem::create_directories(dir);
  const std::string loose = (dir / "loose.pcd").string(), grid = (dir / "grid.pcd").string();
  writeMosdLikeCloud(loose, r, camera, false);
  writeMosdLikeCloud(grid, r, camera, true);
  Image<uint32_t> loose_labels, grid_labels;
  const DepthImage a = readDepthPcd(loose, &camera, &loose_labels);
  const DepthImage b = readDepthPcd(grid, nullptr, &grid_labels);
  ASSERT_EQ(a.width, camera.width);
  ASSERT_EQ(a.height, camera.height);
  int valid = 0;
  for (size_t i = 0; i < a.pixels.size(); ++i) {
    ASSERT_EQ(validDepth(a.pixels[i]), validDepth(b.pixels[i])) << "pixel " << i;
    if (!validDepth(a.pixels[i])) continue;
    ++valid;
    EXPECT_NEAR(a.pixels[i], b.pixels[i], 1e-6);
    EXPECT_EQ(loose_labels.pixels[i], grid_labels.pixels[i]);
  }
  EXPECT_GT(valid, 100000);
  // Without a camera, with another camera, or with two points on one pixel: refused by name.
  const auto refused = [&](const std::string& path, const PinholeCamera* c, const char* why) {
    try {
      readDepthPcd(path, c);
      ADD_FAILURE() << "accepted " << path << " (" << why << ")";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(why), std::string::npos) << e.what();
    }
  };
  refused(loose, nullptr, "not an organized cloud");
  PinholeCamera other = camera;
  other.fx = other.fy = 600;
  refused(loose, &other, "does not fall on a pixel");
  const Vec3 centre_pixel(0.5 / 525, 0.5 / 525, 1.0);  // on pixel (320, 240)
  writeLabelledCloudPcd((dir / "twice.pcd").string(), {centre_pixel, centre_pixel}, {20, 30});
  refused((dir / "twice.pcd").string(), &camera, "falls on the pixel of point 0");
  // An organized cloud holds its camera in its x and y: another one is refused, naming it.
  refused(grid, &other, "they fit fx 525, fy 525, cx 319.5, cy 239.5");
  other = camera;
  other.fx = other.fy = 524;  // 0.6 px off at the corners
  refused(grid, &other, "other intrinsics?");
  EXPECT_EQ(readDepthPcd(grid, &camera).width, 640);
  // Its z moved by 2 mm after x and y were taken (a depth filter): still its camera.
  const std::string filtered = (dir / "filtered.pcd").string();
  writeMosdLikeCloud(filtered, r, camera, true, 0.002);
  EXPECT_EQ(readDepthPcd(filtered, &camera).width, 640);
  // Its own camera: the given one when its points fit it, else the one they fit.
  std::optional<PinholeCamera> own;
  readDepthPcd(filtered, &camera, nullptr, &own);
  ASSERT_TRUE(own);
  EXPECT_EQ(own->fx, 525.0);
  const PinholeCamera half = test::centredCamera(320, 240, 260.0);
  writeMosdLikeCloud(
      filtered, DepthRenderer(scene).render(half, lookAt(Vec3(0.5, -0.4, 0.6), Vec3(0, 0, 0.03))),
      half, true);
  readDepthPcd(filtered, &camera, nullptr, &own);
  ASSERT_TRUE(own);
  EXPECT_NEAR(own->fx, 260.0, 1e-3);
  EXPECT_NEAR(own->cx, 159.5, 1e-3);
  EXPECT_EQ(own->width, 320);
  std::filesystem::remove_all(dir);
}

/// Answers with the objects of labelled views it was given (or with nothing).
class LabelledAnswer : public EvaluatedMethod {
 public:
  LabelledAnswer(std::string name, std::map<int, Image<int>> answers, bool nothing)
      : name_(std::move(name)), answers_(std::move(answers)), nothing_(nothing) {}
  const std::string& name() const override { return name_; }
  MethodInfo info() const override { return {}; }
  MethodEstimate estimate(const DepthView& view, const GridSpec*, const Vec2&) override {
    MethodEstimate out;
    out.pixel_instances = Image<int>(view.depth.width, view.depth.height, -1);
    if (nothing_) return out;
    const Image<int>& truth = answers_.at(view.depth.width);
    std::set<int> objects;
    for (size_t i = 0; i < truth.pixels.size(); ++i)
      if (truth.pixels[i] >= 0) {
        out.pixel_instances.pixels[i] = 100 - truth.pixels[i];
        objects.insert(truth.pixels[i]);
      }
    out.superquadrics.resize(objects.size());
    out.fits_at_bound = 1;  // counted through to the summary and the table
    return out;
  }

 private:
  std::string name_;
  std::map<int, Image<int>> answers_;  ///< by image width: the views differ in size
  bool nothing_;
};

TEST(RealScenes, TheTruthScoresOneAndNothingZeroByCategory) {
  const auto dir = test::tempPath("simstack_test_real_scenes");
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const Scene scene =
      Scene::fromSuperquadrics({box(Vec3(0.05, 0.05, 0.05), Vec3(-0.12, 0, 0.05)),
                                box(Vec3(0.04, 0.06, 0.03), Vec3(0.12, 0.02, 0.03))});
  std::map<int, Image<int>> answers;
  for (const auto& [name, width] :
       std::vector<std::pair<std::string, int>>{{"learn3.pcd", 320}, {"test50.pcd", 330}}) {
    const PinholeCamera camera = test::centredCamera(width, 240, 260.0);
    const RenderResult r =
        DepthRenderer(scene).render(camera, lookAt(Vec3(0.5, -0.4, 0.6), Vec3(0, 0, 0.03)));
    writeMosdLikeCloud((dir / name).string(), r, camera, true);
    answers[width] = readLabelledView((dir / name).string()).objects;
  }
  LabelledAnswer truth("truth", answers, false), nothing("nothing", answers, true);
  const std::vector<RealMethodResults> results =
      evaluateRealScenes(dir.string(), {&truth, &nothing});
  ASSERT_EQ(results.size(), 2u);
  ASSERT_EQ(results[0].scenes.size(), 2u);
  EXPECT_EQ(results[0].scenes[0].scene, "learn3.pcd");
  EXPECT_EQ(results[0].scenes[0].category, "boxes");
  EXPECT_EQ(results[0].scenes[1].category, "mixed");
  EXPECT_EQ(results[0].scenes[0].objects, 2);  // two parts each, label / 10 merges them
  const nlohmann::json t = realSummary(results[0].scenes), n = realSummary(results[1].scenes);
  EXPECT_DOUBLE_EQ(t["overlap_f"].get<double>(), 1.0);
  EXPECT_DOUBLE_EQ(t["count_exact"].get<double>(), 1.0);
  EXPECT_DOUBLE_EQ(n["overlap_f"].get<double>(), 0.0);
  EXPECT_DOUBLE_EQ(n["count_error"].get<double>(), -2.0);
  EXPECT_EQ(realSummary(results[0].scenes, "mixed")["scenes"].get<int>(), 1);
  EXPECT_EQ(t["fits_at_bound"].get<int>(), 2);  // a total, not a mean
  EXPECT_TRUE(n["fits_at_bound"].is_null());    // a method that does not count them
  const std::string table = realScenesTable(results);
  EXPECT_NE(table.find("truth: 2 superquadrics at the fitter's lower bound"), std::string::npos)
      << table;
  EXPECT_EQ(table.find("at the fitter's lower bound"), table.rfind("at the fitter's lower bound"))
      << "one line, the truth's: " << table;
  EXPECT_NE(table.find("| truth: boxes | 1 | 100.0 | 100.0 | 100.0 | 100.0 | 100 % |"),
            std::string::npos)
      << table;
  EXPECT_NE(table.find("| nothing: mixed | 1 |"), std::string::npos) << table;
  EXPECT_NE(table.find("| -2.00 | 2.00 |\n"), std::string::npos) << table;  // a cell per figure
  const std::vector<RealMethodResults> first = evaluateRealScenes(dir.string(), {&truth}, {}, 1);
  ASSERT_EQ(first.size(), 1u);
  ASSERT_EQ(first[0].scenes.size(), 1u);
  EXPECT_EQ(first[0].scenes[0].scene, "learn3.pcd");
  std::filesystem::remove_all(dir);
}

TEST(GraspSummary, PicksNeverPulledFreeNothingAndDoNotDiluteThePulls) {
  // Two pulls (one freed its target and moved the others 10 mm, one broke its seal after
  // moving them 30 mm and toppling one) and a pick whose estimate had no match for the target.
  std::vector<PickResult> picks(3);
  for (PickResult& p : picks) p.method = "m", p.chooser = "ranked";
  picks[0].outcome.cup_held = true, picks[0].outcome.target_freed = true;
  picks[0].outcome.mean_displacement_m = 0.010;
  picks[1].outcome.cup_held = false, picks[1].outcome.mean_displacement_m = 0.030;
  picks[1].outcome.toppled = 1;
  picks[2].found = false, picks[2].grasped = false, picks[2].outcome.cup_held = false;
  // The oracle's picks of the same three targets: the first and last freed, the second's seal
  // broke.
  for (int t = 0; t < 3; ++t) {
    picks[t].target = t;
    PickResult o;
    o.method = "truth", o.chooser = "ranked", o.target = t;
    o.outcome.cup_held = t != 1;
    o.outcome.target_freed = t != 1;
    picks.push_back(o);
  }
  const nlohmann::json all = graspSummary(picks);
  ASSERT_EQ(all.size(), 2u);
  const nlohmann::json s = nlohmann::json::array({all[0]});
  // Against the oracle: half its freed share (one target of its two), and as many broken seals
  // on the two targets both pulled (one each; over all three of the oracle's pulls, one of
  // three, the ratio would read 1.5).
  EXPECT_NEAR(s[0]["freed_of_oracle"].get<double>(), 0.5, 1e-12);
  EXPECT_NEAR(s[0]["seal_broke_of_oracle"].get<double>(), 1.0, 1e-12);
  // One resample in 27 draws none of the oracle's two freed targets: no interval.
  EXPECT_TRUE(s[0]["freed_of_oracle_ci95"].is_null()) << s[0]["freed_of_oracle_ci95"];
  EXPECT_NEAR(all[1]["freed_of_oracle"].get<double>(), 1.0, 1e-12);
  EXPECT_DOUBLE_EQ(s[0]["picks"].get<double>(), 3.0);
  EXPECT_NEAR(s[0]["pulled_share"].get<double>(), 2.0 / 3, 1e-12);
  EXPECT_NEAR(s[0]["freed_share"].get<double>(), 1.0 / 3, 1e-12);
  EXPECT_NEAR(s[0]["target_found_share"].get<double>(), 2.0 / 3, 1e-12);
  EXPECT_NEAR(s[0]["seal_broke_share"].get<double>(), 0.5, 1e-12);  // of the two pulls
  EXPECT_NEAR(s[0]["mean_displacement_mm"].get<double>(), 20.0, 1e-9);
  EXPECT_NEAR(s[0]["freed_mean_displacement_mm"].get<double>(), 10.0, 1e-9);
  EXPECT_NEAR(s[0]["toppled_share"].get<double>(), 0.5, 1e-12);
  EXPECT_NE(graspSummaryTable(s).find("| m | ranked | 3 | 67 % | 33 % | 50 % | "),
            std::string::npos)
      << graspSummaryTable(s);
}

TEST(GraspSummary, TheIntervalOverTheOraclesShareLeavesOutResamplesWhereItFreedNothing) {
  // 40 targets: the method frees every other one the oracle frees.
  const auto picksWith = [](int oracle_freed) {
    std::vector<PickResult> picks;
    for (int t = 0; t < 40; ++t) {
      PickResult m, o;
      m.method = "m", o.method = "truth";
      m.chooser = o.chooser = "ranked";
      m.target = o.target = t;
      o.outcome.cup_held = o.outcome.target_freed = t < oracle_freed;
      m.outcome.cup_held = m.outcome.target_freed = t < oracle_freed && t % 2 == 0;
      picks.push_back(m);
      picks.push_back(o);
    }
    return graspSummary(picks)[0];
  };
  // Freeing 20: every resample has oracle successes, and the interval lies round a half.
  const nlohmann::json half = picksWith(20);
  EXPECT_NEAR(half["freed_of_oracle"].get<double>(), 0.5, 1e-12);
  const double low = half["freed_of_oracle_ci95"][0].get<double>();
  const double high = half["freed_of_oracle_ci95"][1].get<double>();
  EXPECT_GT(low, 0.2);
  EXPECT_LT(low, 0.5);
  EXPECT_GT(high, 0.5);
  EXPECT_LT(high, 0.8);
  // Freeing 2: 0.95^40, 13 % of the resamples, hold none of them; counting those as a ratio of
  // 0 would pin the low end at 0. The ratio stands, the interval is not given.
  const nlohmann::json few = picksWith(2);
  EXPECT_NEAR(few["freed_of_oracle"].get<double>(), 0.5, 1e-12);
  EXPECT_TRUE(few["freed_of_oracle_ci95"].is_null()) << few["freed_of_oracle_ci95"];
}

TEST(GraspSummary, AMethodThatPulledNothingHasNoPullFigures) {
  // Two targets: the oracle frees both without a broken seal; the method found neither.
  std::vector<PickResult> picks;
  for (int t = 0; t < 2; ++t) {
    PickResult m;
    m.method = "m", m.chooser = "ranked", m.target = t;
    m.found = false, m.grasped = false;
    PickResult o;
    o.method = "truth", o.chooser = "ranked", o.target = t;
    o.outcome.cup_held = true, o.outcome.target_freed = true;
    picks.push_back(m);
    picks.push_back(o);
  }
  const nlohmann::json all = graspSummary(picks);
  ASSERT_EQ(all.size(), 2u);
  const nlohmann::json& m = all[0];
  EXPECT_NEAR(m["freed_share"].get<double>(), 0.0, 1e-12);
  EXPECT_NEAR(m["freed_of_oracle"].get<double>(), 0.0, 1e-12);
  for (const char* key : {"seal_broke_share", "mean_displacement_mm", "median_displacement_mm",
                          "freed_mean_displacement_mm", "toppled_share", "seal_broke_of_oracle"})
    EXPECT_TRUE(m[key].is_null()) << key << " " << m[key];
  // The oracle broke no seal: its own ratio to itself is not defined either.
  EXPECT_TRUE(all[1]["seal_broke_of_oracle"].is_null());
  EXPECT_NE(graspSummaryTable(all).find(
                "| m | ranked | 2 | 0 % | 0 % | 0 % (0-0) | - | - | - | - | - | - |"),
            std::string::npos)
      << graspSummaryTable(all);
}

TEST(SceneFiles, SuperquadricsMeshesAndGridsRoundTrip) {
  const auto dir = test::tempPath("simstack_test_eval");
  std::filesystem::create_directories(dir);
  const std::vector<SuperquadricShape> shapes = {
      box(Vec3(0.05, 0.04, 0.03), Vec3(0.1, -0.2, 0.03), 0.7),
      box(Vec3(0.02, 0.03, 0.04), Vec3(0, 0, 0.1), -1.2)};
  writeSuperquadricsYaml((dir / "sq.yaml").string(), shapes);
  std::optional<Vec3> camera = Vec3(9, 9, 9);
  const std::vector<SuperquadricShape> back =
      readSuperquadricsYaml((dir / "sq.yaml").string(), nullptr, &camera);
  EXPECT_FALSE(camera.has_value());  // none written
  writeSuperquadricsYaml((dir / "sq_camera.yaml").string(), shapes, "table", {},
                         Vec3(0.5, -0.25, 0.75));
  readSuperquadricsYaml((dir / "sq_camera.yaml").string(), nullptr, &camera);
  ASSERT_TRUE(camera.has_value());
  EXPECT_TRUE(camera->isApprox(Vec3(0.5, -0.25, 0.75)));
  ASSERT_EQ(back.size(), 2u);
  for (int i = 0; i < 2; ++i) {
    EXPECT_TRUE(back[i].scale_m.isApprox(shapes[i].scale_m, 1e-9));
    EXPECT_TRUE(back[i].exponents.isApprox(shapes[i].exponents, 1e-9));
    EXPECT_TRUE(back[i].T_table_object.isApprox(shapes[i].T_table_object, 1e-9));
  }
  const TriangleMesh mesh = superquadricsMesh(shapes, 8);
  writeMeshPly((dir / "m.ply").string(), mesh);
  const TriangleMesh m2 = readMeshPly((dir / "m.ply").string());
  EXPECT_EQ(m2.triangles.size(), mesh.triangles.size());
  EXPECT_NEAR(m2.area(), mesh.area(), 1e-6);
  writeLabelledCloudPcd((dir / "c.pcd").string(), {Vec3(1, 2, 3), Vec3(4, 5, 6)}, {0, 2});
  EXPECT_TRUE(std::filesystem::file_size(dir / "c.pcd") > 0);
  EXPECT_THROW(readSuperquadricsYaml((dir / "missing.yaml").string()), std::runtime_error);
  std::ofstream(dir / "bad.yaml") << "objects:\n  - {scale: [1, 2], exponents: [2, 2, 2]}\n";
  try {
    readSuperquadricsYaml((dir / "bad.yaml").string());
    ADD_FAILURE() << "a short scale list must be rejected";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.yaml"), std::string::npos);
  }
  // A field given twice (yaml-cpp would read the first) is named, with where both stand.
  std::ofstream(dir / "twice.yaml")
      << "objects:\n  - {scale: [1, 2, 3], exponents: [2, 2, 2], scale: [3, 2, 1]}\n";
  try {
    readSuperquadricsYaml((dir / "twice.yaml").string());
    ADD_FAILURE() << "a repeated field must be rejected";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(
        std::string(e.what()).find("'objects[0].scale' appears twice (line 2, columns 6 and "),
        std::string::npos)
        << e.what();
  }
  // A word where a number belongs, a misspelt key, an id twice, a file that is not a map: each
  // named with the file.
  const std::string object =
      "scale: [0.05, 0.05, 0.05], exponents: [2, 2, 2], position: [0, 0, 0.05], "
      "orientation: [1, 0, 0, 0]";
  const std::vector<std::pair<std::string, std::string>> spoiled = {
      {"objects:\n  - {scale: [0.05, abc, 0.05], exponents: [2, 2, 2], position: [0, 0, 0], "
       "orientation: [1, 0, 0, 0]}\n",
       "'scale' must be a list of 3 numbers"},
      {"objects:\n  - {" + object + ", colour: red}\n", "unknown key 'colour' in object 0"},
      {"bogus: 1\nobjects:\n  - {" + object + "}\n", "unknown key 'bogus'"},
      {"frame: [1, 2]\nobjects:\n  - {" + object + "}\n", "frame is not a name"},
      {"objects:\n  - {id: 0, " + object + "}\n  - {id: 0, " + object + "}\n",
       "id 0 is given twice"},
      {"just text\n", "no 'objects' list"},
      {"objects:\n  - {" + object + ", truncated: maybe}\n",
       "object 0's truncated is not true or false"},
      {"objects: [1, 2]\n", "object 0 is not a map"}};
  for (const auto& [text, message] : spoiled) {
    std::ofstream(dir / "spoiled.yaml") << text;
    std::vector<int> ids;
    try {
      readSuperquadricsYaml((dir / "spoiled.yaml").string(), &ids);
      ADD_FAILURE() << "accepted: " << text;
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("spoiled.yaml"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(message), std::string::npos) << e.what();
    }
  }
  // A camera at or below the table measured no pile.
  std::ofstream(dir / "below.yaml") << "camera: [0, 0, -1]\nobjects:\n  - {" << object << "}\n";
  try {
    readSuperquadricsYaml((dir / "below.yaml").string(), nullptr, &camera);
    ADD_FAILURE() << "accepted a camera below the table";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("below.yaml: camera is at z = -1"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW(readDepthPcd((dir / "c.pcd").string()), std::runtime_error);  // not organized
  std::filesystem::remove_all(dir);
}

// The protocol against methods whose answer is known: the truth itself scores IoU 1, exact
// counts and a Chamfer distance at the sampling floor; a method that finds nothing scores
// IoU 0 and no exact count.
class KnownAnswer : public EvaluatedMethod {
 public:
  KnownAnswer(std::string name, const DatasetReader& reader, bool truth)
      : name_(std::move(name)), reader_(reader), truth_(truth) {}
  const std::string& name() const override { return name_; }
  MethodInfo info() const override { return {}; }
  MethodEstimate estimate(const DepthView&, const GridSpec* grid, const Vec2& pile_xy) override {
    const SceneRecord rec = reader_.read(scene_++ / 2);  // 2 views per scene
    MethodEstimate out;
    out.grid =
        grid ? *grid
             : GridSpec::sceneGrid(pile_xy, reader_.info().extent_m, reader_.info().resolution);
    if (!truth_) {
      out.hypotheses_tsdf.emplace_back(out.grid.voxelCount(), 1.0f);
      out.surfaces.emplace_back();
      return out;
    }
    out.hypotheses_tsdf.push_back(
        computeGroundTruth(rec.scene, out.grid, reader_.info().truncation_m).tsdf.data);
    TriangleMesh mesh;
    for (const SceneObject& o : rec.scene.objects) {
      mesh.append(o.shape->mesh().transformed(o.T_table_object));
      out.superquadrics.push_back(o.superquadricTable());
    }
    out.surfaces.push_back(mesh);
    return out;
  }

 private:
  std::string name_;
  const DatasetReader& reader_;
  bool truth_;
  int scene_ = 0;
};

/// A dataset of two generated piles in a temporary file.
std::filesystem::path twoPileDataset(const std::string& name) {
  const std::filesystem::path path = test::tempPath(name);
  DatasetInfo info;
  info.num_scenes = 2;
  DatasetWriter writer(path.string(), info);
  const PileGenerator generator{PileConfig()};
  for (int k = 0; k < 2; ++k) {
    const Scene scene = generator.generate(31 + k).scene;
    const GridSpec grid =
        GridSpec::sceneGrid(scene.surfaceCentroid().head<2>(), info.extent_m, info.resolution);
    writer.write(k, scene, computeGroundTruth(scene, grid, info.truncation_m));
  }
  return path;
}

// Methods that place their grids themselves, 10 cm off the first method's or at half its side
// (a network perceiving a view in a finer grid): each is scored in its own grid, where its
// true answer is the ground truth, not voxel by voxel against a grid lying elsewhere.
class Elsewhere : public KnownAnswer {
 public:
  Elsewhere(std::string name, const DatasetReader& reader, Vec2 shift, double extent_m)
      : KnownAnswer(std::move(name), reader, true), shift_(shift), extent_m_(extent_m) {}
  MethodEstimate estimate(const DepthView& view, const GridSpec*, const Vec2& pile_xy) override {
    const GridSpec own = GridSpec::sceneGrid(pile_xy + shift_, extent_m_, 32);
    return KnownAnswer::estimate(view, &own, pile_xy);
  }

 private:
  Vec2 shift_;
  double extent_m_;
};

// A method that takes the grid it is handed, as the classical baseline does, and records it.
class TakesTheGrid : public KnownAnswer {
 public:
  using KnownAnswer::KnownAnswer;
  MethodEstimate estimate(const DepthView& view, const GridSpec* grid,
                          const Vec2& pile_xy) override {
    handed.push_back(grid ? std::optional<GridSpec>(*grid) : std::nullopt);
    piles.push_back(pile_xy);
    return KnownAnswer::estimate(view, grid, pile_xy);
  }
  std::vector<std::optional<GridSpec>> handed;
  std::vector<Vec2> piles;
};

TEST(Evaluator, AMethodOnAnotherGridIsScoredInItsOwn) {
  const std::filesystem::path path = twoPileDataset("simstack_evaluator_grid.h5");
  const DatasetReader reader(path.string());
  KnownAnswer truth("truth", reader, true);
  Elsewhere shifted("shifted", reader, Vec2(0.1, 0.0), reader.info().extent_m);
  Elsewhere finer("finer", reader, Vec2::Zero(), 0.5 * reader.info().extent_m);
  TakesTheGrid taker("taker", reader, true);
  EvaluationOptions options;
  options.views = 2;
  options.stability = false;
  const EvaluationResults r = evaluateDataset(reader, {&truth, &shifted, &finer, &taker}, options);
  ASSERT_EQ(r.methods.size(), 4u);
  // The method that takes a grid is handed the first method's, not the last one scored.
  ASSERT_EQ(taker.handed.size(), 4u);
  for (size_t i = 0; i < taker.handed.size(); ++i) {
    ASSERT_TRUE(taker.handed[i]);
    const GridSpec truths =
        GridSpec::sceneGrid(taker.piles[i], reader.info().extent_m, reader.info().resolution);
    EXPECT_TRUE(*taker.handed[i] == truths) << "view " << i;
  }
  for (const MethodResults& m : r.methods) {
    ASSERT_EQ(m.rows.size(), 4u);
    for (const Row& row : m.rows) {
      EXPECT_DOUBLE_EQ(row.at("iou"), 1.0) << m.name;
      EXPECT_DOUBLE_EQ(row.at("count_exact"), 1.0) << m.name;
    }
  }
  std::filesystem::remove(path);
}

TEST(Evaluator, TheTruthScoresPerfectlyAndNothingScoresNothing) {
  const std::filesystem::path path = twoPileDataset("simstack_evaluator_test.h5");
  const DatasetReader reader(path.string());
  KnownAnswer truth("truth", reader, true), nothing("nothing", reader, false);
  EvaluationOptions options;
  options.views = 2;
  options.stability = false;
  options.chamfer_points = 4000;  // two samplings of a surface differ by ~1 cm at this count
  int progress = 0;
  const EvaluationResults r = evaluateDataset(
      reader, {&truth, &nothing}, options, [&](int done, int total) { progress = done + total; });
  EXPECT_EQ(progress, 4);
  ASSERT_EQ(r.methods.size(), 2u);
  ASSERT_EQ(r.methods[0].rows.size(), 4u);
  for (const Row& row : r.methods[0].rows) {
    EXPECT_DOUBLE_EQ(row.at("iou"), 1.0);
    EXPECT_DOUBLE_EQ(row.at("count_exact"), 1.0);
    EXPECT_LT(row.at("chamfer_full_m"), 0.02);  // two samplings of one surface
    EXPECT_LT(row.at("chamfer_visible_m"), 0.02);
    EXPECT_GT(row.at("visible_ratio"), 0.1);
    EXPECT_LT(row.at("visible_ratio"), 0.9);
  }
  for (const Row& row : r.methods[1].rows) {
    EXPECT_DOUBLE_EQ(row.at("iou"), 0.0);
    EXPECT_DOUBLE_EQ(row.at("count_exact"), 0.0);
  }
  for (const Row& row : r.methods[0].rows) {  // the truth counts every object, seen or not
    EXPECT_GE(row.at("objects_seen"), 1.0);
    EXPECT_LE(row.at("objects_seen"), row.at("objects"));
    EXPECT_EQ(row.at("count_exact_seen") == 1.0, row.at("objects_seen") == row.at("objects"));
  }
  // No object fills the whole image: none is seen, and only a count of none is exact.
  options.seen_pixels = options.width * options.height + 1;
  KnownAnswer truth_again("truth", reader, true), nothing_again("nothing", reader, false);
  const EvaluationResults none = evaluateDataset(reader, {&truth_again, &nothing_again}, options);
  for (const Row& row : none.methods[0].rows) {
    EXPECT_DOUBLE_EQ(row.at("objects_seen"), 0.0);
    EXPECT_DOUBLE_EQ(row.at("count_exact_seen"), 0.0);
  }
  for (const Row& row : none.methods[1].rows) EXPECT_DOUBLE_EQ(row.at("count_exact_seen"), 1.0);
  const nlohmann::json j = resultsJson(r, false);
  EXPECT_DOUBLE_EQ(j["methods"]["truth"]["iou"]["mean"].get<double>(), 1.0);
  EXPECT_EQ(j["methods"]["truth"]["iou"]["n"].get<int>(), 4);
  EXPECT_FALSE(j["methods"]["truth"].contains("views"));
  EXPECT_TRUE(resultsJson(r, true)["methods"]["nothing"].contains("views"));
  EXPECT_NE(resultsTable(r).find("| truth | "), std::string::npos);
  std::filesystem::remove(path);
}

// A method that keeps the views it was given and predicts nothing.
class ViewRecorder : public EvaluatedMethod {
 public:
  explicit ViewRecorder(const DatasetInfo& info) : info_(info) {}
  const std::string& name() const override { return name_; }
  MethodInfo info() const override { return {}; }
  MethodEstimate estimate(const DepthView& view, const GridSpec* grid,
                          const Vec2& pile_xy) override {
    return estimateViews({view}, grid, pile_xy);
  }
  MethodEstimate estimateViews(const std::vector<DepthView>& views, const GridSpec*,
                               const Vec2& pile_xy) override {
    seen.push_back(views);
    MethodEstimate out;
    out.grid = GridSpec::sceneGrid(pile_xy, info_.extent_m, info_.resolution);
    out.hypotheses_tsdf.emplace_back(out.grid.voxelCount(), 1.0f);
    out.surfaces.emplace_back();
    out.objects = false;
    return out;
  }
  std::vector<std::vector<DepthView>> seen;

 private:
  DatasetInfo info_;
  std::string name_ = "recorder";
};

/// One 160 x 120 view per scene, no stability test: the protocol's mechanics, quickly.
EvaluationOptions oneSmallView() {
  EvaluationOptions options;
  options.views = 1;
  options.stability = false;
  options.width = 160;
  options.height = 120;
  return options;
}

// The multi-view protocol: its first view is the single-view protocol's, the others circle the
// pile at the same distance and height; TSDF fusion scores higher with more views; a method
// that takes one view is refused.
TEST(Evaluator, MultiViewCirclesThePileFromTheSingleView) {
  const std::filesystem::path path = twoPileDataset("simstack_evaluator_multiview.h5");
  const DatasetReader reader(path.string());
  EvaluationOptions options = oneSmallView();
  options.noise = true;
  std::map<int, std::vector<double>> fusion_iou, visible;
  std::map<int, std::vector<std::vector<DepthView>>> seen;
  for (const int k : {1, 3, 6}) {
    options.views_per_estimate = k;
    ViewRecorder recorder(reader.info());
    FusionMethod fusion(reader.info().extent_m, reader.info().resolution,
                        reader.info().truncation_m);
    const EvaluationResults r = evaluateDataset(reader, {&recorder, &fusion}, options);
    for (const Row& row : r.methods[1].rows) {
      fusion_iou[k].push_back(row.at("iou"));
      visible[k].push_back(row.at("visible_ratio"));
      EXPECT_EQ(row.count("count_exact"), 0u);  // fusion finds no objects
    }
    seen[k] = recorder.seen;
  }
  for (int scene = 0; scene < 2; ++scene) {
    const Vec3 centre = reader.read(scene).scene.surfaceCentroid();
    const DepthView& single = seen[1][scene].front();
    ASSERT_EQ(seen[3][scene].size(), 3u);
    EXPECT_EQ(seen[3][scene].front().depth.pixels, single.depth.pixels);  // noise included
    for (const DepthView& v : seen[6][scene]) {
      const Vec3 eye = v.T_table_camera->translation() - centre;
      const Vec3 first = single.T_table_camera->translation() - centre;
      EXPECT_NEAR(eye.norm(), first.norm(), 1e-9);
      EXPECT_NEAR(eye.z(), first.z(), 1e-9);
    }
    const Vec3 a = seen[3][scene][0].T_table_camera->translation() - centre,
               b = seen[3][scene][1].T_table_camera->translation() - centre;
    EXPECT_NEAR(std::atan2(a.x() * b.y() - a.y() * b.x(), a.head<2>().dot(b.head<2>())),
                2.0 * M_PI / 3.0, 1e-9);
    // The turned camera looks the same way relative to the pile: its optical axis turned too.
    const Eigen::AngleAxisd turn(2.0 * M_PI / 3.0, Vec3::UnitZ());
    EXPECT_LT((seen[3][scene][1].T_table_camera->linear().col(2) -
               turn * seen[3][scene][0].T_table_camera->linear().col(2))
                  .norm(),
              1e-9);
    EXPECT_GT(visible[6][scene], visible[1][scene] + 0.1);
    EXPECT_GT(fusion_iou[6][scene], fusion_iou[1][scene] + 0.05);
    EXPECT_GE(visible[6][scene], visible[3][scene]);
  }
  KnownAnswer one_view("truth", reader, true);
  options.views_per_estimate = 2;
  EXPECT_THROW(evaluateDataset(reader, {&one_view}, options), std::invalid_argument);
  std::filesystem::remove(path);
}

// Another camera's intrinsics: the views are rendered with it (the same viewpoints), and the
// scaled Kinect given explicitly renders what the default does.
TEST(Evaluator, RendersWithTheGivenCamera) {
  const std::filesystem::path path = twoPileDataset("simstack_evaluator_camera.h5");
  const DatasetReader reader(path.string());
  EvaluationOptions options = oneSmallView();
  ViewRecorder kinect(reader.info());
  evaluateDataset(reader, {&kinect}, options);
  options.camera = scaledKinect(160, 120);
  ViewRecorder explicit_kinect(reader.info());
  evaluateDataset(reader, {&explicit_kinect}, options);
  const PinholeCamera wide = test::centredCamera(212, 120, 106.0);  // 90 degrees across
  options.camera = wide;
  ViewRecorder realsense(reader.info());
  const EvaluationResults r = evaluateDataset(reader, {&realsense}, options);
  ASSERT_EQ(realsense.seen.size(), 2u);
  for (size_t i = 0; i < 2; ++i) {
    const DepthView& a = kinect.seen[i].front();
    const DepthView& w = realsense.seen[i].front();
    EXPECT_EQ(explicit_kinect.seen[i].front().depth.pixels, a.depth.pixels);
    EXPECT_EQ(w.depth.width, 212);
    EXPECT_DOUBLE_EQ(w.camera.fx, 106.0);
    EXPECT_TRUE(w.T_table_camera->isApprox(*a.T_table_camera));  // the same viewpoint
    // Exactly what that camera sees from there (no noise in these views).
    const DepthRenderer renderer(reader.read(static_cast<int>(i)).scene);
    EXPECT_EQ(renderer.render(wide, *w.T_table_camera, SensorNoiseConfig()).depth.pixels,
              w.depth.pixels);
  }
  const nlohmann::json j = resultsJson(r, false);
  EXPECT_EQ(j["image"], "212x120");
  EXPECT_DOUBLE_EQ(j["intrinsics"][0].get<double>(), 106.0);
  options.camera->fx = 0.5;  // a focal length in metres, not pixels
  ViewRecorder refused(reader.info());
  EXPECT_THROW(evaluateDataset(reader, {&refused}, options), std::invalid_argument);
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace simstack
