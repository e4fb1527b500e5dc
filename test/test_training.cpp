#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>

#include <H5Cpp.h>

#include "model_test_helpers.h"
#include "simstack/io/yaml_file.h"
#include "simstack/model/cvae.h"
#include "simstack/model/model_integrity.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/offline/piles/mesh_catalogue.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/offline/training/cvae_trainer.h"
#include "simstack/offline/training/model_writer.h"
#include "simstack/offline/training/training_sample.h"
#include "simstack/render/depth_renderer.h"
#include "test_scenes.h"

// The offline training: the samples it draws and the trainer (runs, checkpoints, resumes).
using namespace simstack;
namespace fs = std::filesystem;
using test::RemoveAtExit;
using test::tempPath;
using test::tiny;

TEST(TrainingSample, VoteWeightsMarkVoxelsNearAnotherObject) {
  // Two slabs along x in an 8^3 grid: object 1 in x = 0-2, object 2 in x = 4-7, free x = 3.
  // Within 2 voxels of the other object: x = 2 (object 1) and x = 4 (object 2).
  const int r = 8;
  std::vector<uint8_t> labels(r * r * r, 0);
  for (int z = 0; z < r; ++z)
    for (int y = 0; y < r; ++y)
      for (int x = 0; x < r; ++x) labels[(z * r + y) * r + x] = x <= 2 ? 1 : x >= 4 ? 2 : 0;
  const std::vector<float> w = voteBoundaryWeights(labels, r, 4.0f);
  for (int x = 0; x < r; ++x) {
    const bool near = x == 2 || x == 4;
    EXPECT_FLOAT_EQ(w[(3 * r + 3) * r + x], near ? 5.0f : 1.0f) << x;
  }
  EXPECT_THROW(voteBoundaryWeights(labels, 7, 4.0f), std::invalid_argument);
  // The builder fills them only when the loss uses them; a lone sphere has no such voxel.
  const Scene scene = test::sphereScene(0.08, Vec3(0.0, 0.0, 0.08));
  SceneRecord rec;
  rec.scene = scene;
  CvaeConfig c = tiny();
  c.resolution = 32;
  rec.grid = GridSpec::sceneGrid(Vec2(0.0, 0.0), c.extent_m, c.resolution);
  rec.ground_truth = computeGroundTruth(scene, rec.grid, c.truncation_m());
  const Transform eye = lookAt(Vec3(0.6, 0.0, 0.4), Vec3(0, 0, 0.08));
  EXPECT_TRUE(TrainingSampleBuilder(c, scaledKinect(320, 240), false)
                  .build(rec, eye, 0)
                  .vote_weight.empty());
  c.vote_boundary_weight = 4.0;
  const TrainingSample s =
      TrainingSampleBuilder(c, scaledKinect(320, 240), false).build(rec, eye, 0);
  ASSERT_EQ(s.vote_weight.size(), s.tsdf.size());
  for (float x : s.vote_weight) EXPECT_EQ(x, 1.0f);
  c.vote_boundary_weight = -1.0;
  EXPECT_THROW(c.validate(), std::invalid_argument);
}

TEST(TrainingSample, GridFollowsTheVisiblePile) {
  const Scene scene = test::sphereScene(0.08, Vec3(0.05, 0.0, 0.08));
  DatasetInfo info;
  SceneRecord rec;
  rec.scene = scene;
  CvaeConfig c = tiny();
  c.resolution = 32;
  rec.grid = GridSpec::sceneGrid(Vec2(-0.1, 0.0), c.extent_m, c.resolution);  // stored off-centre
  rec.ground_truth = computeGroundTruth(scene, rec.grid, c.truncation_m());
  const TrainingSampleBuilder builder(c, scaledKinect(320, 240), false);
  const TrainingSample s = builder.build(rec, lookAt(Vec3(0.6, 0.0, 0.4), Vec3(0.05, 0, 0.08)), 0);
  // The visible centre lies near the sphere: the grid moved by whole voxels towards +x.
  const double shift = s.grid.origin_table.x() - rec.grid.origin_table.x();
  EXPECT_GT(shift, 0.08);
  EXPECT_NEAR(std::remainder(shift, rec.grid.voxel_size_m), 0.0, 1e-9);
  // Shifted ground truth still has the sphere where it is: occupied at its centre.
  const Vec3i idx = s.grid.voxelIndex(Vec3(0.05, 0.0, 0.08));
  EXPECT_LT(s.tsdf[s.grid.linear(idx.x(), idx.y(), idx.z())], 0.0f);
  int occupied = 0;
  for (float x : s.tsdf) occupied += x <= 0.0f;
  int occupied_stored = 0;
  for (float x : rec.ground_truth.tsdf.data) occupied_stored += x <= 0.0f;
  EXPECT_EQ(occupied, occupied_stored);
}

