// The perception pipeline: table estimation, decomposition of known grids, and
// ScenePerception end to end with the shipped model.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <thread>

#include "simstack/fitting/superquadric_fit.h"
#include "simstack/instances/instance_finder.h"
#include "simstack/model/cvae_inference.h"
#include "simstack/model/model_integrity.h"
#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/offline/eval/evaluated_methods.h"
#include "simstack/offline/eval/real_scenes.h"
#include "simstack/offline/eval/segmentation.h"
#include "simstack/offline/piles/mesh_catalogue.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/pipeline/object_tracker.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack/pipeline/view_history.h"
#include "simstack/render/depth_renderer.h"
#include "test_scenes.h"

namespace simstack {
namespace {

const std::string kModel = std::string(SIMSTACK_SOURCE_DIR) + "/models/simstack_r32.pt";

struct RenderedPile {
  Scene scene;
  PinholeCamera camera;
  Transform T_table_camera;
  RenderResult view;
};

RenderedPile renderPile(uint64_t seed, const PileConfig& piles = PileConfig()) {
  RenderedPile p;
  p.scene = PileGenerator(piles).generate(seed).scene;
  const Vec3 centre = p.scene.surfaceCentroid();
  p.T_table_camera = lookAt(centre + Vec3(0.55, -0.35, 0.55), Vec3(centre.x(), centre.y(), 0.05));
  const DepthRenderer renderer(p.scene);
  p.view = renderer.render(p.camera, p.T_table_camera);
  return p;
}

PerceptionConfig shippedConfig(const std::string& name = "perception") {
  const std::string dir = SIMSTACK_SOURCE_DIR;
  return loadPerceptionYaml(dir + "/config/" + name + ".yaml", dir);
}

TEST(PerceptionConfig, ShippedYamlHoldsTheDefaultsAndTyposAreErrors) {
  const std::string dir = SIMSTACK_SOURCE_DIR;
  const PerceptionConfig c = loadPerceptionYaml(dir + "/config/perception.yaml", dir);
  EXPECT_EQ(c.model_path, dir + "/models/simstack_r32_fc.pt");
  // With the C-VAE named (its card holds the struct's sample count, and the Hough setting it
  // shares with `fc`, whose decoder it took), the file is the struct's defaults.
  const PerceptionConfig with_cvae =
      loadPerceptionYaml(dir + "/config/perception.yaml", dir, kModel);
  PerceptionConfig defaults;
  defaults.model_path = kModel;
  defaults.hough.refinement = 8;
  defaults.hough.min_traversals = 3;
  defaults.hough.min_instance_voxels = 25;
  EXPECT_EQ(perceptionYaml(with_cvae), perceptionYaml(defaults));
  const std::string bad = test::tempPath("simstack_bad_perception.yaml");
  std::ofstream(bad) << "hough:\n  min_travesals: 3\n";
  try {
    loadPerceptionYaml(bad);
    ADD_FAILURE() << "a misspelt field must be an error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("hough.min_travesals"), std::string::npos) << e.what();
  }
  std::ofstream(bad) << "hough:\n  min_traversals: many\n";
  EXPECT_THROW(loadPerceptionYaml(bad), std::runtime_error);
  // The pipeline's own fields stand at the top level: a misspelt one, or the section an older
  // layout kept them in, is refused by name.
  const auto refusal = [&](const std::string& text) {
    std::ofstream(bad) << text;
    try {
      loadPerceptionYaml(bad);
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_NE(refusal("symetries: 4\n").find("unknown field 'symetries'"), std::string::npos);
  EXPECT_NE(refusal("perception:\n  symmetries: 4\n").find("top level"), std::string::npos);
  EXPECT_NE(refusal("node:\n  table_frame: t\n").find("perception_node.yaml"), std::string::npos);
  // A misspelt section field is refused by its full name.
  EXPECT_NE(refusal("hough:\n  bandwith_m: 0.04\n").find("unknown field hough.bandwith_m"),
            std::string::npos);
  std::ofstream(bad) << "hough:\n  refinement: 6\n  min_vote_norm: 0.3\n";
  const PerceptionConfig split = loadPerceptionYaml(bad);
  EXPECT_EQ(split.hough.refinement, 6);
  EXPECT_DOUBLE_EQ(split.hough.min_vote_norm, 0.3);
  std::ofstream(bad) << perceptionYaml(split);  // the full dump reads back as it was
  EXPECT_EQ(perceptionYaml(loadPerceptionYaml(bad)), perceptionYaml(split));
  std::filesystem::remove(bad);
}

TEST(PerceptionConfig, ACardSectionReadsBackAsTheSettingItCameFrom) {
  HoughConfig h;
  h.refinement = 8;
  h.min_vote_norm = 0.3;
  const std::string text = modelCardPerceptionYaml(1, h);
  // The section pasted into a card is read back as the setting it came from.
  const auto dir = test::tempPath("simstack_card_section");
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "m.yaml") << text;
  PerceptionConfig c;
  c.model_path = (dir / "m.pt").string();
  applyModelCard(&c);
  EXPECT_EQ(c.hough.refinement, 8);
  EXPECT_DOUBLE_EQ(c.hough.min_vote_norm, 0.3);
  // A misspelt section would leave the card's setting (or its checksum) unread: refused.
  for (const char* misspelt : {"perceptoin", "integirty"}) {
    std::ofstream(dir / "m.yaml") << misspelt << ":\n  samples: 1\n";
    PerceptionConfig d;
    d.model_path = (dir / "m.pt").string();
    try {
      applyModelCard(&d);
      ADD_FAILURE() << "a card section '" << misspelt << "' was passed over";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("unknown section '" + std::string(misspelt) + "'"),
                std::string::npos)
          << e.what();
    }
    EXPECT_THROW(readModelIntegrity(d.model_path), std::runtime_error);
  }
  std::filesystem::remove_all(dir);
}

TEST(PerceptionConfig, ParametersAreLaidOverTheShippedFileFieldByField) {
  // What the ROS node reads: the package's file, with a field of its own and one of a section.
  const std::string dir = SIMSTACK_SOURCE_DIR;
  const PerceptionConfig c =
      overlayPerceptionYaml(dir + "/config/perception.yaml",
                            "symmetries: 2\nsegments:\n  pixel_stride: 3\n", "params", dir);
  const PerceptionConfig shipped = loadPerceptionYaml(dir + "/config/perception.yaml", dir);
  EXPECT_EQ(c.symmetries, 2);
  EXPECT_EQ(c.segments.pixel_stride, 3);
  EXPECT_EQ(c.segments.seed_resolution_m, shipped.segments.seed_resolution_m);  // kept
  EXPECT_EQ(c.model_path, shipped.model_path);
  EXPECT_EQ(c.hough.refinement, shipped.hough.refinement);  // the model's card
  try {
    overlayPerceptionYaml(dir + "/config/perception.yaml", "segments:\n  pixel_strid: 3\n",
                          "the parameters under /camera/perception", dir);
    ADD_FAILURE() << "a misspelt parameter must be an error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("segments.pixel_strid"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("/camera/perception"), std::string::npos) << e.what();
  }
}

TEST(PerceptionConfig, ModelCardsBringTheirOwnSettings) {
  const std::string dir = SIMSTACK_SOURCE_DIR;
  const std::string config = dir + "/config/perception.yaml";
  // The default model is `fc` (the best test IoU), with its card's setting.
  const PerceptionConfig fc = loadPerceptionYaml(config, dir);
  EXPECT_EQ(fc.model_card_path, dir + "/models/simstack_r32_fc.yaml");
  EXPECT_EQ(fc.samples, 1);
  EXPECT_EQ(fc.hough.refinement, 8);
  EXPECT_EQ(fc.hough.min_traversals, 3);
  // Naming the C-VAE brings its samples and setting (fc's, which is not the struct's default).
  const PerceptionConfig cvae = loadPerceptionYaml(config, dir, dir + "/models/simstack_r32.pt");
  EXPECT_EQ(cvae.model_card_path, dir + "/models/simstack_r32.yaml");
  EXPECT_EQ(cvae.samples, 3);
  EXPECT_EQ(cvae.hough.refinement, 8);
  EXPECT_EQ(cvae.hough.min_traversals, 3);
  EXPECT_NE(cvae.hough.refinement, HoughConfig().refinement);
  // Naming another model is enough to get its setting.
  const PerceptionConfig plain =
      loadPerceptionYaml(config, dir, dir + "/models/simstack_r32_fc_plain.pt");
  EXPECT_EQ(plain.model_card_path, dir + "/models/simstack_r32_fc_plain.yaml");
  EXPECT_EQ(plain.samples, 1);
  EXPECT_EQ(plain.hough.refinement, 3);
  EXPECT_EQ(plain.hough.min_traversals, 3);
  EXPECT_DOUBLE_EQ(plain.hough.bandwidth_m, 0.04);
  EXPECT_EQ(plain.hough.min_instance_voxels, 25);
  EXPECT_DOUBLE_EQ(plain.hough.min_vote_norm, 0.3);
  EXPECT_EQ(plain.fit.max_points, cvae.fit.max_points);  // the pipeline's settings are shared

  const std::filesystem::path tmp = test::tempPath("simstack_model_cards");
  std::filesystem::create_directories(tmp);
  // What a config says explicitly overrides the card, field by field.
  std::ofstream(tmp / "override.yaml") << "samples: 2\nhough:\n  refinement: 7\n";
  const PerceptionConfig over = loadPerceptionYaml((tmp / "override.yaml").string(), dir,
                                                   dir + "/models/simstack_r32_fc_plain.pt");
  EXPECT_EQ(over.samples, 2);
  EXPECT_EQ(over.hough.refinement, 7);
  EXPECT_EQ(over.hough.min_traversals, 3);
  // A model without a card keeps the defaults; a misspelt card field is an error naming it.
  const PerceptionConfig bare = loadPerceptionYaml(config, dir, (tmp / "no_card.pt").string());
  EXPECT_TRUE(bare.model_card_path.empty());
  EXPECT_EQ(perceptionYaml(bare).find("refinement: 5") != std::string::npos, true);
  std::ofstream(tmp / "typo.yaml") << "model: {}\nperception:\n  hough:\n    refinment: 3\n";
  try {
    loadPerceptionYaml(config, dir, (tmp / "typo.pt").string());
    ADD_FAILURE() << "a misspelt card field must be an error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("typo.yaml"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("hough.refinment"), std::string::npos) << e.what();
  }
  std::ofstream(tmp / "typo.yaml") << "perception:\n  sampels: 3\n";
  EXPECT_THROW(loadPerceptionYaml(config, dir, (tmp / "typo.pt").string()), std::runtime_error);
  // yaml-cpp answers a repeated key with its first value: a card whose tuned section was
  // appended below the trainer's would run with the default setting. It is an error instead.
  std::ofstream(tmp / "twice.yaml") << "model: {}\nperception:\n  samples: 1\n"
                                    << "perception:\n  hough:\n    refinement: 8\n";
  try {
    loadPerceptionYaml(config, dir, (tmp / "twice.pt").string());
    ADD_FAILURE() << "a card repeating its perception section must be an error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("twice.yaml"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("'perception' appears twice (lines 2 and 4)"),
              std::string::npos)
        << e.what();
  }
  try {  // at any depth, in a config given as text too
    parsePerceptionYaml("segments:\n  enabled: true\n  enabled: false\n", "inline");
    ADD_FAILURE() << "a repeated field must be an error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("'segments.enabled' appears twice"), std::string::npos)
        << e.what();
  }
  std::filesystem::remove_all(tmp);
}

TEST(EvaluatedMethods, ResultsRecordTheModelRelativeToTheWorkingDirectory) {
  // Results written from checkouts in different places must compare equal: a model below the
  // working directory is recorded by its relative path, in the config's copy too.
  const std::string dir = SIMSTACK_SOURCE_DIR;
  const std::filesystem::path before = std::filesystem::current_path();
  std::filesystem::current_path(dir);
  const NetworkMethod method(loadPerceptionYaml(dir + "/config/perception.yaml", dir), false);
  const MethodInfo info = method.info();
  std::filesystem::current_path(before);
  EXPECT_EQ(info.model, "models/simstack_r32_fc.pt");
  EXPECT_NE(info.config_yaml.find("model: models/simstack_r32_fc.pt"), std::string::npos)
      << info.config_yaml;
  EXPECT_EQ(info.config_yaml.find(dir + "/models"), std::string::npos) << info.config_yaml;
}

TEST(TablePlane, RecoversTheTableOfARenderedScene) {
  const RenderedPile p = renderPile(11);
  const TablePlane plane = estimateTablePlane(p.view.depth, p.camera);
  // Table points (instance 0) land on z = 0 of the estimated frame.
  double worst = 0;
  for (int v = 0; v < p.camera.height; v += 7)
    for (int u = 0; u < p.camera.width; u += 7) {
      if (p.view.instances.at(u, v) != 0) continue;
      const Vec3 q = plane.T_table_camera * p.camera.backproject(u, v, p.view.depth.at(u, v));
      worst = std::max(worst, std::abs(q.z()));
    }
  EXPECT_LT(worst, 0.002);
  // Its z axis is the true one.
  const Vec3 z_true = p.T_table_camera.linear().transpose() * Vec3::UnitZ();  // in the camera frame
  const Vec3 z_est = plane.T_table_camera.linear().transpose() * Vec3::UnitZ();
  EXPECT_GT(z_true.dot(z_est), std::cos(M_PI / 180.0));
  // Objects are above it.
  const Vec3 top = plane.T_table_camera * p.T_table_camera.inverse() * p.scene.surfaceCentroid();
  EXPECT_GT(top.z(), 0.0);
}

TEST(TablePlane, HolesInStepWithTheSampleStrideLeaveTheTableFound) {
  RenderedPile p = renderPile(11);
  const int stride = TablePlaneConfig().pixel_stride;
  for (int v = 0; v < p.camera.height; ++v)
    for (int u = 0; u < p.camera.width; u += stride) p.view.depth.at(u, v) = 0.0f;
  const TablePlane plane = estimateTablePlane(p.view.depth, p.camera);
  const Vec3 z_true = p.T_table_camera.linear().transpose() * Vec3::UnitZ();
  const Vec3 z_est = plane.T_table_camera.linear().transpose() * Vec3::UnitZ();
  EXPECT_GT(z_true.dot(z_est), std::cos(M_PI / 180.0));
  EXPECT_GT(plane.points, 1000);
}

TEST(TablePlane, FailsClearlyWithoutDepth) {
  PinholeCamera camera;
  const DepthImage empty(camera.width, camera.height, std::nanf(""));
  EXPECT_THROW(estimateTablePlane(empty, camera), std::runtime_error);
  EXPECT_THROW(estimateTablePlane(DepthImage(10, 10, 1.0f), camera), std::invalid_argument);
}

/// A generated pile with its ground-truth TSDF and votes as the network's output would be.
struct TruePile {
  explicit TruePile(uint64_t seed)
      : scene(PileGenerator(PileConfig()).generate(seed).scene),
        grid(GridSpec::sceneGrid(scene.surfaceCentroid().head<2>(), 0.64, 32)) {
    const GroundTruthGrids gt = computeGroundTruth(scene, grid, 3 * grid.voxel_size_m);
    h.tsdf_m = gt.tsdf;
    h.votes = gt.votes;
  }
  Scene scene;
  GridSpec grid;
  SceneHypothesis h;  ///< not yet decomposed
};

/// Exact votes: the Hough setting for sharp votes (the shipped default is chosen for the
/// shipped model's blunter ones, and splits one of the first five piles' objects in two).
PerceptionConfig sharpVotesConfig() {
  PerceptionConfig config;
  config.hough.min_traversals = 5;
  config.hough.bandwidth_m = 0.07;
  return config;
}

TEST(Decompose, GroundTruthGridsGiveOneFittedShapePerObject) {
  const PerceptionConfig config = sharpVotesConfig();
  for (uint64_t seed : {1, 2, 3, 4, 5}) {
    TruePile pile(seed);
    const Scene& scene = pile.scene;
    const GridSpec& grid = pile.grid;
    SceneHypothesis& h = pile.h;
    StageTimings timings;
    decompose(&h, config, &timings);
    ASSERT_TRUE(h.decomposed);
    ASSERT_EQ(h.instances.size(), scene.objects.size()) << "seed " << seed;
    for (const SceneObject& o : scene.objects) {
      double best = 1e9;
      for (const InstanceEstimate& e : h.instances)
        best = std::min(best, (e.superquadric.centroid() - o.T_table_object.translation()).norm());
      EXPECT_LT(best, grid.voxel_size_m) << "seed " << seed;
    }
    for (const InstanceEstimate& e : h.instances) {
      EXPECT_GE(e.superquadric.exponents.minCoeff(), config.fit.min_exponent);
      EXPECT_GT(e.superquadric.scale_m.minCoeff(), 0.0);
    }
    EXPECT_GT(timings.fitting_ms, 0.0);
  }
}

/// Distance of a table-frame point to the nearest object's surface (along its centre's ray).
double distanceToScene(const Scene& scene, const Vec3& p) {
  double best = std::numeric_limits<double>::infinity();
  for (const SceneObject& o : scene.objects) {
    SuperquadricShape sq = o.shape->superquadric();
    sq.T_table_object = o.T_table_object;
    best = std::min(best, std::abs(surfaceDistance(sq, p)));
  }
  return best;
}

// A network that places every surface 1 cm inside the objects (the true TSDF plus 1 cm): the
// seen part of each instance is then handed to the fitter as the view's depth points, which
// lie on the true surface, and the fits come nearer the true volumes than fits to the
// shrunken mesh alone. A second view from the other side measures more of each surface.
TEST(Decompose, TheSeenSurfaceComesFromTheDepthPoints) {
  PerceptionConfig config = sharpVotesConfig();
  for (uint64_t seed : {1, 2, 3}) {
    TruePile pile(seed);
    for (float& d : pile.h.tsdf_m.data) d += 0.01f;
    PinholeCamera camera;
    const Vec3 centre = pile.scene.surfaceCentroid();
    const Vec3 target(centre.x(), centre.y(), 0.05);
    const Transform T_first = lookAt(centre + Vec3(0.55, -0.35, 0.55), target);
    const Transform T_second = lookAt(centre + Vec3(-0.55, 0.35, 0.55), target);
    const DepthRenderer renderer(pile.scene);
    const DepthView first_view{renderer.render(camera, T_first).depth, camera, T_first};
    const DepthView second{renderer.render(camera, T_second).depth, camera, T_second};
    const std::optional<SurfaceSegments> segments =
        InstanceFinder(config.hough, config.segments)
            .segmentView(first_view.depth, camera, T_first, config.min_pile_height_m, &pile.grid);
    ASSERT_TRUE(segments) << "seed " << seed;
    // Mesh samples alone, the first view's depth points, both views' depth points.
    double near_share[3] = {0, 0, 0}, volume_error[3] = {0, 0, 0};
    for (int variant = 0; variant < 3; ++variant) {
      config.observed_points = variant > 0;
      std::vector<MeasuredView> measured{measuredView(first_view, T_first, pile.grid, config)};
      if (variant == 2) measured.push_back(measuredView(second, T_second, pile.grid, config));
      SceneHypothesis h = pile.h;
      decompose(&h, config, nullptr, &*segments, measured);
      ASSERT_EQ(h.instances.size(), pile.scene.objects.size()) << "seed " << seed;
      int near = 0, total = 0;
      for (const InstanceEstimate& e : h.instances) {
        for (const Vec3& p : e.points) near += distanceToScene(pile.scene, p) < 0.002;
        total += static_cast<int>(e.points.size());
        // The volume error against the object whose centre is nearest the fit's.
        const SceneObject* match = nullptr;
        for (const SceneObject& o : pile.scene.objects)
          if (!match ||
              (o.T_table_object.translation() - e.superquadric.centroid()).norm() <
                  (match->T_table_object.translation() - e.superquadric.centroid()).norm())
            match = &o;
        const double truth = match->shape->superquadric().volume();
        volume_error[variant] += std::abs(e.superquadric.volume() - truth) / truth;
      }
      near_share[variant] = static_cast<double>(near) / total;
    }
    EXPECT_LT(near_share[0], 0.05) << "seed " << seed;
    EXPECT_GT(near_share[1], 0.25) << "seed " << seed;
    EXPECT_GT(near_share[2], near_share[1] + 0.05) << "seed " << seed;
    EXPECT_LT(volume_error[1], 0.7 * volume_error[0]) << "seed " << seed;
    EXPECT_LT(volume_error[2], 0.85 * volume_error[1]) << "seed " << seed;
  }
}

// The label grid numbers voxels by the reported instances (label k is instances[k]), also when
// an instance is dropped: here the largest (Hough's label 0), its centre put outside the
// workspace by a bound along x or y.
TEST(Decompose, LabelsNameTheReportedInstancesWhenOneIsDropped) {
  const PerceptionConfig config = sharpVotesConfig();
  for (uint64_t seed = 1; seed <= 10; ++seed) {
    const TruePile pile(seed);
    const GridSpec& grid = pile.grid;
    SceneHypothesis all = pile.h;
    decompose(&all, config, nullptr);
    if (all.instances.size() < 3) continue;
    // An axis along which instance 0 lies beyond every other by a centimetre.
    const Vec3 dropped = all.instances[0].vote_centre;
    PerceptionConfig cut = config;
    for (int axis = 0; axis < 2; ++axis) {
      double lowest = 1e9, highest = -1e9;
      for (size_t k = 1; k < all.instances.size(); ++k) {
        lowest = std::min(lowest, all.instances[k].vote_centre[axis]);
        highest = std::max(highest, all.instances[k].vote_centre[axis]);
      }
      if (dropped[axis] > highest + 0.01) cut.workspace.max_m[axis] = dropped[axis] - 0.005;
      if (dropped[axis] < lowest - 0.01) cut.workspace.min_m[axis] = dropped[axis] + 0.005;
    }
    if (!cut.workspace.bounded()) continue;
    SceneHypothesis h = pile.h;
    decompose(&h, cut, nullptr);
    ASSERT_EQ(h.instances.size(), all.instances.size() - 1) << "seed " << seed;
    std::vector<Vec3> sum(h.instances.size(), Vec3::Zero());
    std::vector<int> count(h.instances.size(), 0);
    for (int i = 0; i < grid.voxelCount(); ++i) {
      const int l = h.labels.data[i];
      if (l < 0) continue;
      ASSERT_LT(l, static_cast<int>(h.instances.size())) << "seed " << seed;
      const Vec3i v = grid.unravel(i);
      sum[l] += grid.voxelCentre(v.x(), v.y(), v.z());
      ++count[l];
    }
    for (size_t k = 0; k < h.instances.size(); ++k) {
      ASSERT_GT(count[k], 0) << "instance " << k << " has no voxel";
      const Vec3 centre = sum[k] / count[k];
      for (size_t j = 0; j < h.instances.size(); ++j)
        EXPECT_LE((centre - h.instances[k].vote_centre).norm(),
                  (centre - h.instances[j].vote_centre).norm())
            << "seed " << seed << ": label " << k << " lies nearer instance " << j;
    }
    return;
  }
  FAIL() << "no pile of seeds 1-10 has its largest instance outermost along x or y";
}

TEST(ScenePerception, PerceivesARenderedPile) {
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  PerceptionConfig config;
  config.model_path = kModel;
  const ScenePerception perception(config);
  const RenderedPile p = renderPile(12);
  for (bool known_table : {true, false}) {
    DepthView view{p.view.depth, p.camera, std::nullopt};
    if (known_table) view.T_table_camera = p.T_table_camera;
    const SceneEstimate est = perception.perceive(view);
    EXPECT_EQ(est.table_estimated, !known_table);
    ASSERT_EQ(est.hypotheses.size(), 3u);
    EXPECT_EQ(est.grid.resolution, 32);
    EXPECT_EQ(est.occupancy_probability.data.size(), 32u * 32 * 32);
    int occupied = 0;
    for (float q : est.occupancy_probability.data) {
      ASSERT_GE(q, 0.0f);
      ASSERT_LE(q, 1.0f);
      occupied += q >= 0.5f;
    }
    EXPECT_GT(occupied, 100);
    EXPECT_TRUE(est.hypotheses[0].decomposed);
    EXPECT_FALSE(est.hypotheses[1].decomposed);
    EXPECT_FALSE(est.hypotheses[0].surface.empty());
    EXPECT_NEAR(static_cast<double>(est.instances().size()),
                static_cast<double>(p.scene.objects.size()), 1.0);
    for (const InstanceEstimate& e : est.instances()) {
      EXPECT_TRUE(e.superquadric.scale_m.allFinite());
      EXPECT_FALSE(e.points.empty());
    }
    EXPECT_GT(est.timings.network_ms, 0.0);
    EXPECT_GE(est.timings.total_ms, est.timings.network_ms);
  }
}

// Piles of 5-8 objects of 5-15 cm (more, and smaller, than training's 3-4 of 5-30 cm): with the
// default radius the centres of small neighbours merge. The shipped config's first pass splits
// again (crowded:) with its settings where it finds many; its second pass, in a finer grid,
// counts such piles better still. A pile of the training's objects it perceives once.
TEST(ScenePerception, AFinerSecondPassCountsSmallNeighboursTheFirstMerges) {
  PerceptionConfig one_split_config = shippedConfig();
  ASSERT_TRUE(std::filesystem::exists(one_split_config.model_path))
      << one_split_config.model_path << " is missing (the models are in git)";
  ASSERT_GT(one_split_config.crowded.min_objects, 0) << "the shipped config splits twice";
  ASSERT_GT(one_split_config.grid.object_voxels, 0.0) << "the shipped config has a finer pass";
  const ScenePerception twice(one_split_config);
  one_split_config.grid.object_voxels = 0.0;  // the shipped config's first pass alone
  const ScenePerception shipped(one_split_config);
  one_split_config.crowded.min_objects = 0;
  const ScenePerception one_split(one_split_config);
  PerceptionConfig crowded_config = one_split_config;  // the crowded: settings, split once
  crowded_config.hough.bandwidth_m = one_split_config.crowded.bandwidth_m;
  crowded_config.hough.min_instance_voxels = one_split_config.crowded.min_instance_voxels;
  crowded_config.segments.max_unseen_points = one_split_config.crowded.max_unseen_points;
  const ScenePerception crowded_split(crowded_config);
  PileConfig crowded;
  crowded.min_objects = 5;
  crowded.max_objects = 8;
  crowded.max_size_m = 0.15;
  int one_error = 0, shipped_error = 0, twice_error = 0, one_under = 0;
  int split_again = 0, finer = 0;
  for (uint64_t seed = 1; seed <= 6; ++seed) {
    const RenderedPile p = renderPile(seed, crowded);
    const DepthView view{p.view.depth, p.camera, p.T_table_camera};
    const int objects = static_cast<int>(p.scene.objects.size());
    const SceneEstimate a = one_split.perceive(view), b = crowded_split.perceive(view);
    const SceneEstimate c = shipped.perceive(view), d = twice.perceive(view);
    const int na = static_cast<int>(a.instances().size()),
              nc = static_cast<int>(c.instances().size()),
              nd = static_cast<int>(d.instances().size());
    one_error += std::abs(na - objects);
    shipped_error += std::abs(nc - objects);
    twice_error += std::abs(nd - objects);
    one_under += na < objects;
    const bool as_one = c.hypotheses[0].labels.data == a.hypotheses[0].labels.data;
    const bool as_crowded = c.hypotheses[0].labels.data == b.hypotheses[0].labels.data;
    EXPECT_TRUE(as_one || as_crowded)
        << "pile " << seed << ": the shipped labels are neither split's";
    split_again += !as_one;
    if (d.tile_side_m < c.tile_side_m) {
      ++finer;
      EXPECT_GT(d.tiles, c.tiles) << "pile " << seed << ": both passes counted";
      EXPECT_NEAR(d.grid.voxel_size_m, 0.4 / 32, 1e-12);
    }
  }
  ASSERT_GE(one_under, 3) << "the premise: one split merges neighbours in most piles";
  EXPECT_GE(split_again, 1) << "no pile was split again";
  EXPECT_LT(shipped_error, one_error) << "count errors summed over the six piles";
  EXPECT_GE(finer, 4) << "the piles' objects looked small in most piles";
  EXPECT_LT(twice_error, shipped_error);
  const RenderedPile paper = renderPile(12);
  const SceneEstimate e =
      twice.perceive(DepthView{paper.view.depth, paper.camera, paper.T_table_camera});
  EXPECT_GE(e.object_voxels, twice.config().grid.object_voxels);
  EXPECT_GE(e.smallest_object_voxels, twice.config().grid.smallest_object_voxels);
  EXPECT_EQ(e.tile_side_m, 0.64);
  EXPECT_EQ(e.tiles, 1);
}

// A grid of half the side shows the network a pile of objects half the training's size as
// the training's: the TSDF, the truncation and the Hough radius follow the side, and the
// objects are found where they are.
TEST(ScenePerception, AFinerGridPerceivesAPileOfSmallObjects) {
  PerceptionConfig config = shippedConfig();
  config.grid.side_m = 0.32;
  config.grid.object_voxels = 0.0;  // that grid alone
  const ScenePerception finer(config);
  PileConfig small;
  small.max_size_m = 0.15;
  const RenderedPile p = renderPile(12, small);
  const SceneEstimate est = finer.perceive(DepthView{p.view.depth, p.camera, p.T_table_camera});
  EXPECT_DOUBLE_EQ(est.tile_side_m, 0.32);
  EXPECT_NEAR(est.grid.voxel_size_m, 0.01, 1e-12);
  EXPECT_GT(est.smallest_object_voxels, 0.0);
  EXPECT_LE(est.smallest_object_voxels, est.object_voxels) << "the smallest, and the median";
  // The TSDF is truncated at the model's 3 voxels of this grid, 3 cm.
  float largest = 0.0f;
  for (size_t i = 0; i < est.partial_tsdf_m.data.size(); ++i)
    if (est.partial_weight.data[i] > 0.0f)
      largest = std::max(largest, std::abs(est.partial_tsdf_m.data[i]));
  EXPECT_NEAR(largest, 0.03, 1e-4);
  // Each object is found near its centre.
  ASSERT_EQ(est.instances().size(), p.scene.objects.size());
  for (const SceneObject& o : p.scene.objects) {
    double nearest = 1e9;
    for (const InstanceEstimate& e : est.instances())
      nearest =
          std::min(nearest, (e.superquadric.centroid() - o.T_table_object.translation()).norm());
    EXPECT_LT(nearest, 0.05);
  }
  config.grid.side_m = 0.005;
  EXPECT_THROW(ScenePerception{config}, std::invalid_argument);
  // 2 cm: crowded:'s 3 cm radius for 0.64 m would be under a millimetre.
  config.grid.side_m = 0.02;
  EXPECT_THROW(ScenePerception{config}, std::invalid_argument);
  // A finer pass at a quarter of 3 cm: under 1 cm.
  config.grid.side_m = 0.03;
  config.crowded.min_objects = 0;
  config.crowded.bandwidth_m = 1.0;
  config.hough.bandwidth_m = 1.0;
  EXPECT_NO_THROW(ScenePerception{config});
  config.grid.object_voxels = 7.0;
  config.grid.fine_side_share = 0.25;
  EXPECT_THROW(ScenePerception{config}, std::invalid_argument);
  config = shippedConfig();
  config.grid.side_m = 0.0;
  config.grid.fine_side_share = 1.0;
  EXPECT_THROW(ScenePerception{config}, std::invalid_argument);
  // A second pass needs the first pass's objects: grids alone (decompose_samples 0) find none,
  // and the pile whose objects look small is perceived once, in the model's grid.
  config = shippedConfig();
  const DepthView view{p.view.depth, p.camera, p.T_table_camera};
  ASSERT_LT(ScenePerception(config).perceive(view).tile_side_m, 0.64) << "the premise";
  config.decompose_samples = 0;
  const SceneEstimate grids = ScenePerception(config).perceive(view);
  EXPECT_TRUE(grids.instances().empty());
  EXPECT_EQ(grids.object_voxels, 0.0);
  EXPECT_DOUBLE_EQ(grids.tile_side_m, 0.64);
  // Nor without the regrouping along the surface, which holds the finer grid's fragments together.
  config.decompose_samples = 1;
  config.segments.enabled = false;
  const SceneEstimate unregrouped = ScenePerception(config).perceive(view);
  EXPECT_GT(unregrouped.object_voxels, 0.0);
  EXPECT_DOUBLE_EQ(unregrouped.tile_side_m, 0.64);
}

// With one tile a frame, small objects spread wider than the finer grid would be cut by it:
// the first pass stands, uncut, and the finer one is not perceived.
TEST(ScenePerception, AFinerPassThatWouldCutThePileIsNotTaken) {
  PerceptionConfig config = shippedConfig();
  config.workspace.max_tiles = 1;
  const ScenePerception one_tile(config);
  config.grid.object_voxels = 0.0;
  const ScenePerception one_pass(config);
  // Four 8 cm boxes in two pairs 0.44 m apart: one 0.64 m tile holds them, one 0.4 m tile not.
  std::vector<SuperquadricShape> boxes;
  for (const double x : {-0.22, 0.22})
    for (const double y : {-0.05, 0.05}) {
      SuperquadricShape box;
      box.scale_m = Vec3(0.04, 0.04, 0.04);
      box.exponents = Vec3(10.0, 10.0, 10.0);
      box.T_table_object.translation() = Vec3(x, y, 0.04);
      boxes.push_back(box);
    }
  const Scene scene = Scene::fromSuperquadrics(boxes);
  PinholeCamera camera;
  const Transform T = lookAt(Vec3(0.0, -0.6, 0.7), Vec3(0.0, 0.0, 0.0));
  const DepthView view{DepthRenderer(scene).render(camera, T).depth, camera, T};
  const SceneEstimate a = one_pass.perceive(view), b = one_tile.perceive(view);
  ASSERT_FALSE(a.tiles_cropped) << "the premise: one 0.64 m tile holds the boxes";
  ASSERT_LT(a.object_voxels, 7.0) << "the premise: the boxes look small";
  EXPECT_FALSE(b.tiles_cropped);
  EXPECT_EQ(b.tile_side_m, 0.64);
  EXPECT_EQ(b.tiles, 1) << "the finer pass was not perceived";
  EXPECT_EQ(b.instances().size(), a.instances().size());
  EXPECT_EQ(a.instances().size(), 4u);
}

TEST(ScenePerception, TheSecondPassIsTakenWhenTheObjectsLookSmall) {
  GridConfig grid;
  EXPECT_DOUBLE_EQ(gridSideFor(grid, 0.64, 6.9, 6.0), 0.4) << "the default, 7 voxels";
  EXPECT_EQ(gridSideFor(grid, 0.64, 7.0, 6.0), 0.64);
  EXPECT_DOUBLE_EQ(gridSideFor(grid, 0.64, 9.0, 4.4), 0.4)
      << "the smallest object under 4.5 voxels, the median over 7: merges hide small ones";
  EXPECT_EQ(gridSideFor(grid, 0.64, 9.0, 4.5), 0.64);
  grid.smallest_object_voxels = 0.0;
  EXPECT_EQ(gridSideFor(grid, 0.64, 9.0, 2.0), 0.64) << "the median alone";
  EXPECT_DOUBLE_EQ(gridSideFor(grid, 0.64, 6.9, 2.0), 0.4);
  grid.smallest_object_voxels = 4.5;
  grid.object_voxels = 0.0;
  EXPECT_EQ(gridSideFor(grid, 0.64, 3.0, 2.0), 0.64) << "off, whatever the smallest";
  grid.object_voxels = 6.0;
  EXPECT_DOUBLE_EQ(gridSideFor(grid, 0.64, 5.9, 5.9), 0.4);
  EXPECT_EQ(gridSideFor(grid, 0.64, 6.0, 6.0), 0.64);
  EXPECT_EQ(gridSideFor(grid, 0.64, 0.0, 0.0), 0.64) << "nothing found: nothing to look at closer";
  grid.smallest_object_voxels = -1.0;
  EXPECT_THROW(grid.validate(), std::invalid_argument);
}

/// Index of the instance whose superquadric centre is nearest to `p` (-1 when none).
int nearestInstance(const SceneEstimate& est, const Vec3& p) {
  int best = -1;
  double d = 1e9;
  for (size_t k = 0; k < est.instances().size(); ++k) {
    const double dk = (est.instances()[k].superquadric.centroid() - p).norm();
    if (dk < d) {
      d = dk;
      best = static_cast<int>(k);
    }
  }
  return best;
}

TEST(ScenePerception, ObjectsCutByTheImageBorderOrTheMaskAreTruncated) {
  PerceptionConfig config;
  config.model_path = kModel;
  const ScenePerception perception(config);
  // Two boxes apart on the table; the camera sees both whole.
  const Vec3 a(-0.12, 0.0, 0.05), b(0.12, 0.02, 0.04);
  SuperquadricShape box_a, box_b;
  box_a.scale_m = Vec3(0.05, 0.05, 0.05);
  box_b.scale_m = Vec3(0.05, 0.06, 0.04);
  box_a.exponents = box_b.exponents = Vec3::Constant(10.0);
  box_a.T_table_object = Transform(Eigen::Translation3d(a));
  box_b.T_table_object = Transform(Eigen::Translation3d(b));
  const Scene scene = Scene::fromSuperquadrics({box_a, box_b});
  const PinholeCamera camera;
  const Transform T = lookAt(Vec3(0.0, -0.55, 0.55), Vec3(0.0, 0.0, 0.04));
  const RenderResult r = DepthRenderer(scene).render(camera, T);
  int u_lo = camera.width, u_hi = 0;  // box b's columns (instance 2)
  for (int v = 0; v < camera.height; ++v)
    for (int u = 0; u < camera.width; ++u)
      if (r.instances.at(u, v) == 2) {
        u_lo = std::min(u_lo, u);
        u_hi = std::max(u_hi, u);
      }
  ASSERT_GT(u_lo, camera.width / 2 + 10) << "box b must stand right of the principal point";
  const int cut = (u_lo + u_hi) / 2;
  const auto truncation = [&](const DepthView& view) {
    const SceneEstimate est = perception.perceive(view);
    const int ka = nearestInstance(est, a), kb = nearestInstance(est, b);
    EXPECT_NE(ka, kb);
    if (ka < 0 || kb < 0 || ka == kb) return std::make_pair(true, false);
    return std::make_pair(bool(est.instances()[ka].truncated), bool(est.instances()[kb].truncated));
  };
  DepthView whole{r.depth, camera, T};
  EXPECT_EQ(truncation(whole), std::make_pair(false, false));
  // The image ends in the middle of box b.
  DepthView cropped{DepthImage(cut, camera.height, 0.0f), camera, T};
  cropped.camera.width = cut;
  cropped.camera.window = true;  // a crop of the checked camera's image
  for (int v = 0; v < camera.height; ++v)
    for (int u = 0; u < cut; ++u) cropped.depth.at(u, v) = r.depth.at(u, v);
  EXPECT_EQ(truncation(cropped), std::make_pair(false, true));
  // A mask leaves out the right half of box b.
  DepthView masked = whole;
  masked.mask = InstanceImage(camera.width, camera.height, 255);
  for (int v = 0; v < camera.height; ++v)
    for (int u = cut; u < camera.width; ++u) masked.mask.at(u, v) = 0;
  EXPECT_EQ(truncation(masked), std::make_pair(false, true));
  // The workspace box ends inside box b (x = 0.12 +- 0.05 m), past its centre.
  PerceptionConfig bounded = config;
  bounded.workspace.max_m[0] = 0.14;
  const ScenePerception bounded_perception(bounded);
  const SceneEstimate est = bounded_perception.perceive(whole);
  const int ka = nearestInstance(est, a), kb = nearestInstance(est, b);
  ASSERT_GE(ka, 0);
  EXPECT_FALSE(est.instances()[ka].truncated);
  ASSERT_GE(kb, 0) << "the part of box b inside the workspace was not found";
  EXPECT_NE(ka, kb);
  EXPECT_TRUE(est.instances()[kb].truncated) << "an object the workspace cuts is not truncated";
}

TEST(PixelInstances, LabelsFollowTheDepthEdges) {
  // A near surface (1 m, left of column 40) in front of a far one (1.5 m): instance 1 owns the
  // far one and spills 3 columns over the near one, which is instance 0's.
  DepthImage depth(80, 20, 1.5f);
  Image<int> labels(80, 20, 1);
  for (int v = 0; v < 20; ++v)
    for (int u = 0; u < 40; ++u) {
      depth.at(u, v) = 1.0f + 0.0005f * u;  // a slanted surface stays one region
      labels.at(u, v) = u < 37 ? 0 : 1;
    }
  depth.at(5, 5) = std::numeric_limits<float>::quiet_NaN();
  labels.at(5, 5) = -1;
  followDepthEdges(depth, &labels);
  for (int v = 0; v < 20; ++v)
    for (int u = 0; u < 80; ++u)
      if (u != 5 || v != 5) {
        ASSERT_EQ(labels.at(u, v), u < 40 ? 0 : 1) << u << ", " << v;
      }
  EXPECT_EQ(labels.at(5, 5), -1);
  // Two instances on one continuous surface (objects that touch) keep their pixels.
  DepthImage flat(80, 20, 1.0f);
  Image<int> halves(80, 20, 0);
  for (int v = 0; v < 20; ++v)
    for (int u = 50; u < 80; ++u) halves.at(u, v) = 1;
  const Image<int> before = halves;
  followDepthEdges(flat, &halves);
  EXPECT_EQ(halves.pixels, before.pixels);
}

TEST(ScenePerception, TheThreadCountDoesNotChangeTheHypotheses) {
  // Hough voting, the fits and the joint solve split their work over `threads`: every
  // decomposed hypothesis must come out the same, to the bit, on one thread or two.
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  if (std::thread::hardware_concurrency() < 2)
    GTEST_SKIP() << "one core: the pipeline caps its threads at the cores, so both runs use one";
  const RenderedPile p = renderPile(12);
  const DepthView view{p.view.depth, p.camera, p.T_table_camera};
  std::vector<SceneEstimate> runs;
  for (int threads : {1, 2}) {
    PerceptionConfig config;
    config.model_path = kModel;
    config.decompose_samples = 3;
    config.threads = threads;
    runs.push_back(ScenePerception(config).perceive(view));
  }
  ASSERT_EQ(runs[0].hypotheses.size(), 3u);
  ASSERT_EQ(runs[1].hypotheses.size(), 3u);
  for (size_t h = 0; h < 3; ++h) {
    const auto& one = runs[0].hypotheses[h].instances;
    const auto& two = runs[1].hypotheses[h].instances;
    EXPECT_TRUE(runs[1].hypotheses[h].decomposed);
    ASSERT_EQ(one.size(), two.size()) << "hypothesis " << h;
    ASSERT_FALSE(one.empty());
    for (size_t k = 0; k < one.size(); ++k) {
      EXPECT_EQ(one[k].superquadric.scale_m, two[k].superquadric.scale_m) << h << ", " << k;
      EXPECT_EQ(one[k].superquadric.exponents, two[k].superquadric.exponents) << h << ", " << k;
      EXPECT_TRUE(
          one[k].superquadric.T_table_object.isApprox(two[k].superquadric.T_table_object, 0.0))
          << h << ", " << k;
    }
    EXPECT_EQ(runs[0].hypotheses[h].labels.data, runs[1].hypotheses[h].labels.data);
  }
}

TEST(ScenePerception, AWindowWithoutItsPrincipalPointIsPerceivedAsTheWholeView) {
  // A cropped camera image (a camera_info's ROI) need not hold the principal point: the pile
  // seen off the optical axis, and the window of the image around it alone, perceived as the
  // whole image with nothing measured outside the window.
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  const Scene scene = PileGenerator(PileConfig()).generate(12).scene;
  const Vec3 centre = scene.surfaceCentroid();
  const Vec3 eye = centre + Vec3(0.55, -0.35, 0.55);
  const Vec3 right = lookAt(eye, centre).linear().col(0);
  const Transform T = lookAt(eye, Vec3(centre.x(), centre.y(), 0.05) - 0.25 * right);
  const PinholeCamera camera;
  const DepthImage full = DepthRenderer(scene).render(camera, T).depth;
  const DepthImage table = DepthRenderer(Scene()).render(camera, T).depth;
  const auto [u0, v0, u1, v1] = test::pilePixels(full, table, 20);
  ASSERT_LE(u0, u1) << "the pile is not in view";
  ASSERT_GT(u0, camera.cx) << "the pile is not off the optical axis";
  DepthImage cut(u1 - u0 + 1, v1 - v0 + 1, 0.0f), outside_missing(full.width, full.height, 0.0f);
  for (int v = 0; v < cut.height; ++v)
    for (int u = 0; u < cut.width; ++u)
      cut.at(u, v) = outside_missing.at(u0 + u, v0 + v) = full.at(u0 + u, v0 + v);
  PinholeCamera window = camera;
  window.width = cut.width;
  window.height = cut.height;
  window.cx -= u0;
  window.cy -= v0;
  PinholeCamera plain = window;  // the same intrinsics, not marked as a window: refused
  EXPECT_THROW(plain.validate(), std::invalid_argument);
  window.window = true;
  PerceptionConfig config;
  config.model_path = kModel;
  const ScenePerception perception(config);
  const SceneEstimate whole = perception.perceive(DepthView{outside_missing, camera, T});
  const SceneEstimate part = perception.perceive(DepthView{cut, window, T});
  EXPECT_EQ(part.grid, whole.grid);
  EXPECT_EQ(part.partial_tsdf_m.data, whole.partial_tsdf_m.data);
  ASSERT_EQ(part.instances().size(), whole.instances().size());
  ASSERT_FALSE(whole.instances().empty());
  for (size_t k = 0; k < whole.instances().size(); ++k)
    EXPECT_LT((whole.instances()[k].superquadric.T_table_object.translation() -
               part.instances()[k].superquadric.T_table_object.translation())
                  .norm(),
              0.005);
}

TEST(ScenePerception, BadInputGetsClearErrors) {
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  PerceptionConfig config;
  config.model_path = kModel;
  const ScenePerception perception(config);
  PinholeCamera camera;
  EXPECT_THROW(perception.perceive(std::vector<DepthView>{}), std::invalid_argument);
  EXPECT_THROW(
      perception.perceive(DepthView{DepthImage(320, 240, 1.0f), camera, Transform::Identity()}),
      std::invalid_argument);
  // No valid depth, with or without a table pose: unusable depth, said as such.
  const DepthImage nan_depth(camera.width, camera.height, std::nanf(""));
  EXPECT_THROW(perception.perceive(DepthView{nan_depth, camera, std::nullopt}),
               std::invalid_argument);
  const RenderedPile p = renderPile(13);
  try {
    perception.perceive(DepthView{nan_depth, camera, p.T_table_camera});
    ADD_FAILURE() << "a view without depth was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("sensor range"), std::string::npos) << e.what();
  }
  // Depth at under 1 % of the pixels (a covered camera), or an image of a few pixels: no scene,
  // so that a node keeps the last one rather than reporting the pile gone.
  DepthImage covered = nan_depth;
  for (int u = 0; u < 30; ++u) covered.at(u, 0) = 1.0f;
  try {
    perception.perceive(DepthView{covered, camera, p.T_table_camera});
    ADD_FAILURE() << "a view with 30 depths was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("lost sight"), std::string::npos) << e.what();
  }
  PinholeCamera tiny = test::centredCamera(2, 2, 1.0);
  EXPECT_THROW(perception.perceive(DepthView{DepthImage(2, 2, 1.0f), tiny, p.T_table_camera}),
               std::invalid_argument);
  // Millimetres in a metre image: their span given, and what it looks like.
  DepthImage millimetres = p.view.depth;
  for (float& d : millimetres.pixels) d *= 1000.0f;
  try {
    perception.perceive(DepthView{millimetres, p.camera, p.T_table_camera});
    ADD_FAILURE() << "a view in millimetres was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("sensor range 0.1 .. 10 m (its depths span"),
              std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("millimetres where metres"), std::string::npos)
        << e.what();
  }
  // Depth beyond the sensor's range (a float image of random bits) is missing, not a crash.
  DepthImage far = p.view.depth;
  for (size_t i = 0; i < far.pixels.size(); i += 7) far.pixels[i] = 1e30f;
  EXPECT_EQ(perception.perceive(DepthView{far, p.camera, p.T_table_camera}).hypotheses.size(), 3u);
  // Intrinsics that do not fit the image, and poses no camera over a table can have.
  PinholeCamera normalized = p.camera;
  normalized.fx = 0.82, normalized.fy = 1.09, normalized.cx = normalized.cy = 0.5;
  EXPECT_THROW(perception.perceive(DepthView{p.view.depth, normalized, p.T_table_camera}),
               std::invalid_argument);
  Transform below = p.T_table_camera;
  below.translation().z() = -0.5;
  EXPECT_THROW(perception.perceive(DepthView{p.view.depth, p.camera, below}),
               std::invalid_argument);
  Transform sheared = p.T_table_camera;
  sheared.linear()(0, 1) += 0.3;
  EXPECT_THROW(perception.perceive(DepthView{p.view.depth, p.camera, sheared}),
               std::invalid_argument);
  // A second view without a pose.
  const DepthView good{p.view.depth, p.camera, p.T_table_camera};
  EXPECT_THROW(perception.perceive({good, DepthView{p.view.depth, p.camera, std::nullopt}}),
               std::invalid_argument);
  PerceptionConfig missing = config;
  missing.model_path = "/nonexistent/model.pt";
  try {
    ScenePerception bad(missing);
    ADD_FAILURE() << "a missing model must throw";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/model.pt"), std::string::npos);
  }
}

TEST(ScenePerception, AModelWithoutACodeGivesOneHypothesis) {
  const std::string fc = std::string(SIMSTACK_SOURCE_DIR) + "/models/simstack_r32_fc.pt";
  ASSERT_TRUE(std::filesystem::exists(fc)) << fc << " is missing (the models are in git)";
  // Samples asked of `fc` are one scene; hypotheses asked of it would be that scene handed on
  // as several: refused, naming the field.
  PerceptionConfig config;
  config.model_path = fc;
  config.samples = 3;
  config.decompose_samples = 1;
  const ScenePerception perception(config);
  EXPECT_EQ(perception.config().samples, 1);
  // A live change is judged as updateSettings would, and shows what would be in effect.
  PerceptionConfig live = perception.config();
  live.samples = 5;
  EXPECT_EQ(perception.settingsInEffect(live).samples, 1);
  live.symmetries = 3;
  EXPECT_THROW(perception.settingsInEffect(live), std::invalid_argument);
  EXPECT_EQ(perception.config().symmetries, config.symmetries);
  config.decompose_samples = 10;
  try {
    ScenePerception{config};
    ADD_FAILURE() << "decompose_samples 10 with fc accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("decompose_samples 10"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("no latent code"), std::string::npos) << e.what();
  }
  // The C-VAE draws distinct samples: more decomposed than drawn is an error.
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  config.model_path = kModel;
  config.samples = 2;
  EXPECT_THROW(ScenePerception{config}, std::invalid_argument);
  // A live lowering of samples lowers decompose_samples with it; raising samples again gives
  // back the decompose_samples asked for.
  config.samples = 4;
  config.decompose_samples = 3;
  {
    const ScenePerception cvae(config);
    PerceptionConfig fewer = cvae.config();
    fewer.samples = 2;
    EXPECT_EQ(cvae.settingsInEffect(fewer).decompose_samples, 2);
    fewer.samples = 8;
    EXPECT_EQ(cvae.settingsInEffect(fewer).decompose_samples, 3);
  }
  // Tiles whose widest scene, times the Hough refinement, has more fine cells than the voting
  // indexes: refused when the model is loaded, not on the first wide pile.
  config.samples = 3;
  config.decompose_samples = 1;
  config.hough.refinement = 8;
  config.workspace.max_tiles = 64;  // 8 tiles' side: 256 voxels x 8
  try {
    ScenePerception{config};
    ADD_FAILURE() << "max_tiles 64 with refinement 8 accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_tiles"), std::string::npos) << e.what();
  }
  config.workspace.max_tiles = 9;
  EXPECT_NO_THROW(ScenePerception{config});
  // Samples whose hypotheses over the widest scene grid would take more memory than a machine
  // has (64 over 192^3 voxels: 9 GB): refused, naming both settings.
  config.hough.refinement = 4;
  config.workspace.max_tiles = 36;
  config.samples = 64;
  try {
    ScenePerception{config};
    ADD_FAILURE() << "64 samples at max_tiles 36 accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("samples 64 and workspace.max_tiles 36"),
              std::string::npos)
        << e.what();
  }
  config.samples = 16;
  EXPECT_NO_THROW(ScenePerception{config});
}