namespace {
// A small dataset of generated piles at R = 16 (the tiny config's grid).
std::string tinyDataset(int scenes, int min_objects = 3, uint64_t seed = 5,
                        const std::string& name = "simstack_test_train.h5") {
  const std::string path = tempPath(name);
  DatasetInfo info;
  info.num_scenes = scenes;
  info.min_objects = min_objects;
  info.resolution = 16;
  info.extent_m = 0.64;
  info.truncation_m = tiny().truncation_m();
  info.seed = seed;
  DatasetWriter writer(path, info);
  const PileGenerator gen{PileConfig()};
  for (int i = 0; i < scenes; ++i) {
    const Scene s = gen.generate(300 + i).scene;
    const GridSpec g = GridSpec::sceneGrid(s.surfaceCentroid().head<2>(), info.extent_m, 16);
    writer.write(i, s, computeGroundTruth(s, g, info.truncation_m));
  }
  return path;
}

// Training on tinyDataset(3): batches of 2, one validation scene, small views, one thread.
TrainConfig tinyTraining(int steps) {
  TrainConfig tc;
  tc.batch_size = 2;
  tc.steps = steps;
  tc.threads = 1;
  tc.validate_every = 2;
  tc.validation_scenes = 1;
  tc.image_width = 80;
  tc.image_height = 60;
  return tc;
}

/// A tiny dataset of 3 scenes, three absent run directories `prefix`_a, _b and _c (all removed
/// when the test ends), and a training of 4 steps with a checkpoint every 2.
struct TrainingScratch {
  explicit TrainingScratch(const std::string& prefix) : data(tinyDataset(3)), tc(tinyTraining(4)) {
    tc.checkpoint_every = 2;
    cleanup.paths.push_back(data);
    for (size_t k = 0; k < dirs.size(); ++k) {
      dirs[k] = tempPath(prefix + "_" + static_cast<char>('a' + k));
      fs::remove_all(dirs[k]);
      cleanup.paths.push_back(dirs[k]);
    }
  }
  std::string data;
  std::array<std::string, 3> dirs;
  TrainConfig tc;
  RemoveAtExit cleanup;
};

std::vector<std::string> lines(const std::string& path) {
  std::ifstream f(path);
  std::vector<std::string> out;
  for (std::string l; std::getline(f, l);) out.push_back(l);
  return out;
}

size_t fields(const std::string& line) { return std::count(line.begin(), line.end(), ',') + 1; }

// Output of a trained model on a fixed input.
torch::Tensor probe(const std::string& model_path) {
  Cvae m = loadCvae(model_path);
  m->eval();
  torch::NoGradGuard no_grad;
  const torch::Tensor partial = torch::linspace(-1, 1, 2 * 16 * 16 * 16).view({1, 2, 16, 16, 16});
  return m->generate(partial, torch::zeros({1, 8})).tsdf;
}
}  // namespace

TEST(CvaeTrainer, ValidatesAModelFileAsARunDoes) {
  const std::string data = tinyDataset(3);
  const std::string a = tempPath("simstack_train_validate");
  const RemoveAtExit cleanup{{a, data}};
  fs::remove_all(a);
  const TrainConfig tc = tinyTraining(2);
  CvaeTrainer(data, tiny(), tc, a, "test").run(false);
  TrainConfig v = tc;
  v.validation_scenes = 2;
  v.validation_views = 3;
  // (Two steps of training predict little occupied space: BCE tells the views apart.)
  const TrainingReport r = CvaeTrainer::validateModel(data, a + "/model.pt", v);
  EXPECT_GE(r.validation_iou, 0.0);
  EXPECT_LE(r.validation_iou, 1.0);
  EXPECT_GE(r.validation_iou_se, 0.0);
  EXPECT_GT(r.validation_bce, 0.0);
  EXPECT_EQ(CvaeTrainer::validateModel(data, a + "/model.pt", v).validation_bce, r.validation_bce);
  // The training seed does not choose the views or codes: runs of other seeds score alike.
  v.seed = 7;
  EXPECT_EQ(CvaeTrainer::validateModel(data, a + "/model.pt", v).validation_bce, r.validation_bce);
  // One scene: no spread over scenes; its three views are not its first view alone.
  v.validation_scenes = 1;
  const TrainingReport three = CvaeTrainer::validateModel(data, a + "/model.pt", v);
  EXPECT_EQ(three.validation_iou_se, 0.0);
  v.validation_views = 1;
  EXPECT_NE(CvaeTrainer::validateModel(data, a + "/model.pt", v).validation_bce,
            three.validation_bce);
  EXPECT_THROW(CvaeTrainer::validateModel(data, a + "/missing.pt", v), std::runtime_error);
  v.validation_views = 0;
  EXPECT_THROW(CvaeTrainer::validateModel(data, a + "/model.pt", v), std::invalid_argument);
}

TEST(CvaeTrainerYcb, TrainsAndValidatesOnYcbPilesGivenTheirMeshes) {
  const std::string dir = std::string(SIMSTACK_SHARED_DATA) + "/ycb";
  if (const std::string missing = test::firstMissing(
          test::ycbMeshFiles(dir, {"003_cracker_box", "005_tomato_soup_can", "061_foam_brick"}));
      !missing.empty())
    GTEST_SKIP() << missing << " not found (see ../shared/data/README.md)";
  const std::string data = tinyDataset(3);
  const std::string ycb = tempPath("simstack_test_validate_ycb.h5");
  const std::string a = tempPath("simstack_train_validate_ycb");
  const std::string b = tempPath("simstack_train_on_ycb");
  const RemoveAtExit cleanup{{a, b, data, ycb}};
  fs::remove_all(a);
  fs::remove_all(b);
  {
    DatasetInfo info;
    info.num_scenes = 3;
    info.resolution = 16;
    info.extent_m = 0.64;
    info.truncation_m = tiny().truncation_m();
    info.mesh_names = {"003_cracker_box", "005_tomato_soup_can", "061_foam_brick"};
    DatasetWriter writer(ycb, info);
    const PileGenerator gen(PileConfig(), loadMeshCatalogue(dir, info.mesh_names));
    for (int i = 0; i < info.num_scenes; ++i) {
      const Scene s = gen.generate(40 + i).scene;
      const GridSpec g = GridSpec::sceneGrid(s.surfaceCentroid().head<2>(), info.extent_m, 16);
      writer.write(i, s, computeGroundTruth(s, g, info.truncation_m));
    }
  }
  const TrainConfig tc = tinyTraining(2);
  CvaeTrainer(data, tiny(), tc, a, "test").run(false);
  TrainConfig v = tc;
  v.validation_scenes = 2;
  v.validation_views = 1;
  // Without the meshes the file cannot be read, and the error says which option reads it.
  try {
    CvaeTrainer::validateModel(ycb, a + "/model.pt", v);
    ADD_FAILURE() << "a YCB dataset was validated without its meshes";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("simstack_tune_hough take (--ycb DIR)"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW(CvaeTrainer({data, ycb}, tiny(), tc, b, "test"), std::runtime_error);
  const TrainingReport r = CvaeTrainer::validateModel(ycb, a + "/model.pt", v, dir);
  EXPECT_GE(r.validation_iou, 0.0);
  EXPECT_LE(r.validation_iou, 1.0);
  EXPECT_GT(r.validation_bce, 0.0);
  // The mesh piles are other piles than the superquadric ones: another score.
  EXPECT_NE(CvaeTrainer::validateModel(data, a + "/model.pt", v).validation_bce, r.validation_bce);

  // Given the meshes, mesh piles train beside superquadric ones (three scenes each,
  // interleaved: the last, the run's validation, is a mesh pile), and the run's validation is
  // the one --validate-only gives for its model file.
  TrainConfig t = tinyTraining(2);
  t.validation_scenes = 1;
  t.validation_views = 1;
  const TrainingReport trained = CvaeTrainer({data, ycb}, tiny(), t, b, "test", dir).run(false);
  EXPECT_EQ(trained.steps, 2);
  EXPECT_EQ(CvaeTrainer::validateModel({data, ycb}, b + "/model.pt", t, dir).validation_bce,
            trained.validation_bce);
  EXPECT_EQ(
      loadYamlFile(b + "/model.yaml", "model card")["provenance"]["dataset"].as<std::string>(),
      data + " + " + ycb);
}

TEST(CvaeTrainer, DeterministicResumableAndLogged) {
  const TrainingScratch scratch("simstack_train");
  const auto& [a, b, c] = scratch.dirs;
  const std::string& data = scratch.data;
  TrainConfig tc = scratch.tc;
  // Two fresh runs with one seed give the same weights.
  const TrainingReport ra = CvaeTrainer(data, tiny(), tc, a, "test").run(false);
  CvaeTrainer(data, tiny(), tc, b, "test").run(false);
  EXPECT_TRUE(torch::equal(probe(a + "/model.pt"), probe(b + "/model.pt")));
  EXPECT_EQ(ra.steps, 4);
  EXPECT_TRUE(std::isfinite(ra.posterior_mu_rms) && ra.posterior_sigma > 0.0);
  EXPECT_GE(ra.validation_disagreement, 0.0);
  EXPECT_LE(ra.validation_disagreement, 1.0);
  EXPECT_GE(ra.validation_posterior_iou, 0.0);
  EXPECT_LE(ra.validation_posterior_iou, 1.0);
  // The log: header, a row every 10 steps or validation (steps 2 and 4), all columns on
  // validation rows.
  const std::vector<std::string> log = lines(a + "/train_log.csv");
  ASSERT_EQ(log.size(), 3u);
  EXPECT_EQ(log[0].rfind("step,total,", 0), 0u);
  EXPECT_EQ(fields(log[1]), fields(log[0]));
  EXPECT_EQ(log[2].rfind("4,", 0), 0u);
  // Interrupted at step 2 and resumed: it continues from the checkpoint to step 4, appending
  // to the log, and a resumed run is itself reproducible (not equal to the uninterrupted run:
  // the shorter run's learning-rate schedule differs; a run stopped and resumed is, below).
  TrainConfig half = tc;
  half.steps = 2;
  for (const auto& d : {b, c}) {
    fs::remove_all(d);
    CvaeTrainer(data, tiny(), half, d, "test").run(false);
    // b was killed after logging a step past its checkpoint: that row is trained again and
    // must not stay twice.
    if (d == b) std::ofstream(d + "/train_log.csv", std::ios::app) << "3,1,1,1,1,1,1,1,1\n";
    CvaeTrainer(data, tiny(), tc, d, "test").run(true);
  }
  EXPECT_EQ(lines(b + "/state.yaml").at(0), "step: 4");
  const std::vector<std::string> resumed = lines(b + "/train_log.csv");
  ASSERT_EQ(resumed.size(), 3u);
  EXPECT_EQ(resumed[1].rfind("2,", 0), 0u);
  EXPECT_EQ(resumed[2].rfind("4,", 0), 0u);
  EXPECT_TRUE(torch::equal(probe(b + "/model.pt"), probe(c + "/model.pt")));
  // A log of other columns (an older version's) is not appended to: resuming says so.
  {
    std::ofstream old(c + "/train_log.csv");
    old << "step,total,tsdf,partial,votes,mmd,occupancy,samples_per_s\n";
  }
  try {
    CvaeTrainer(data, tiny(), tc, c, "test").run(true);
    ADD_FAILURE() << "a log of other columns was appended to";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("other columns"), std::string::npos) << e.what();
  }
  // A warm start takes the file's weights (the every-scale network adds its code projections),
  // stays nearer to them than a fresh start, and says where it started in model.yaml.
  {
    const std::string w = tempPath("simstack_train_warm"), f = tempPath("simstack_train_fresh");
    const RemoveAtExit cleanup_warm{{w, f}};
    CvaeConfig every = tiny();
    every.latent_injection = "every_scale";
    TrainConfig warm = tc;
    warm.steps = 1;
    warm.learning_rate = warm.final_learning_rate = 1e-9;
    CvaeTrainer(data, every, warm, f, "test").run(false);
    warm.init_from = a + "/model.pt";
    // The parent's card holds a tuned Hough setting (its perception section is the card's last).
    std::ofstream(a + "/model.yaml", std::ios::app) << "  hough:\n    refinement: 7\n";
    CvaeTrainer(data, every, warm, w, "test").run(false);
    const torch::Tensor from = probe(a + "/model.pt");
    EXPECT_LT((probe(w + "/model.pt") - from).abs().max().item<double>(),
              (probe(f + "/model.pt") - from).abs().max().item<double>());
    bool recorded = false;
    for (const auto& line : lines(w + "/model.yaml"))
      recorded |= line.find("init_from: " + warm.init_from) != std::string::npos;
    EXPECT_TRUE(recorded) << "model.yaml does not name the warm start's file";
    // The warm start's card carries the parent's Hough setting; a fresh start's has none.
    const YAML::Node child = loadYamlFile(w + "/model.yaml", "model card")["perception"];
    const YAML::Node fresh = loadYamlFile(f + "/model.yaml", "model card")["perception"];
    ASSERT_TRUE(child["hough"]) << "the warm start's card lost its parent's Hough setting";
    EXPECT_EQ(child["hough"]["refinement"].as<int>(), 7);
    EXPECT_EQ(child["samples"].as<int>(), 3);
    EXPECT_TRUE(fresh.IsMap() && !fresh["hough"]);
    // From the run's checkpoint, which has no card of its own: its run's card gives the setting.
    const std::string w2 = w + "_checkpoint";
    const RemoveAtExit cleanup_w2{{w2}};
    warm.init_from = a + "/checkpoint.pt";
    CvaeTrainer(data, every, warm, w2, "test").run(false);
    const YAML::Node from_checkpoint = loadYamlFile(w2 + "/model.yaml", "model card")["perception"];
    ASSERT_TRUE(from_checkpoint["hough"])
        << "a warm start from a checkpoint lost the run's setting";
    EXPECT_EQ(from_checkpoint["hough"]["refinement"].as<int>(), 7);
    warm.init_from = "/nonexistent/start.pt";
    fs::remove_all(w);
    try {
      CvaeTrainer(data, every, warm, w, "test").run(false);
      ADD_FAILURE() << "a warm start from a missing file did not throw";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("/nonexistent/start.pt"), std::string::npos) << e.what();
    }
  }
  // FC: no posterior to report.
  TrainConfig fc = tc;
  fc.steps = 2;
  fs::remove_all(c);
  const TrainingReport rf = CvaeTrainer(data, tiny("fc"), fc, c, "test").run(false);
  EXPECT_TRUE(std::isnan(rf.posterior_mu_rms));
  EXPECT_TRUE(std::isnan(rf.validation_posterior_iou));
  // Trained further with other loss settings, the saved model says which; another network in
  // the config is an error.
  CvaeConfig widths = tiny();
  widths.mmd_kernel_widths = {0.2, 1.0, 5.0};
  TrainConfig longer = tc;
  longer.steps = 5;
  CvaeTrainer(data, widths, longer, b, "test").run(true);
  EXPECT_EQ(loadCvae(b + "/model.pt")->config().mmd_kernel_widths, widths.mmd_kernel_widths);
  CvaeConfig wider = tiny();
  wider.base_channels = 8;
  longer.steps = 6;
  EXPECT_THROW(CvaeTrainer(data, wider, longer, b, "test").run(true), std::runtime_error);
  // --resume with nothing to resume is an error, not a fresh start.
  const std::string none = tempPath("simstack_train_none");
  const RemoveAtExit cleanup_none{{none}};
  try {
    CvaeTrainer(data, tiny(), tc, none, "test").run(true);
    ADD_FAILURE() << "resumed without a checkpoint";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("no checkpoint"), std::string::npos) << e.what();
  }
}