TEST(ScenePerception, ShippedModelsProveThemselvesAndADifferentSelfTestIsRefused) {
  // Every shipped card records its file's hash, format and self-test, and the file passes.
  for (const char* name : {"simstack_r32_fc", "simstack_r32", "simstack_r32_fc_plain"}) {
    const std::string model = std::string(SIMSTACK_SOURCE_DIR) + "/models/" + name + ".pt";
    const std::optional<ModelIntegrity> card = readModelIntegrity(model);
    ASSERT_TRUE(card) << name << ": its card has no integrity: section";
    EXPECT_GE(card->self_test_objects, 0) << name;
    const ModelSelfTest t = checkModel(model);
    EXPECT_EQ(t.objects, 1) << name << ": the rendered box is one object";
  }
  // A card that expects another result of the self-test: the model is refused, both named.
  const std::filesystem::path dir = test::tempPath("simstack_selftest");
  std::filesystem::create_directories(dir);
  const std::string copy = (dir / "m.pt").string();
  std::filesystem::copy_file(SIMSTACK_SOURCE_DIR "/models/simstack_r32_fc.pt", copy,
                             std::filesystem::copy_options::overwrite_existing);
  std::filesystem::remove(dir / "m.yaml");
  ModelIntegrity m;
  m.sha256 = sha256OfFile(copy);
  m.format_version = modelFormatVersion();
  m.self_test_objects = 2;
  m.self_test_occupied_voxels = 77;
  writeModelIntegrity(copy, m);
  try {
    checkModel(copy);
    ADD_FAILURE() << "a self-test that disagrees with the card was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("self-test"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(copy), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(dir);
}

TEST(ScenePerception, TheWarmUpBoxStandsInsideABoundedWorkspace) {
  // A workcell whose workspace leaves the table's origin out still warms up on one object.
  PerceptionConfig config;
  config.model_path = SIMSTACK_SOURCE_DIR "/models/simstack_r32_fc.pt";
  config.samples = 1;
  config.symmetries = 1;
  config.workspace.min_m = {0.5, -WorkspaceConfig::kUnbounded, -WorkspaceConfig::kUnbounded};
  config.workspace.max_m = {0.9, -0.3, WorkspaceConfig::kUnbounded};
  const SceneEstimate estimate = ScenePerception(config).warmUp();
  ASSERT_EQ(estimate.instances().size(), 1u);
  // The box stands at (0.7, -0.4): in the middle of the bounded x, 10 cm in from y's bound.
  const Vec3 c = estimate.instances()[0].superquadric.T_table_object.translation();
  EXPECT_TRUE(config.workspace.contains(c)) << c.transpose();
  EXPECT_LT((c.head<2>() - Eigen::Vector2d(0.7, -0.4)).norm(), 0.05) << c.transpose();
}

TEST(ScenePerception, EveryShippedModelSeesNothingOnAnEmptyTable) {
  // Generated piles always hold objects; a bare table must still give no object in any
  // hypothesis, seen from the side, obliquely or from above. The grid goes on the table the
  // camera sees: a grid on the camera's own footprint is seen a ninth from the first eye, and
  // the networks fill the rest with objects. SIMSTACK_EXTRA_MODEL names one more file to check
  // (a training run's, say).
  std::vector<std::string> models;
  for (const auto& f : std::filesystem::directory_iterator(SIMSTACK_SOURCE_DIR "/models"))
    if (f.path().extension() == ".pt") models.push_back(f.path().string());
  if (const char* extra = std::getenv("SIMSTACK_EXTRA_MODEL")) models.push_back(extra);
  ASSERT_FALSE(models.empty()) << "no model in models/";
  std::sort(models.begin(), models.end());
  const PinholeCamera camera;
  std::vector<DepthView> views;  // the bare table from the side, obliquely and from above
  for (const Vec3& eye : {Vec3(0.55, -0.35, 0.55), Vec3(-0.7, 0.1, 0.3), Vec3(0.1, 0.05, 0.8)}) {
    const Transform T_table_camera = lookAt(eye, Vec3(0.0, 0.0, 0.05));
    views.push_back(DepthView{DepthRenderer(Scene{}).render(camera, T_table_camera).depth, camera,
                              T_table_camera});
  }
  for (const std::string& model : models) {
    PerceptionConfig config;
    config.model_path = model;
    config.samples = 8;
    config.decompose_samples = CvaeInference(model, 1).config().hasLatentCode() ? 8 : 1;
    const ScenePerception perception(config);
    for (const DepthView& view : views) {
      const SceneEstimate est = perception.perceive(view);
      const Vec3 eye = view.T_table_camera->translation();
      int seen = 0, occupied = 0;
      for (float w : est.partial_weight.data) seen += w > 0.0f;
      EXPECT_GT(seen, 0.2 * est.partial_weight.data.size()) << eye.transpose();
      for (float q : est.occupancy_probability.data) occupied += q > 0.0f;
      EXPECT_EQ(occupied, 0) << model << " from " << eye.transpose()
                             << ": voxels occupied in some hypothesis";
      for (size_t k = 0; k < est.hypotheses.size(); ++k)
        EXPECT_TRUE(est.hypotheses[k].instances.empty()) << model << ", hypothesis " << k;
    }
  }
}

TEST(ScenePerception, TwoViewsFuse) {
  ASSERT_TRUE(std::filesystem::exists(kModel)) << kModel << " is missing (the models are in git)";
  PerceptionConfig config;
  config.model_path = kModel;
  config.decompose_samples = 0;
  const ScenePerception perception(config);
  const RenderedPile p = renderPile(14);
  const Vec3 centre = p.scene.surfaceCentroid();
  const Transform second =
      lookAt(centre + Vec3(-0.5, 0.45, 0.5), Vec3(centre.x(), centre.y(), 0.05));
  const RenderResult r2 = DepthRenderer(p.scene).render(p.camera, second);
  const SceneEstimate one =
      perception.perceive(DepthView{p.view.depth, p.camera, p.T_table_camera});
  const SceneEstimate two = perception.perceive(
      {DepthView{p.view.depth, p.camera, p.T_table_camera}, DepthView{r2.depth, p.camera, second}});
  int seen_one = 0, seen_two = 0;
  for (float w : one.partial_weight.data) seen_one += w > 0;
  for (float w : two.partial_weight.data) seen_two += w > 0;
  EXPECT_GT(seen_two, seen_one);
  // Conditioned on the first view alone (the paper's multi-view optimisation without its
  // steps), the second view changes nothing: the network's input and output are the first's.
  PerceptionConfig first = config;
  first.condition_views = "first";
  const ScenePerception first_only(first);
  const SceneEstimate cond = first_only.perceive(
      {DepthView{p.view.depth, p.camera, p.T_table_camera}, DepthView{r2.depth, p.camera, second}});
  EXPECT_EQ(cond.partial_weight.data, one.partial_weight.data);
  ASSERT_EQ(cond.hypotheses.size(), one.hypotheses.size());
  // (to rounding: the network's last bits may follow where its buffers lie)
  for (size_t k = 0; k < one.hypotheses.size(); ++k) {
    float most = 0.0f;
    for (size_t i = 0; i < one.hypotheses[k].tsdf_m.data.size(); ++i)
      most = std::max(
          most, std::abs(cond.hypotheses[k].tsdf_m.data[i] - one.hypotheses[k].tsdf_m.data[i]));
    EXPECT_LT(most, 1e-4f) << k;
  }
  // Decomposed, too, the first view's instances: the second view reaches nothing.
  first.decompose_samples = 1;
  const ScenePerception first_decomposed(first);
  PerceptionConfig single = config;
  single.decompose_samples = 1;
  const SceneEstimate alone =
      ScenePerception(single).perceive(DepthView{p.view.depth, p.camera, p.T_table_camera});
  const SceneEstimate both = first_decomposed.perceive(
      {DepthView{p.view.depth, p.camera, p.T_table_camera}, DepthView{r2.depth, p.camera, second}});
  ASSERT_FALSE(alone.instances().empty());
  ASSERT_EQ(both.instances().size(), alone.instances().size());
  for (size_t i = 0; i < alone.instances().size(); ++i)
    EXPECT_EQ(both.instances()[i].voxels, alone.instances()[i].voxels) << i;
  first.condition_views = "second";
  EXPECT_THROW(ScenePerception{first}, std::invalid_argument);
  PerceptionConfig odd = config;
  odd.symmetries = 3;  // not a count of the grid's symmetries the network is run on
  EXPECT_THROW(ScenePerception{odd}, std::invalid_argument);
}

// Real Kinect scenes (../shared/data/real/mosd_learn, the mOSD learn split): skipped without
// the data. The default config (the fc model) on them.
std::string learnScene(int n) {
  return std::string(SIMSTACK_SHARED_DATA) + "/real/mosd_learn/learn" + std::to_string(n) + ".pcd";
}

// Objects found in a learn scene and their Overlap F, the shipped config with or without the
// two tests that keep an open container whole: the inside and outside votes meeting at one
// centre (segments.same_centre_m), and parts on one upright surface of revolution seen from
// inside (surface_instances.container_*).
std::pair<int, double> containerScene(const LabelledView& scene, bool vote_test,
                                      bool container_join) {
  PerceptionConfig c = shippedConfig();
  // The tests this isolates only: learn39 split without them holds 5 instances, which would
  // also make the crowded piles' second split; one pass, and no fits joined for overlapping.
  c.crowded.min_objects = 0;
  c.grid.object_voxels = 0.0;
  c.surface_instances.fit_overlap_share = 0.0;
  if (!vote_test) c.segments.same_centre_m = 0.0;
  if (!container_join) c.surface_instances.container_profile_m = 0.0;
  const SceneEstimate est = ScenePerception(c).perceive(scene.view);
  Image<int> found = pixelInstances(scene.view, est, 0, labelMinHeight(c));
  return {static_cast<int>(est.instances().size()),
          overlapScores(scene.objects.pixels, found.pixels).f_measure};
}

TEST(RealScenes, AnOpenContainerIsOneObject) {
  for (int n : {37, 39})
    if (!std::filesystem::exists(learnScene(n)))
      GTEST_SKIP() << learnScene(n) << " not found (see ../shared/data/README.md)";
  // learn39, four objects: a mug's inside, seen over its rim, and its outside vote for one
  // centre. learn37, three objects: a pot's near wall and the inside of its far wall lie on one
  // surface of revolution. Without its test each container is two objects.
  struct Case {
    int scene, objects;
    bool by_votes;  // the test that keeps this one whole
  };
  for (const Case& k : {Case{39, 4, true}, Case{37, 3, false}}) {
    const LabelledView scene = readLabelledView(learnScene(k.scene));
    const auto [split, split_f] = containerScene(scene, false, false);
    EXPECT_EQ(split, k.objects + 1) << "learn" << k.scene << ": without either test";
    for (const auto& [votes, container] : {std::pair{k.by_votes, !k.by_votes}, {true, true}}) {
      const auto [whole, whole_f] = containerScene(scene, votes, container);
      EXPECT_EQ(whole, k.objects) << "learn" << k.scene << ", vote test " << votes
                                  << ", container join " << container;
      EXPECT_GT(whole_f, 0.95) << "learn" << k.scene;
      EXPECT_GT(whole_f, split_f) << "learn" << k.scene;
    }
  }
}

// learn36's objects look 5.7 voxels across, so the shipped config perceives it again in the
// finer grid, which parts a pot's near wall from the inside of its far wall; their points fit
// one surface of revolution within 6 mm, not 3. The first pass held the pot as one object, so
// the two are joined (surface_instances.held_container_profile_m).
TEST(RealScenes, AContainerTheFirstPassHeldWholeIsOneObjectInTheSecond) {
  if (!std::filesystem::exists(learnScene(36)))
    GTEST_SKIP() << learnScene(36) << " not found (see ../shared/data/README.md)";
  const LabelledView scene = readLabelledView(learnScene(36));
  PerceptionConfig c = shippedConfig();
  const SceneEstimate held = ScenePerception(c).perceive(scene.view);
  ASSERT_LT(held.tile_side_m, 0.64) << "the premise: a second pass";
  EXPECT_EQ(held.instances().size(), 3u);
  c.surface_instances.held_container_profile_m = 0.0;
  EXPECT_EQ(ScenePerception(c).perceive(scene.view).instances().size(), 4u);
}

// learn30's two boxes look 5.2 voxels across, so the shipped config perceives them again in
// the finer grid, which parts the far box into its two sides seen past the near one; the near
// box's voxels lie between them, so the plain occluded test would keep them apart. The first
// pass held the far box as one object, so its sides are joined
// (surface_instances.held_occluded_plane_m).
TEST(RealScenes, ABoxTheFirstPassHeldWholePastANearerOneIsOneObjectInTheSecond) {
  if (!std::filesystem::exists(learnScene(30)))
    GTEST_SKIP() << learnScene(30) << " not found (see ../shared/data/README.md)";
  const LabelledView scene = readLabelledView(learnScene(30));
  PerceptionConfig c = shippedConfig();
  ASSERT_EQ(c.surface_instances.occluded_plane_m, 0.0) << "the premise: the plain test is off";
  const SceneEstimate held = ScenePerception(c).perceive(scene.view);
  ASSERT_LT(held.tile_side_m, 0.64) << "the premise: a second pass";
  EXPECT_EQ(held.instances().size(), 2u);
  c.surface_instances.held_occluded_plane_m = 0.0;
  EXPECT_EQ(ScenePerception(c).perceive(scene.view).instances().size(), 3u);
  c.surface_instances.occluded_plane_m = 0.006;  // the plain test, without the first pass's word
  EXPECT_EQ(ScenePerception(c).perceive(scene.view).instances().size(), 3u);
}

// surface_instances.fit_overlap_share (0.8 in the shipped config): instances whose own fits
// overlap by that share of the smaller are one object. learn28's two objects are counted three
// without it and two with it at 0.8; the three stacked boxes of learn22, whose own fits (each
// fitted to a view of one side) reach into each other by more than half, stay three at 0.8 and
// become one at 0.5.
TEST(RealScenes, InstancesWhoseOwnFitsOverlapHeavilyAreOneObject) {
  for (int n : {22, 28})
    if (!std::filesystem::exists(learnScene(n)))
      GTEST_SKIP() << learnScene(n) << " not found (see ../shared/data/README.md)";
  const auto perceive = [](int scene, double share) {
    PerceptionConfig c = shippedConfig();
    c.surface_instances.fit_overlap_share = share;
    return ScenePerception(c).perceive(readLabelledView(learnScene(scene)).view);
  };
  const auto count = [&](int scene, double share) {
    return perceive(scene, share).instances().size();
  };
  const SceneEstimate apart = perceive(28, 0.0), joined = perceive(28, 0.8);
  EXPECT_EQ(apart.instances().size(), 3u);
  EXPECT_EQ(joined.instances().size(), 2u);
  // The joined instance's points still begin with every depth point measured on its pieces
  // (where a grasp's seal is judged), the samples of the predicted surface after them.
  const auto measured = [](const SceneEstimate& est) {
    std::vector<std::array<double, 3>> out;
    for (const InstanceEstimate& e : est.instances())
      for (int i = 0; i < e.measured_points; ++i)
        out.push_back({e.points[i].x(), e.points[i].y(), e.points[i].z()});
    std::sort(out.begin(), out.end());
    return out;
  };
  EXPECT_EQ(measured(joined), measured(apart));
  // Every depth point measured on an instance (the surface its seals are judged on) holds the
  // fitter's share of them, and more where the fitter took only points_per_instance.
  size_t beyond_the_fitters = 0;
  for (const InstanceEstimate& e : joined.instances()) {
    std::set<std::array<double, 3>> all;
    for (const Vec3& p : e.measured) all.insert({p.x(), p.y(), p.z()});
    for (int i = 0; i < e.measured_points; ++i)
      EXPECT_EQ(all.count({e.points[i].x(), e.points[i].y(), e.points[i].z()}), 1u) << i;
    beyond_the_fitters += e.measured.size() - e.measured_points;
  }
  EXPECT_GT(beyond_the_fitters, 0u);
  EXPECT_EQ(count(22, 0.8), 3u);
  EXPECT_EQ(count(22, 0.5), 1u);
}

/// Checks that no fit of `est` collapsed or flattened, and that a segment spanning more than
/// kCollapseSpanM is fitted larger than the bound; counts the objects checked.
void expectNoCollapsedFit(const SceneEstimate& est, const PerceptionConfig& c,
                          const std::string& what, int* objects) {
  for (const InstanceEstimate& e : est.instances()) {
    ++*objects;
    EXPECT_FALSE(collapsedFit(e.superquadric, e.points))
        << what << ": scales " << e.superquadric.scale_m.transpose();
    EXPECT_FALSE(flattenedFit(e.superquadric, e.points, c.fit.min_scale_m))
        << what << ": scales " << e.superquadric.scale_m.transpose();
    if (2 * initialGuess(e.points).scale_m.maxCoeff() > kCollapseSpanM) {
      EXPECT_GT(e.superquadric.scale_m.maxCoeff(), 2 * c.fit.min_scale_m) << what;
    }
  }
}

TEST(ScenePerception, NoFitCollapsesOnSyntheticPiles) {
  const PerceptionConfig c = shippedConfig();
  const ScenePerception perception(c);
  int objects = 0;
  for (uint64_t seed : {3u, 12u, 21u}) {
    const RenderedPile p = renderPile(seed);
    expectNoCollapsedFit(perception.perceive(DepthView{p.view.depth, p.camera, p.T_table_camera}),
                         c, "pile " + std::to_string(seed), &objects);
  }
  EXPECT_GE(objects, 7);  // of 9 found in the three piles
}

TEST(RealScenes, NoFitCollapsesOnTheCylindricalScenes) {
  std::vector<std::string> scenes;
  for (int n = 33; n <= 44; ++n) scenes.push_back(learnScene(n));
  if (const std::string missing = test::firstMissing(scenes); !missing.empty())
    GTEST_SKIP() << missing << " not found (see ../shared/data/README.md)";
  const PerceptionConfig c = shippedConfig();
  const ScenePerception perception(c);
  int objects = 0;
  for (int n = 33; n <= 44; ++n)  // bowls, pots, cups, cans
    expectNoCollapsedFit(perception.perceive(readLabelledView(learnScene(n)).view), c,
                         "learn" + std::to_string(n), &objects);
  EXPECT_GE(objects, 30);  // of 38 found in the twelve scenes
}

TEST(YcbObjects, NoFitCollapsesOnYcbObjectsSideBySide) {
  const std::string ycb = std::string(SIMSTACK_SHARED_DATA) + "/ycb";
  if (const std::string missing = test::firstMissing(test::ycbMeshFiles(ycb, ycbObjectNames()));
      !missing.empty())
    GTEST_SKIP() << missing << " not found (see ../shared/data/README.md)";
  const PerceptionConfig c = shippedConfig();
  const ScenePerception perception(c);
  // Five YCB objects side by side on the table, as their meshes rest (no physics).
  const auto catalogue = loadMeshCatalogue(ycb);
  Scene scene;
  for (int k : {1, 2, 3, 5, 8}) {  // cracker box, sugar box, soup can, pudding box, wood block
    SceneObject o{catalogue[k], Transform::Identity()};
    double lowest = 0;
    for (const Vec3& v : catalogue[k]->mesh().vertices) lowest = std::min(lowest, v.z());
    o.T_table_object.translation() = Vec3(-0.24 + 0.12 * scene.objects.size(), 0.0, -lowest);
    scene.objects.push_back(o);
  }
  const Transform T = lookAt(Vec3(0.1, -0.6, 0.6), Vec3(0.0, 0.0, 0.05));
  const PinholeCamera camera;
  int objects = 0;
  expectNoCollapsedFit(
      perception.perceive(DepthView{DepthRenderer(scene).render(camera, T).depth, camera, T}), c,
      "YCB objects", &objects);
  EXPECT_GE(objects, 4);  // of the five
}

/// The node's objects on each frame of the example bag (test/data/example_bag_objects.txt): per
/// frame, the recorded ids and the shapes.
std::vector<std::pair<std::vector<uint32_t>, std::vector<SuperquadricShape>>> exampleBagObjects() {
  std::ifstream f(std::string(SIMSTACK_SOURCE_DIR) + "/test/data/example_bag_objects.txt");
  std::string line;
  while (f.peek() == '#') std::getline(f, line);
  std::vector<std::pair<std::vector<uint32_t>, std::vector<SuperquadricShape>>> frames;
  size_t n = 0;
  while (f >> n) {
    frames.emplace_back();
    for (size_t k = 0; k < n; ++k) {
      uint32_t id = 0;
      Vec3 t;
      Eigen::Quaterniond q;
      SuperquadricShape s;
      f >> id >> t.x() >> t.y() >> t.z() >> q.x() >> q.y() >> q.z() >> q.w() >> s.scale_m.x() >>
          s.scale_m.y() >> s.scale_m.z() >> s.exponents.x() >> s.exponents.y() >> s.exponents.z();
      s.T_table_object.linear() = q.normalized().toRotationMatrix();
      s.T_table_object.translation() = t;
      frames.back().first.push_back(id);
      frames.back().second.push_back(s);
    }
  }
  return frames;
}

TEST(ObjectTracker, IdsHoldOverTheExampleBagWhateverFramesAreDropped) {
  // The camera circles the still pile; a node too slow for the bag perceives some of its frames.
  // A half-hidden flat box is estimated up to 8 cm apart from one view to another.
  const auto frames = exampleBagObjects();
  ASSERT_EQ(frames.size(), 12u);
  // Whether, over the frames `keep` marks (the first always), each recorded object keeps one id.
  const auto holds = [&](const TrackerConfig& config, unsigned keep) {
    ObjectTracker tracker(config);
    std::map<uint32_t, uint32_t> given, named;  // recorded id -> the tracker's, and back
    for (size_t k = 0; k < frames.size(); ++k) {
      if (k > 0 && !(keep & (1u << (k - 1)))) continue;
      const std::vector<uint32_t> ids = tracker.assign(frames[k].second);
      for (size_t i = 0; i < ids.size(); ++i) {
        const uint32_t recorded = frames[k].first[i];
        if (given.emplace(recorded, ids[i]).first->second != ids[i] ||
            named.emplace(ids[i], recorded).first->second != recorded)
          return false;
      }
    }
    return true;
  };
  int renumbered = 0, renumbered_by_centres_alone = 0;
  TrackerConfig centres_alone;
  centres_alone.min_overlap_share = 1.0;  // only an estimate holding the other whole
  int sequences = 0;
  for (unsigned keep = 0; keep < (1u << (frames.size() - 1)); keep += 5, ++sequences) {
    renumbered += !holds(TrackerConfig(), keep);
    renumbered_by_centres_alone += !holds(centres_alone, keep);
  }
  EXPECT_EQ(renumbered, 0) << "of " << sequences;
  // The overlap is what holds them: by the centre gate alone some frame sequences renumber.
  EXPECT_GT(renumbered_by_centres_alone, sequences / 10) << "of " << sequences;
  std::printf("of %d frame sequences, %d renumbered by the centre gate alone\n", sequences,
              renumbered_by_centres_alone);
}

TEST(ObjectTracker, AnObjectMissedForAFewFramesTakesItsIdBack) {
  const auto sq = [](double x, double a) {
    SuperquadricShape s;
    s.scale_m = Vec3(a, 0.8 * a, 0.5 * a);
    s.T_table_object.translation() = Vec3(x, 0.0, 0.5 * a);
    return s;
  };
  const SuperquadricShape a = sq(0.0, 0.05), b = sq(0.12, 0.04), c = sq(-0.12, 0.03);
  ObjectTracker tracker;  // max_missed_frames 3
  EXPECT_EQ(tracker.assign({a, b, c}), (std::vector<uint32_t>{0, 1, 2}));
  // b merged into a neighbour for two frames, then found again 1 cm from where it was.
  EXPECT_EQ(tracker.assign({a, c}), (std::vector<uint32_t>{0, 2}));
  EXPECT_EQ(tracker.assign({c, a}), (std::vector<uint32_t>{2, 0}));
  EXPECT_EQ(tracker.assign({a, sq(0.13, 0.04), c}), (std::vector<uint32_t>{0, 1, 2}));
  // c missed for three frames keeps its id; a missed for four is retired.
  for (int k = 0; k < 3; ++k) EXPECT_EQ(tracker.assign({b}), (std::vector<uint32_t>{1}));
  EXPECT_EQ(tracker.assign({b, c}), (std::vector<uint32_t>{1, 2}));
  EXPECT_EQ(tracker.assign({a, b, c}), (std::vector<uint32_t>{3, 1, 2}));
  // A waiting object is matched as it was last estimated: elsewhere, it is another object.
  EXPECT_EQ(tracker.assign({a, c}), (std::vector<uint32_t>{3, 2}));
  EXPECT_EQ(tracker.assign({a, sq(0.3, 0.04), c}), (std::vector<uint32_t>{3, 4, 2}));
  // A reset forgets the waiting ones too.
  EXPECT_EQ(tracker.assign({a}), (std::vector<uint32_t>{3}));
  tracker.reset();
  EXPECT_EQ(tracker.assign({a, b}), (std::vector<uint32_t>{5, 6}));
}

TEST(ObjectTracker, IdsStayWithTheirObjectsAndVanishedOnesAreRetired) {
  const auto sq = [](double x, double y, double a) {
    SuperquadricShape s;
    s.scale_m = Vec3(a, 0.8 * a, 0.5 * a);
    s.T_table_object.translation() = Vec3(x, y, 0.5 * a);
    return s;
  };
  TrackerConfig at_once;  // a vanished object's id retired by the first frame without it
  at_once.max_missed_frames = 0;
  ObjectTracker tracker(at_once);
  const std::vector<uint32_t> first =
      tracker.assign({sq(0.0, 0.0, 0.05), sq(0.1, 0.0, 0.04), sq(0.0, 0.12, 0.03)});
  EXPECT_EQ(first, (std::vector<uint32_t>{0, 1, 2}));
  // The next frame: the fits moved by millimetres and come in another order.
  std::vector<SuperquadricShape> second = {sq(0.003, 0.118, 0.031), sq(0.002, -0.004, 0.052),
                                           sq(0.097, 0.002, 0.041)};
  second[1].scale_m = Vec3(0.026, 0.052, 0.04);  // its axes numbered otherwise: same size
  EXPECT_EQ(tracker.assign(second), (std::vector<uint32_t>{2, 0, 1}));
  // Object 1 picked, a new one placed, object 2 grown beyond the size gate (another object).
  SuperquadricShape grown = sq(0.0, 0.12, 0.031);
  grown.scale_m *= 5.0;  // in place, five times the size
  EXPECT_EQ(tracker.assign({sq(0.0, 0.0, 0.05), sq(-0.1, 0.0, 0.04), grown}),
            (std::vector<uint32_t>{0, 3, 4}));
  // Object 1 is back where it was: vanished ids are not given again.
  EXPECT_EQ(tracker.assign({sq(0.0, 0.0, 0.05), sq(0.1, 0.0, 0.04)}),
            (std::vector<uint32_t>{0, 5}));
  // Two candidates for one track: the nearer one keeps the id.
  EXPECT_EQ(tracker.assign({sq(0.03, 0.0, 0.05), sq(0.01, 0.0, 0.05)}),
            (std::vector<uint32_t>{6, 0}));
  tracker.reset();
  EXPECT_EQ(tracker.assign({sq(0.01, 0.0, 0.05)}), (std::vector<uint32_t>{7}));
  EXPECT_TRUE(tracker.assign({}).empty());
  // A long flat object half hidden: from the next view its estimate lies 6 cm further along
  // it, beyond the centre gate, but each estimate holds the other's centre: one object. A box
  // that a pick uncovers under another (its centre below the picked one's bottom) is new.
  SuperquadricShape flat = sq(0.2, 0.0, 0.08), stacked = sq(0.0, 0.2, 0.05);
  flat.scale_m.z() = 0.015;
  stacked.T_table_object.translation().z() = 0.075;  // on a box below it, hidden at first
  EXPECT_EQ(tracker.assign({flat, stacked}), (std::vector<uint32_t>{8, 9}));
  SuperquadricShape seen_further = flat, uncovered = sq(0.0, 0.2, 0.05);
  seen_further.T_table_object.translation().x() += 0.06;
  uncovered.T_table_object.translation().z() = 0.02;
  EXPECT_EQ(tracker.assign({seen_further, uncovered}), (std::vector<uint32_t>{8, 10}));
  TrackerConfig bad;
  bad.max_missed_frames = -1;
  EXPECT_THROW(ObjectTracker{bad}, std::invalid_argument);
  bad = TrackerConfig();
  bad.max_size_ratio = 0.9;
  try {
    ObjectTracker{bad};
    ADD_FAILURE() << "max_size_ratio 0.9 accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_size_ratio must be finite and >= 1, not 0.9"),
              std::string::npos)
        << e.what();
  }
  bad = TrackerConfig();
  bad.max_centre_distance_m = std::nan("");
  EXPECT_THROW(ObjectTracker{bad}, std::invalid_argument);
}