TEST(CvaeTrainer, ACheckpointIsOneFileThatOutlivesStaleSideFiles) {
  // The checkpoint holds the network, the optimizer's state and the step, so that a kill
  // while it is saved cannot pair one checkpoint's network with another's optimizer: side
  // files (state.yaml and optimizer.pt of step 2 beside step 4's network) change nothing.
  const TrainingScratch scratch("simstack_ckpt");
  const auto& [x, y, z] = scratch.dirs;
  const std::string& data = scratch.data;
  const TrainConfig& tc = scratch.tc;
  TrainConfig half = tc;
  half.steps = 2;
  CvaeTrainer(data, tiny(), half, y, "test").run(false);
  for (const auto& d : {x, z}) CvaeTrainer(data, tiny(), tc, d, "test").run(false);
  EXPECT_FALSE(fs::exists(x + "/optimizer.pt"));
  fs::copy_file(y + "/state.yaml", x + "/state.yaml", fs::copy_options::overwrite_existing);
  torch::optim::Adam stale(Cvae(tiny())->parameters());
  torch::save(stale, x + "/optimizer.pt");
  TrainConfig longer = tc;
  longer.steps = 6;
  for (const auto& d : {x, z}) CvaeTrainer(data, tiny(), longer, d, "test").run(true);
  EXPECT_TRUE(torch::equal(probe(x + "/model.pt"), probe(z + "/model.pt")));
  EXPECT_EQ(lines(x + "/state.yaml").at(0), "step: 6");
}

TEST(CvaeTrainer, AStopCheckpointsItsStepAndAFinishedRunKeepsItsModel) {
  // Asked to stop after step 1 (checkpoints every 2): the step is not lost.
  const TrainingScratch scratch("simstack_stop");
  const std::string& run = scratch.dirs[0];
  int asked = 0;
  try {
    CvaeTrainer(scratch.data, tiny(), scratch.tc, run, "test").run(false, {}, [&] {
      ++asked;
      return true;
    });
    ADD_FAILURE() << "a run asked to stop trained on";
  } catch (const TrainingStopped& e) {
    EXPECT_EQ(e.step, 1);
    EXPECT_NE(std::string(e.what()).find("--resume"), std::string::npos) << e.what();
  }
  EXPECT_EQ(asked, 1);
  EXPECT_EQ(lines(run + "/state.yaml").at(0), "step: 1");
  EXPECT_FALSE(fs::exists(run + "/model.pt"));
  const TrainingReport finished =
      CvaeTrainer(scratch.data, tiny(), scratch.tc, run, "test").run(true);
  EXPECT_EQ(finished.steps_trained, 3);
  // Stopped after step 1 and resumed, it ends where the run never stopped ends: the C-VAE's
  // posterior noise and prior codes are drawn step by step, not from one stream since the start.
  ASSERT_EQ(tiny().architecture, "cvae");
  const std::string straight = scratch.dirs[1];
  CvaeTrainer(scratch.data, tiny(), scratch.tc, straight, "test").run(false);
  EXPECT_TRUE(torch::equal(probe(run + "/model.pt"), probe(straight + "/model.pt")));
  // Resumed once more with nothing to train: the model and its card stay as written, and the
  // report gives the card's figures (the posterior of the steps that trained it included).
  const std::vector<std::string> card = lines(run + "/model.yaml");
  const auto bytes = [](const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
  };
  const std::string model_before = bytes(run + "/model.pt");  // its metadata holds the losses
  const TrainingReport again = CvaeTrainer(scratch.data, tiny(), scratch.tc, run, "test").run(true);
  EXPECT_EQ(again.steps_trained, 0);
  EXPECT_EQ(lines(run + "/model.yaml"), card);
  EXPECT_EQ(bytes(run + "/model.pt"), model_before) << "the finished model was written again";
  EXPECT_NEAR(again.total, finished.total, 1e-6 * std::abs(finished.total));
  EXPECT_NEAR(again.validation_iou, finished.validation_iou, 1e-9);
  ASSERT_TRUE(std::isfinite(finished.posterior_mu_rms));
  EXPECT_NEAR(again.posterior_mu_rms, finished.posterior_mu_rms, 1e-6);
}

// A warm start from a parent trained on the same seed's piles: the validation piles it trained
// on are counted, said and written in the card's provenance.
TEST(CvaeTrainer, AWarmStartSaysWhichValidationPilesItsParentTrainedOn) {
  const TrainingScratch scratch("simstack_warm_overlap");
  const auto& [parent, child, apart] = scratch.dirs;
  TrainConfig tc = scratch.tc;
  tc.steps = 1;
  CvaeTrainer(scratch.data, tiny(), tc, parent, "test").run(false);  // trained on scenes 0, 1
  tc.init_from = parent + "/model.pt";
  tc.validation_scenes = 2;  // scenes 1 and 2: the parent trained on 1
  tc.steps = 4;
  // Stopped after its first step and resumed (without --init-from, as a resume is started):
  // the count is the run's parent's, said again, and in the finished card.
  try {
    CvaeTrainer(scratch.data, tiny(), tc, child, "test").run(false, {}, [] { return true; });
    ADD_FAILURE() << "a run asked to stop trained on";
  } catch (const TrainingStopped&) {
  }
  TrainConfig resumed = tc;
  resumed.init_from.clear();
  testing::internal::CaptureStderr();
  CvaeTrainer(scratch.data, tiny(), resumed, child, "test").run(true);
  const std::string said = testing::internal::GetCapturedStderr();
  EXPECT_NE(said.find("note: 1 of the last 2 piles, this run's validation, were trained on by " +
                      tc.init_from),
            std::string::npos)
      << said;
  EXPECT_NE(said.find("from pile 2 on, the parent trained on none"), std::string::npos) << said;
  const YAML::Node provenance = loadYamlFile(child + "/model.yaml", "model card")["provenance"];
  EXPECT_EQ(provenance["validation_trained_by_parent"].as<int>(), 1);
  tc.validation_scenes = 1;  // the parent's own validation pile: nothing to say
  tc.steps = 1;
  testing::internal::CaptureStderr();
  CvaeTrainer(scratch.data, tiny(), tc, apart, "test").run(false);
  EXPECT_EQ(testing::internal::GetCapturedStderr().find("were trained on by"), std::string::npos);
  EXPECT_FALSE(loadYamlFile(apart + "/model.yaml",
                            "model card")["provenance"]["validation_trained_by_parent"]);
}