// A view told apart by its depth's width; posed unless `posed` is false.
DepthView numberedView(int n, bool posed = true) {
  DepthView v;
  v.depth = DepthImage(n, 1, 1.0f);
  if (posed) v.T_table_camera = Transform::Identity();
  return v;
}

TEST(ViewHistory, FusesTheNewestViewsFirstAndForgetsThoseOfAnotherTime) {
  ViewHistory history(3);
  for (int n = 1; n <= 4; ++n) {
    EXPECT_FALSE(history.arrive(n * 1000000000LL).went_back);
    history.keep(numberedView(n));
  }
  EXPECT_EQ(history.size(), 2u);  // a frame fuses two of them with itself
  std::vector<DepthView> views = history.viewsWith(numberedView(5));
  ASSERT_EQ(views.size(), 3u);
  EXPECT_EQ(views[0].depth.width, 5);  // the new frame first, then the newest kept
  EXPECT_EQ(views[1].depth.width, 4);
  EXPECT_EQ(views[2].depth.width, 3);
  // An unposed view (the table estimated from its own depth) is perceived alone, not kept.
  EXPECT_EQ(history.viewsWith(numberedView(6, false)).size(), 1u);
  history.keep(numberedView(6, false));
  EXPECT_EQ(history.size(), 2u);
  // A bag that restarted: its first frame is stamped before the last one.
  const ViewHistory::Arrival back = history.arrive(2500000000LL);
  EXPECT_TRUE(back.went_back);
  EXPECT_EQ(back.cleared, 2u);
  EXPECT_NEAR(back.back_s, 1.5, 1e-9);
  EXPECT_EQ(history.viewsWith(numberedView(7)).size(), 1u);
  // One view at most: each frame alone, nothing kept.
  history.setMaxViews(1);
  history.keep(numberedView(8));
  EXPECT_EQ(history.size(), 0u);
  EXPECT_THROW(history.setMaxViews(0), std::invalid_argument);
}

}  // namespace
}  // namespace simstack