// A refused setting is named with its value as written: a count whole, a rate to the digit
// that tells it from its neighbour.
TEST(TrainConfig, ARefusedValueIsNamedAsWritten) {
  const auto refusal = [](const TrainConfig& t) {
    try {
      t.validate();
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("(accepted)");
  };
  TrainConfig rate;
  rate.learning_rate = 0.0002;
  rate.final_learning_rate = 0.00020000004;
  EXPECT_NE(refusal(rate).find("<= learning_rate (0.0002), got 0.00020000004"), std::string::npos)
      << refusal(rate);
  TrainConfig steps;
  steps.steps = -1234567;
  EXPECT_NE(refusal(steps).find("steps must be >= 1, got -1234567"), std::string::npos)
      << refusal(steps);
  CvaeConfig weights;
  weights.gamma = -1.0;
  try {
    weights.validate();
    ADD_FAILURE() << "a negative loss weight was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("gamma (a loss weight) must be >= 0, got -1"),
              std::string::npos)
        << e.what();
  }
}

// Two trainings in one run directory would write one checkpoint: the second is refused, and
// the run's files stay as they were.
TEST(CvaeTrainer, ASecondTrainingInARunDirectoryIsRefused) {
  const TrainingScratch scratch("simstack_run_lock");
  const std::string& run = scratch.dirs[0];
  fs::create_directories(run);
  const int held = ::open(run.c_str(), O_RDONLY | O_DIRECTORY);
  ASSERT_GE(held, 0);
  ASSERT_EQ(::flock(held, LOCK_EX | LOCK_NB), 0);  // as the other trainer's process holds it
  try {
    CvaeTrainer(scratch.data, tiny(), scratch.tc, run, "test").run(false);
    ADD_FAILURE() << "a second training ran in a held run directory";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("another training runs in " + run), std::string::npos)
        << e.what();
  }
  EXPECT_FALSE(fs::exists(run + "/checkpoint.pt"));
  ::close(held);  // the other ended: the run goes ahead
  EXPECT_EQ(CvaeTrainer(scratch.data, tiny(), scratch.tc, run, "test").run(false).steps, 4);
}

TEST(CvaeTrainer, ACheckpointWithoutAFormatVersionIsRefusedWithTheWayOn) {
  const TrainingScratch scratch("simstack_ckpt_format");
  const std::string& x = scratch.dirs[0];
  CvaeTrainer(scratch.data, tiny(), scratch.tc, x, "test").run(false);
  std::string metadata;
  Cvae model = loadCvae(x + "/checkpoint.pt", nullptr, &metadata);
  EXPECT_NE(metadata.find("format_version: 1"), std::string::npos) << metadata;
  saveCvae(x + "/checkpoint.pt", model, "dataset: unknown");  // as an unversioned one was
  TrainConfig longer = scratch.tc;
  longer.steps += 2;
  try {
    CvaeTrainer(scratch.data, tiny(), longer, x, "test").run(true);
    ADD_FAILURE() << "resumed a checkpoint without a format version";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("checkpoint format 0 (no format_version"), std::string::npos) << what;
    EXPECT_NE(what.find("--init-from"), std::string::npos) << what;
  }
}

TEST(CvaeTrainer, HowOftenARunValidatesDoesNotChangeWhatItTrains) {
  // Validation draws from streams of its own, and each step from its own: how often a run
  // validates does not change what it trains.
  const TrainingScratch scratch("simstack_validate_every");
  const auto& [often, rarely, unused] = scratch.dirs;
  TrainConfig tc = scratch.tc;
  tc.steps = 6;
  CvaeTrainer(scratch.data, tiny(), tc, often, "test").run(false);  // validates at 2, 4, 6
  tc.validate_every = 3;
  CvaeTrainer(scratch.data, tiny(), tc, rarely, "test").run(false);  // at 3, 6
  EXPECT_TRUE(torch::equal(probe(often + "/model.pt"), probe(rarely + "/model.pt")));
}

// Loss settings may change on a resume: the fields changed are named, a list as a whole.
TEST(CvaeTrainer, AResumeWithOtherLossSettingsNamesThem) {
  const TrainingScratch scratch("simstack_resume_losses");
  const std::string& run = scratch.dirs[0];
  TrainConfig half = scratch.tc;
  half.steps = 2;
  CvaeTrainer(scratch.data, tiny(), half, run, "test").run(false);
  CvaeConfig widths = tiny();
  widths.mmd_kernel_widths = {0.5, 1.0, 2.0};
  widths.tsdf_epsilon = 0.05;  // stored as 0.050000000000000003, written as 0.05
  testing::internal::CaptureStderr();
  CvaeTrainer(scratch.data, widths, scratch.tc, run, "test").run(true);
  const std::string said = testing::internal::GetCapturedStderr();
  EXPECT_NE(said.find("loss settings are replaced by the config's: "), std::string::npos) << said;
  EXPECT_NE(said.find("mmd_kernel_widths: [1] (checkpoint) against mmd_kernel_widths: [0.5, 1, "
                      "2] (config)"),
            std::string::npos)
      << said;
  EXPECT_NE(said.find("tsdf_epsilon: 0.01 (checkpoint) against tsdf_epsilon: 0.05 (config)"),
            std::string::npos)
      << said;
}

// A resume that would rewind a run, mix two datasets or change its network is refused by name,
// and leaves the run as it was; a Hough setting put into the run's card survives a resume.
TEST(CvaeTrainer, AResumeThatWouldRewindOrMixARunIsRefused) {
  const TrainingScratch scratch("simstack_resume_refused");
  const std::string& run = scratch.dirs[0];
  CvaeTrainer(scratch.data, tiny(), scratch.tc, run, "test").run(false);  // 4 steps
  const torch::Tensor trained = probe(run + "/checkpoint.pt");
  auto refused = [&](const std::string& data, const CvaeConfig& model, int steps) {
    TrainConfig tc = scratch.tc;
    tc.steps = steps;
    try {
      CvaeTrainer(data, model, tc, run, "test").run(true);
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string("(not refused)");
  };
  EXPECT_NE(refused(scratch.data, tiny(), 2).find("is at step 4, past steps = 2"),
            std::string::npos);
  CvaeConfig wider = tiny();
  wider.base_channels = 8;
  EXPECT_NE(refused(scratch.data, wider, 6)
                .find("base_channels: 4 (checkpoint) against "
                      "base_channels: 8 (config)"),
            std::string::npos);
  // Other settings than the run was started with: named, the run left as it was.
  {
    TrainConfig faster = scratch.tc;
    faster.steps = 6;
    faster.learning_rate *= 10;
    faster.batch_size += 1;
    std::string why = "(not refused)";
    try {
      CvaeTrainer(scratch.data, tiny(), faster, run, "test").run(true);
    } catch (const std::runtime_error& e) {
      why = e.what();
    }
    EXPECT_NE(why.find("was trained with other settings (batch_size"), std::string::npos) << why;
    EXPECT_NE(why.find("learning_rate"), std::string::npos) << why;
  }
  // The same file written again: with other object counts, then with a fourth scene.
  EXPECT_NE(refused(tinyDataset(3, 2), tiny(), 6)
                .find("was trained on a dataset of seed 5, 3 scenes of 3-4 objects"),
            std::string::npos);
  const std::string other = tinyDataset(4);
  EXPECT_NE(refused(other, tiny(), 6).find("holds seed 5, 4 scenes of 3-4 objects"),
            std::string::npos);
  EXPECT_EQ(lines(run + "/state.yaml").at(0), "step: 4");
  EXPECT_TRUE(torch::equal(probe(run + "/checkpoint.pt"), trained));
  // A validation of more scenes than the dataset holds names the count it can take.
  TrainConfig v = scratch.tc;
  v.validation_scenes = 5;
  try {
    CvaeTrainer::validateModel(other, run + "/model.pt", v);
    ADD_FAILURE() << "5 validation scenes of 4 were accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("give --validation-scenes 4 or fewer"), std::string::npos)
        << e.what();
  }
}

// Several datasets train as one: the card names them all, and the run resumes on that mix only.
TEST(CvaeTrainer, TrainsOnSeveralDatasetsReadAsOne) {
  const TrainingScratch scratch("simstack_train_mix");
  const std::string second = tinyDataset(2, 3, 6, "simstack_test_train_crowded.h5");
  const RemoveAtExit cleanup{{second}};
  const std::string& run = scratch.dirs[0];
  TrainConfig tc = scratch.tc;
  tc.validation_scenes = 2;  // the mix's last two: one scene of each file
  const TrainingReport r = CvaeTrainer({scratch.data, second}, tiny(), tc, run, "test").run(false);
  EXPECT_EQ(r.steps, 4);
  const YAML::Node provenance = loadYamlFile(run + "/model.yaml", "model card")["provenance"];
  EXPECT_EQ(provenance["dataset"].as<std::string>(), scratch.data + " + " + second);
  EXPECT_EQ(provenance["dataset_seed"].as<std::string>(), "5 + 6");
  EXPECT_EQ(provenance["dataset_scenes"].as<std::string>(), "3 + 2");
  // The same validation from the model file, given the same files.
  EXPECT_EQ(
      CvaeTrainer::validateModel({scratch.data, second}, run + "/model.pt", tc).validation_bce,
      r.validation_bce);
  // Resumed on one of its two files: refused, the message naming the run's two tags.
  tc.steps = 6;
  try {
    CvaeTrainer(scratch.data, tiny(), tc, run, "test").run(true);
    ADD_FAILURE() << "a run on two datasets resumed on one";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("seed 5, 3 scenes of 3-4 objects, generator " +
                                         std::string(kGeneratorVersion) +
                                         " + seed 6, 2 scenes of 3-4 objects"),
              std::string::npos)
        << e.what();
  }
}

TEST(CvaeTrainer, AResumeKeepsTheHoughSettingOfTheRunsCard) {
  const TrainingScratch scratch("simstack_resume_card");
  const std::string& run = scratch.dirs[0];
  CvaeTrainer(scratch.data, tiny(), scratch.tc, run, "test").run(false);
  {  // as a user pastes simstack_tune_hough's output over the card's perception: section
    std::ofstream card(run + "/model.yaml", std::ios::app);
    card << "  hough:\n    refinement: 5\n    bandwidth_m: 0.05\n";
  }
  auto card = [&] { return loadYamlFile(run + "/model.yaml", "card")["perception"]; };
  ASSERT_EQ(card()["hough"]["refinement"].as<int>(), 5);
  TrainConfig tc = scratch.tc;
  tc.steps = 6;
  CvaeTrainer(scratch.data, tiny(), tc, run, "test").run(true);
  EXPECT_EQ(lines(run + "/state.yaml").at(0), "step: 6");
  EXPECT_EQ(card()["hough"]["refinement"].as<int>(), 5);
  EXPECT_DOUBLE_EQ(card()["hough"]["bandwidth_m"].as<double>(), 0.05);
  EXPECT_EQ(card()["samples"].as<int>(), 3);
}

// A warm-started run stopped before its end has no card yet; its resume (which does not read
// --init-from) still gives the card its parent's Hough setting.
TEST(CvaeTrainer, AResumedWarmStartKeepsItsParentsHoughSetting) {
  const TrainingScratch scratch("simstack_resume_parent");
  const auto& [parent, child, other] = scratch.dirs;
  CvaeTrainer(scratch.data, tiny(), scratch.tc, parent, "test").run(false);
  std::ofstream(parent + "/model.yaml", std::ios::app) << "  hough:\n    refinement: 5\n";
  TrainConfig tc = scratch.tc;
  tc.steps = 2;
  tc.init_from = parent + "/model.pt";
  CvaeTrainer(scratch.data, tiny(), tc, child, "test").run(false);
  fs::remove(child + "/model.yaml");  // as if stopped before the end: only the checkpoint
  fs::remove(child + "/model.pt");
  tc.steps = 4;
  tc.init_from.clear();
  CvaeTrainer(scratch.data, tiny(), tc, child, "test").run(true);
  EXPECT_EQ(
      loadYamlFile(child + "/model.yaml", "card")["perception"]["hough"]["refinement"].as<int>(),
      5);
  // The card's training section names the parent, as an uninterrupted run's does.
  EXPECT_EQ(loadYamlFile(child + "/model.yaml", "card")["training"]["init_from"].as<std::string>(),
            parent + "/model.pt");
  // Another model named with --init-from on a resume is not read: not its weights, nor its
  // card's setting, nor its name on the card.
  CvaeTrainer(scratch.data, tiny(), scratch.tc, other, "test").run(false);
  std::ofstream(other + "/model.yaml", std::ios::app) << "  hough:\n    refinement: 7\n";
  fs::remove(child + "/model.yaml");
  fs::remove(child + "/model.pt");
  tc.steps = 6;
  tc.init_from = other + "/model.pt";
  CvaeTrainer(scratch.data, tiny(), tc, child, "test").run(true);
  const YAML::Node card = loadYamlFile(child + "/model.yaml", "card");
  EXPECT_EQ(card["perception"]["hough"]["refinement"].as<int>(), 5);
  EXPECT_EQ(card["training"]["init_from"].as<std::string>(), parent + "/model.pt");
}

// A dataset that goes bad between two runs: the resumed run stops on its first training batch
// with the file's name in the message, and the checkpoint it started from stays whole.
TEST(CvaeTrainer, AFailedReadKeepsTheLastCheckpoint) {
  const std::string data = tinyDataset(3), out = tempPath("simstack_train_fail");
  const RemoveAtExit cleanup{{out, data}};
  fs::remove_all(out);
  TrainConfig tc = tinyTraining(2);
  tc.checkpoint_every = 1;
  CvaeTrainer(data, tiny(), tc, out, "test").run(false);
  const torch::Tensor before = probe(out + "/checkpoint.pt");
  {  // the two training scenes claim 999 objects; the validation scene stays good
    H5::H5File file(data, H5F_ACC_RDWR);
    H5::DataSet count = file.openDataSet("num_objects");
    std::vector<int32_t> n(3);
    count.read(n.data(), H5::PredType::NATIVE_INT32);
    n[0] = n[1] = 999;
    count.write(n.data(), H5::PredType::NATIVE_INT32);
  }
  tc.steps = 4;
  try {
    CvaeTrainer(data, tiny(), tc, out, "test").run(true);
    ADD_FAILURE() << "training on scenes with 999 objects did not stop";
  } catch (const std::runtime_error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(data), std::string::npos) << what;
    EXPECT_NE(what.find("invalid object count 999"), std::string::npos) << what;
  }
  EXPECT_EQ(lines(out + "/state.yaml").at(0), "step: 2");
  EXPECT_TRUE(torch::equal(probe(out + "/checkpoint.pt"), before));
  for (const auto& entry : fs::directory_iterator(out))
    EXPECT_NE(entry.path().extension(), ".tmp") << entry.path();
}
