#include <gtest/gtest.h>

#include <unistd.h>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <tuple>

#include <H5Cpp.h>

#include "model_test_helpers.h"
#include "simstack/io/yaml_file.h"
#include "simstack/model/cvae.h"
#include "simstack/model/cvae_inference.h"
#include "simstack/model/model_integrity.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/offline/eval/occupancy.h"
#include "simstack/offline/piles/mesh_catalogue.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/offline/training/cvae_losses.h"
#include "simstack/offline/training/cvae_trainer.h"
#include "simstack/offline/training/model_writer.h"
#include "simstack/offline/training/training_sample.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/tsdf/network_input.h"
#include "simstack/tsdf/projective_tsdf.h"
#include "test_scenes.h"

using namespace simstack;
namespace fs = std::filesystem;

using test::RemoveAtExit;
using test::tempPath;
using test::tiny;

TEST(Cvae, OutputShapesAreRightAndFinite) {
  torch::manual_seed(0);
  for (const std::string arch : {"cvae", "fc", "fc_plain"}) {
    Cvae model(tiny(arch));
    const auto partial = torch::rand({2, 2, 16, 16, 16}) * 2 - 1;
    const auto tsdf = torch::rand({2, 1, 16, 16, 16}) * 2 - 1;
    const auto votes = torch::randn({2, 3, 16, 16, 16});
    const CvaeOutput o = model->forward(partial, tsdf, votes);
    EXPECT_EQ(o.tsdf.sizes(), torch::IntArrayRef({2, 1, 16, 16, 16})) << arch;
    EXPECT_EQ(o.votes.sizes(), torch::IntArrayRef({2, 3, 16, 16, 16})) << arch;
    EXPECT_EQ(o.partial_recon.sizes(), torch::IntArrayRef({2, 1, 16, 16, 16})) << arch;
    EXPECT_TRUE(torch::isfinite(o.tsdf).all().item<bool>()) << arch;
    EXPECT_TRUE(torch::isfinite(o.votes).all().item<bool>()) << arch;
    if (arch == "cvae") {
      EXPECT_EQ(o.z.sizes(), torch::IntArrayRef({2, 8}));
    }
    const CvaeLosses l = computeLosses(o, partial, tsdf, votes, model->config());
    EXPECT_TRUE(std::isfinite(l.total.item<double>())) << arch;
  }
}

// The paper's FC baseline decodes from the encoder's deepest map alone: its decoder blocks
// below the deepest scale read only the decoder's own features, where the C-VAE's and our FC
// ablation's also read the condition's map of that scale (twice the input channels).
TEST(Cvae, PlainFcDecoderReadsNoFinerConditionMaps) {
  auto inputChannels = [](const std::string& arch, int level) {
    Cvae model(tiny(arch));
    const std::string name = "dec_joint" + std::to_string(level) + ".a.conv.weight";
    for (const auto& p : model->named_parameters())
      if (p.key() == name) return p.value().size(1);
    ADD_FAILURE() << "no parameter " << name << " in " << arch;
    return int64_t{-1};
  };
  // tiny(): widths 4, 8, 16, 16, 16 over the five scales.
  const std::vector<int64_t> widths{4, 8, 16, 16, 16};
  for (int level = 0; level < 4; ++level) {
    EXPECT_EQ(inputChannels("fc_plain", level), widths[level]) << level;
    EXPECT_EQ(inputChannels("fc", level), 2 * widths[level]) << level;
    EXPECT_EQ(inputChannels("cvae", level), 2 * widths[level]) << level;
  }
  EXPECT_EQ(inputChannels("fc_plain", 4), 2 * widths[4]);
  // It has no code: one prediction, whatever the codes asked for.
  EXPECT_FALSE(tiny("fc_plain").hasLatentCode());
  EXPECT_TRUE(tiny("cvae").hasLatentCode());
}

TEST(Cvae, LossesMatchHandComputedValues) {
  // Two voxels, batch of one.
  const auto pred = torch::tensor({0.5f, -0.2f}).view({1, 1, 2, 1, 1});
  const auto target = torch::tensor({0.25f, -0.5f}).view({1, 1, 2, 1, 1});
  // |0.5 - 0.25| / (0.25 + 0.01) + |-0.2 + 0.5| / (0.5 + 0.01)
  EXPECT_NEAR(inverseTsdfWeightedLoss(pred, target, 0.01).item<double>(), 0.25 / 0.26 + 0.3 / 0.51,
              1e-6);
  // Batch mean: a second identical sample leaves it unchanged.
  EXPECT_NEAR(inverseTsdfWeightedLoss(torch::cat({pred, pred}), torch::cat({target, target}), 0.01)
                  .item<double>(),
              0.25 / 0.26 + 0.3 / 0.51, 1e-6);
  // Votes: errors (1, 2, 2) and (0, 0, 0): norms 3 and 0.
  const auto vp = torch::tensor({1.0f, 0.0f, 2.0f, 0.0f, 2.0f, 0.0f}).view({1, 3, 2, 1, 1});
  const auto vt = torch::zeros({1, 3, 2, 1, 1});
  EXPECT_NEAR(voteLoss(vp, vt).item<double>(), 3.0, 1e-5);
  // Only voxel 1 lies inside an object (unit target (0, 1, 0)): error (0, -1, 0), norm 1; the
  // free voxel 0 does not count.
  const auto vt_in = torch::tensor({0.0f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f}).view({1, 3, 2, 1, 1});
  EXPECT_NEAR(voteLoss(vp, vt_in, false).item<double>(), 3.0 + 1.0, 1e-5);
  EXPECT_NEAR(voteLoss(vp, vt_in, true).item<double>(), 1.0, 1e-5);
  // Per-voxel weights 2 and 5: 2 x 3 + 5 x 1, and 5 x 1 over the occupied voxel alone.
  const auto w = torch::tensor({2.0f, 5.0f}).view({1, 1, 2, 1, 1});
  EXPECT_NEAR(voteLoss(vp, vt_in, false, w).item<double>(), 2.0 * 3.0 + 5.0, 1e-5);
  EXPECT_NEAR(voteLoss(vp, vt_in, true, w).item<double>(), 5.0, 1e-5);
  // Occupancy, sharpness 10: voxel 0 free (target 0.25), logit -5, -log(1 - sigmoid(-5));
  // voxel 1 occupied (target -0.5), logit 2, -log(sigmoid(2)). A target of exactly 0 is
  // occupied (eq. 8).
  const double free0 = std::log1p(std::exp(-5.0)), occ1 = std::log1p(std::exp(-2.0));
  EXPECT_NEAR(occupancyLoss(pred, target, 10.0).item<double>(), free0 + occ1, 1e-5);
  const auto on_surface = torch::zeros({1, 1, 1, 1, 1});
  EXPECT_NEAR(occupancyLoss(on_surface + 0.1f, on_surface, 10.0).item<double>(),
              std::log1p(std::exp(1.0)), 1e-5);
  // In the total only with a weight: the same output, weight 0 and weight 2.
  CvaeConfig c;
  c.architecture = "fc";
  CvaeOutput o;
  o.tsdf = pred;
  o.partial_recon = pred;
  o.votes = vp;
  const CvaeLosses without = computeLosses(o, torch::cat({target, target}, 1), target, vt, c);
  c.occupancy_weight = 2.0;
  const CvaeLosses with = computeLosses(o, torch::cat({target, target}, 1), target, vt, c);
  EXPECT_NEAR(without.occupancy.item<double>(), free0 + occ1, 1e-5);
  EXPECT_NEAR((with.total - without.total).item<double>(), 2.0 * (free0 + occ1), 1e-4);
}

TEST(Cvae, IouLossIsTheJaccardLossOfTheMistakes) {
  // Sharpness 10: voxels 0, 1 occupied, 2, 3 free. Voxel 0 right by the margin (logit 1), voxel 1
  // undecided (logit 0, hinge error 1), voxel 2 right (logit -1), voxel 3 undecided (error 1).
  // Mistakes {1, 3}: 1 - |{0, 1} minus mistakes| / |{0, 1} or mistakes| = 1 - 1 / 3.
  const auto target = torch::tensor({-0.5f, -0.5f, 0.5f, 0.5f}).view({1, 1, 4, 1, 1});
  const auto pred = torch::tensor({-0.1f, 0.0f, 0.1f, 0.0f}).view({1, 1, 4, 1, 1});
  EXPECT_NEAR(iouLoss(pred, target, 10.0).item<double>(), 2.0 / 3.0, 1e-5);
  // Every voxel right by the margin or more: no loss; the occupied voxel 1 mistaken as free by
  // a margin (error 2): twice its share of the Jaccard loss, 2 x (1 - 1/2).
  const auto right = torch::tensor({-0.3f, -0.1f, 0.1f, 0.4f}).view({1, 1, 4, 1, 1});
  EXPECT_NEAR(iouLoss(right, target, 10.0).item<double>(), 0.0, 1e-6);
  const auto wrong = torch::tensor({-0.3f, 0.1f, 0.1f, 0.4f}).view({1, 1, 4, 1, 1});
  EXPECT_NEAR(iouLoss(wrong, target, 10.0).item<double>(), 1.0, 1e-5);
  // Per sample, then the batch mean: the two samples together score (2/3 + 1) / 2; a sample
  // with nothing occupied scores its largest hinge error (here 2: voxel 0 occupied by the margin).
  EXPECT_NEAR(iouLoss(torch::cat({pred, wrong}), torch::cat({target, target}), 10.0).item<double>(),
              (2.0 / 3.0 + 1.0) / 2.0, 1e-5);
  EXPECT_NEAR(iouLoss(pred, target.abs(), 10.0).item<double>(), 2.0, 1e-5);
  // Its gradient raises the mistaken voxel's occupancy (lowers its TSDF) and leaves the rest.
  const torch::Tensor p = wrong.clone().requires_grad_(true);
  iouLoss(p, target, 10.0).backward();
  const torch::Tensor g = p.grad().flatten();
  EXPECT_GT(g[1].item<double>(), 0.0);
  for (int i : {0, 2, 3}) EXPECT_EQ(g[i].item<double>(), 0.0);
  // In the total only with a weight.
  CvaeConfig c;
  c.architecture = "fc";
  CvaeOutput o;
  o.tsdf = pred;
  o.partial_recon = pred;
  o.votes = torch::zeros({1, 3, 4, 1, 1});
  const CvaeLosses without = computeLosses(o, torch::cat({target, target}, 1), target, o.votes, c);
  c.iou_weight = 3.0;
  const CvaeLosses with = computeLosses(o, torch::cat({target, target}, 1), target, o.votes, c);
  EXPECT_NEAR((with.total - without.total).item<double>(), 3.0 * 2.0 / 3.0, 1e-4);
}

TEST(Cvae, MmdSeparatesPriorFromShiftedCodes) {
  torch::manual_seed(3);
  const auto prior = torch::randn({256, 8});
  EXPECT_LT(mmdLoss(torch::randn({256, 8}), prior).item<double>(), 0.02);
  EXPECT_GT(mmdLoss(torch::randn({256, 8}) + 2.0, prior).item<double>(), 0.3);
  // Hand-computed on two 1-D sets, kernel exp(-(a - b)^2): within {0, 1} e^-1, within {0, 2}
  // e^-4 (diagonals left out), across (1 + e^-4 + e^-1 + e^-1) / 4.
  const torch::Tensor a = torch::tensor({0.0f, 1.0f}).view({2, 1});
  const torch::Tensor b = torch::tensor({0.0f, 2.0f}).view({2, 1});
  const double e1 = std::exp(-1.0), e4 = std::exp(-4.0);
  EXPECT_NEAR(mmdLoss(a, b).item<double>(), e1 + e4 - 2.0 * (1.0 + e4 + 2.0 * e1) / 4.0, 1e-6);
  EXPECT_THROW(mmdLoss(a.narrow(0, 0, 1), b), std::invalid_argument);
  // Widths 1 and 2 (kernel exp(-(a - b)^2 / w) for d = 1): each term is the mean of the two.
  auto k = [](double sq) { return 0.5 * (std::exp(-sq) + std::exp(-sq / 2.0)); };
  EXPECT_NEAR(mmdLoss(a, b, {1.0, 2.0}).item<double>(),
              k(1) + k(4) - 2.0 * (k(0) + k(4) + 2.0 * k(1)) / 4.0, 1e-6);
  EXPECT_THROW(mmdLoss(a, b, {}), std::invalid_argument);
}

TEST(Cvae, SeveralKernelWidthsSeePinnedAndWideCodes) {
  // What our encoders learned: 3/8 of the codes pinned near the prior's centre, the rest wide
  // noise. The single width scores it like a small shift of the prior; widths 0.2, 1 and 5
  // see it.
  torch::manual_seed(5);
  const int n = 512, d = 96, pinned = 3 * n / 8;
  const torch::Tensor prior = torch::randn({n, d});
  const torch::Tensor centre = torch::randn({n, d}) * 0.42;
  torch::Tensor spread = torch::full({n, 1}, 2.5);
  spread.narrow(0, 0, pinned).fill_(0.03);
  const torch::Tensor mixture = centre + torch::randn({n, d}) * spread;
  const double single = mmdLoss(mixture, prior).item<double>();
  const double several = mmdLoss(mixture, prior, {0.2, 1.0, 5.0}).item<double>();
  EXPECT_LT(single, 0.01);
  EXPECT_GT(several, 0.025);
  EXPECT_NEAR(mmdLoss(torch::randn({n, d}), prior, {0.2, 1.0, 5.0}).item<double>(), 0.0, 0.003);
}

TEST(Cvae, GroupNormKeepsEachSampleIndependentOfItsBatch) {
  // In training mode BatchNorm makes a sample's code depend on its batch-mates, which the MMD
  // estimate assumes it does not; with GroupNorm the code of sample 0 is the same in any batch.
  torch::manual_seed(7);  // the same inputs whatever ran before
  const auto x0 = torch::rand({1, 2, 16, 16, 16});
  const auto t0 = torch::rand({1, 1, 16, 16, 16});
  const auto v0 = torch::rand({1, 3, 16, 16, 16});
  for (const std::string norm : {"batch", "group"}) {
    CvaeConfig c = tiny();
    c.norm = norm;
    torch::manual_seed(6);
    Cvae model(c);
    model->train();
    std::vector<torch::Tensor> mu;
    for (int other = 0; other < 2; ++other) {
      torch::manual_seed(100 + other);
      const auto x = torch::cat({x0, torch::rand({1, 2, 16, 16, 16})});
      const auto t = torch::cat({t0, torch::rand({1, 1, 16, 16, 16})});
      const auto v = torch::cat({v0, torch::rand({1, 3, 16, 16, 16})});
      mu.push_back(model->forward(x, t, v).mu[0].detach());
    }
    const double diff = (mu[0] - mu[1]).abs().max().item<double>();
    if (norm == "batch") {
      EXPECT_GT(diff, 1e-3);
    } else {
      EXPECT_LT(diff, 1e-5);
    }
  }
  CvaeConfig bad = tiny();
  bad.norm = "layer";
  EXPECT_THROW(bad.validate(), std::invalid_argument);
}

TEST(Cvae, ResolutionIsAPowerOfTwoTheGridsCanIndex) {
  // The grids' 32-bit voxel indices overflow above 1290 per side; 512 is the largest accepted.
  CvaeConfig c = tiny();
  for (int r : {8, 24, 1024, 2048}) {
    c.resolution = r;
    EXPECT_THROW(c.validate(), std::invalid_argument) << r;
  }
  for (int r : {16, 512}) {
    c.resolution = r;
    EXPECT_NO_THROW(c.validate()) << r;
  }
}

TEST(Cvae, ConditionDropoutDropsWholeSamplesInTrainingOnly) {
  // With condition_dropout, a training step decodes some samples without the condition's two
  // finest maps (they differ from the same step without dropout) and the rest unchanged
  // (GroupNorm keeps samples independent); in eval mode nothing is dropped.
  CvaeConfig c = tiny();
  c.norm = "group";
  torch::manual_seed(5);
  Cvae model(c);
  const auto x = torch::rand({8, 2, 16, 16, 16});
  const auto t = torch::rand({8, 1, 16, 16, 16});
  const auto v = torch::rand({8, 3, 16, 16, 16});
  CvaeConfig dropping = c;
  dropping.condition_dropout = 0.5;
  for (const bool training : {true, false}) {
    model->train(training);
    torch::NoGradGuard no_grad;
    model->setConfig(c);
    torch::manual_seed(9);
    const torch::Tensor plain = model->forward(x, t, v).tsdf;
    model->setConfig(dropping);
    torch::manual_seed(9);  // the same codes: they are drawn before the dropout mask
    const torch::Tensor dropped = model->forward(x, t, v).tsdf;
    int same = 0;
    for (int b = 0; b < 8; ++b) same += torch::allclose(plain[b], dropped[b], 1e-5, 1e-6);
    if (training) {
      EXPECT_GT(same, 0) << "every sample lost its condition maps (p = 0.5, 8 samples)";
      EXPECT_LT(same, 8) << "no sample lost its condition maps (p = 0.5, 8 samples)";
    } else {
      EXPECT_EQ(same, 8);
    }
  }
  dropping.condition_dropout = 1.0;
  EXPECT_THROW(dropping.validate(), std::invalid_argument);
}

TEST(Cvae, DeterministicPosteriorTrainsOnTheMeanCode) {
  // posterior "deterministic": a training step decodes z = mu, the same on every call; the
  // Gaussian posterior decodes a noisy draw around it.
  CvaeConfig c = tiny();
  torch::manual_seed(6);
  Cvae model(c);
  model->train();
  torch::NoGradGuard no_grad;
  const auto x = torch::rand({4, 2, 16, 16, 16});
  const auto t = torch::rand({4, 1, 16, 16, 16});
  const auto v = torch::rand({4, 3, 16, 16, 16});
  const CvaeOutput noisy = model->forward(x, t, v);
  EXPECT_GT((noisy.z - noisy.mu).abs().max().item<float>(), 1e-3);
  c.posterior = "deterministic";
  model->setConfig(c);
  const CvaeOutput a = model->forward(x, t, v);
  const CvaeOutput b = model->forward(x, t, v);
  EXPECT_TRUE(torch::equal(a.z, a.mu));
  EXPECT_TRUE(torch::allclose(a.tsdf, b.tsdf, 1e-5, 1e-6));
  EXPECT_EQ(CvaeConfig::fromYaml(c.toYaml()).posterior, "deterministic");
  c.posterior = "sampled";
  EXPECT_THROW(c.validate(), std::invalid_argument);
}

TEST(Cvae, BestOfManyTrainsTheCodeThatScoresBest) {
  // best_of k: a training step decodes k posterior codes per scene (scene-major), and each
  // scene's reconstruction terms are those of its best code, picked by the weighted sum.
  CvaeConfig c = tiny();
  c.best_of = 3;
  c.occupancy_weight = 0.5;
  torch::manual_seed(8);
  Cvae model(c);
  model->train();
  const auto x = torch::rand({2, 2, 16, 16, 16});
  const auto t = torch::rand({2, 1, 16, 16, 16}) - 0.5;
  const auto v = torch::rand({2, 3, 16, 16, 16});
  const CvaeOutput out = model->forward(x, t, v);
  ASSERT_EQ(out.tsdf.size(0), 6);
  EXPECT_EQ(out.mu.size(0), 2);
  EXPECT_FALSE(torch::allclose(out.z[0], out.z[1]));  // separate draws around one mean
  const CvaeLosses l = computeLosses(out, x, t, v, c);
  double tsdf = 0, votes = 0;
  for (int s = 0; s < 2; ++s) {
    double best = std::numeric_limits<double>::infinity(), best_tsdf = 0, best_votes = 0;
    for (int j = 0; j < 3; ++j) {
      const auto one = out.tsdf.narrow(0, 3 * s + j, 1), target = t.narrow(0, s, 1);
      const double a = inverseTsdfWeightedLoss(one, target, c.tsdf_epsilon).item<double>();
      const double b =
          voteLoss(out.votes.narrow(0, 3 * s + j, 1), v.narrow(0, s, 1), true).item<double>();
      const double o = occupancyLoss(one, target, c.occupancy_sharpness).item<double>();
      if (a + b + 0.5 * o >= best) continue;
      best = a + b + 0.5 * o;
      best_tsdf = a;
      best_votes = b;
    }
    tsdf += best_tsdf / 2;
    votes += best_votes / 2;
  }
  EXPECT_NEAR(l.tsdf.item<double>(), tsdf, 1e-4 * tsdf);
  EXPECT_NEAR(l.votes.item<double>(), votes, 1e-4 * votes);
  l.total.backward();  // the selection is not differentiated, the chosen terms are
  model->eval();
  EXPECT_EQ(model->forward(x, t, v).tsdf.size(0), 2);  // inference decodes one code per scene
  EXPECT_EQ(CvaeConfig::fromYaml(c.toYaml()).best_of, 3);
  c.best_of = 0;
  EXPECT_THROW(c.validate(), std::invalid_argument);
  c.best_of = 2;
  c.posterior = "deterministic";
  EXPECT_THROW(c.validate(), std::invalid_argument);
}

TEST(Cvae, BestOfManyMeasuresTheMmdOnOneCodePerScene) {
  // k codes of one scene share its posterior: with all of them in the MMD, codes whose scenes'
  // draws follow the prior would still score far from zero. The term takes each scene's first.
  CvaeConfig c = tiny();
  const int64_t scenes = 32, k = 8, r = c.resolution;
  torch::manual_seed(3);
  const torch::Tensor distinct = torch::randn({scenes, c.latent_size});
  CvaeOutput out;
  out.z = distinct.repeat_interleave(k, 0);  // each scene's codes alike: sigma near 0
  out.tsdf = torch::zeros({scenes * k, 1, r, r, r});
  out.votes = torch::zeros({scenes * k, 3, r, r, r});
  out.partial_recon = torch::zeros({scenes, 1, r, r, r});
  const auto x = torch::zeros({scenes, 2, r, r, r}), t = torch::zeros({scenes, 1, r, r, r});
  const auto v = torch::zeros({scenes, 3, r, r, r});
  torch::manual_seed(4);
  const double measured = computeLosses(out, x, t, v, c).mmd.item<double>();
  torch::manual_seed(4);
  const torch::Tensor prior = torch::randn({c.mmd_prior_samples, c.latent_size});
  EXPECT_NEAR(measured, mmdLoss(distinct, prior, c.mmd_kernel_widths).item<double>(), 1e-6);
  EXPECT_GT(mmdLoss(out.z, prior, c.mmd_kernel_widths).item<double>(), 3.0 * measured);
}

TEST(Cvae, LearnedPriorStartsStandardAndItsKlIsExact) {
  CvaeConfig c = tiny();
  c.prior = "learned";
  c.kl_weight = 2.0;
  torch::manual_seed(7);
  Cvae model(c);
  model->eval();
  const auto x = torch::rand({2, 2, 16, 16, 16});
  const auto z = torch::randn({2, 8});
  {
    // At first the prior is N(0, I): a draw decodes as itself.
    torch::NoGradGuard no_grad;
    EXPECT_TRUE(torch::allclose(model->generate(x, z).tsdf, model->decodeCodes(x, z).tsdf));
  }
  // Training moves the prior: a step on the KL alone pulls it towards the posterior.
  model->train();
  const auto t = torch::rand({2, 1, 16, 16, 16}), v = torch::rand({2, 3, 16, 16, 16});
  const CvaeOutput out = model->forward(x, t, v);
  ASSERT_TRUE(out.prior_mu.defined());
  const CvaeLosses l = computeLosses(out, x, t, v, c);
  // KL(N(mu, s^2) || N(0, 1)) by hand, the prior being N(0, I) at first.
  const torch::Tensor by_hand =
      0.5 * (torch::exp(out.logvar) + out.mu * out.mu - 1.0 - out.logvar).sum(1).mean();
  EXPECT_NEAR(l.mmd.item<double>(), by_hand.item<double>(), 1e-4 * by_hand.item<double>() + 1e-6);
  const double rest = (l.tsdf + l.partial + l.votes).item<double>();
  EXPECT_NEAR(l.total.item<double>(), rest + 2.0 * l.mmd.item<double>(), 1e-3 * rest);
  {
    // Free bits far above the divergence: the term is their floor, the KL still reported.
    CvaeConfig free = c;
    free.kl_free_nats = 1000.0;
    const CvaeLosses f = computeLosses(out, x, t, v, free);
    EXPECT_NEAR(f.mmd.item<double>(), l.mmd.item<double>(), 1e-6);
    EXPECT_NEAR(f.total.item<double>(), rest + 2.0 * 1000.0, 1e-3 * rest);
  }
  torch::optim::SGD opt(model->parameters(), torch::optim::SGDOptions(1e-2));
  l.mmd.backward();
  opt.step();
  {
    torch::NoGradGuard no_grad;
    model->eval();
    // The codes decoded are now the prior's mu(c) + sigma(c) e, not e (an untrained decoder
    // hardly reads its code, so the codes are compared, not the scenes).
    EXPECT_GT((model->generate(x, z).z - z).abs().max().item<float>(), 1e-4);
    EXPECT_TRUE(torch::equal(model->decodeCodes(x, z).z, z));
  }
  // Equal Gaussians: no divergence.
  CvaeOutput same = out;
  same.prior_mu = out.mu.detach();
  same.prior_logvar = out.logvar.detach();
  EXPECT_NEAR(computeLosses(same, x, t, v, c).mmd.item<double>(), 0.0, 1e-5);
  EXPECT_EQ(CvaeConfig::fromYaml(c.toYaml()).prior, "learned");
  c.posterior = "deterministic";
  EXPECT_THROW(c.validate(), std::invalid_argument);
  c = tiny();
  c.prior = "flat";
  EXPECT_THROW(c.validate(), std::invalid_argument);
}

TEST(Cvae, OneSharedConditionEqualsOnePerCode) {
  torch::manual_seed(4);
  Cvae model(tiny());
  model->eval();
  torch::NoGradGuard no_grad;
  const auto partial = torch::rand({1, 2, 16, 16, 16});
  const auto z = torch::randn({3, 8});
  const CvaeOutput shared = model->generate(partial, z);
  const CvaeOutput each = model->generate(partial.expand({3, 2, 16, 16, 16}).contiguous(), z);
  EXPECT_TRUE(torch::allclose(shared.tsdf, each.tsdf, 1e-5, 1e-6));
  EXPECT_TRUE(torch::allclose(shared.votes, each.votes, 1e-5, 1e-6));
  EXPECT_THROW(model->generate(torch::rand({2, 2, 16, 16, 16}), z), std::invalid_argument);
}

// At inference (eval mode, no gradients) the network folds BatchNorm into the convolutions,
// runs the shared condition's half of each decoder convolution once for all codes, and fuses
// the two heads. It must give what the layers give one by one (eval mode with gradients on),
// for every architecture, and again after parameters change in place (the folded weights are
// rebuilt, not reused).
TEST(Cvae, InferenceFastPathEqualsTheLayerByLayerPass) {
  torch::manual_seed(5);
  auto randomiseBatchNorm = [](Cvae& model, double var_scale) {
    torch::NoGradGuard no_grad;
    for (auto& b : model->named_buffers()) {
      if (b.key().find("bn.running_var") != std::string::npos)
        b.value().uniform_(0.5, 2.0).mul_(var_scale);
      if (b.key().find("bn.running_mean") != std::string::npos) b.value().normal_(0.0, 0.3);
    }
    for (auto& p : model->named_parameters()) {
      if (p.key().find("bn.weight") != std::string::npos) p.value().uniform_(0.5, 1.5);
      if (p.key().find("bn.bias") != std::string::npos) p.value().normal_(0.0, 0.2);
    }
  };
  for (const std::string arch : {"cvae", "fc", "fc_plain"}) {
    Cvae model(tiny(arch));
    randomiseBatchNorm(model, 1.0);
    model->eval();
    const auto partial = torch::rand({1, 2, 16, 16, 16}) * 2 - 1;
    const auto z = torch::randn({3, 8});
    auto expectSame = [&](const std::string& when) {
      const CvaeOutput layers = model->generate(partial, z);  // gradients on: no fast path
      CvaeOutput fast;
      {
        torch::NoGradGuard no_grad;
        fast = model->generate(partial, z);
      }
      EXPECT_EQ(fast.tsdf.sizes(), layers.tsdf.sizes()) << arch << when;
      EXPECT_EQ(fast.votes.sizes(), layers.votes.sizes()) << arch << when;
      if (fast.tsdf.sizes() != layers.tsdf.sizes() || fast.votes.sizes() != layers.votes.sizes())
        return layers;
      EXPECT_LT((fast.tsdf - layers.tsdf).abs().max().item<double>(), 1e-5) << arch << when;
      EXPECT_LT((fast.votes - layers.votes).abs().max().item<double>(), 1e-5) << arch << when;
      return layers;
    };
    const CvaeOutput before = expectSame(" fresh");
    randomiseBatchNorm(model, 4.0);
    const CvaeOutput after = expectSame(" after an in-place change");
    // The change matters, so a stale fold would have been caught.
    EXPECT_GT((after.tsdf - before.tsdf).abs().max().item<double>(), 1e-2) << arch;
  }
}

namespace {

// A network of config `from` (seeded), saved to a temporary file, and a network of config `to`
// warm-started from it; both in eval mode. `fresh` lists the tensors the file did not have.
struct WarmStart {
  Cvae source{nullptr}, model{nullptr};
  std::string path;
  std::vector<std::string> fresh;
};
WarmStart warmStart(const CvaeConfig& from, const CvaeConfig& to, const std::string& file,
                    int seed) {
  WarmStart w;
  torch::manual_seed(seed);
  w.source = Cvae(from);
  w.source->eval();
  w.path = tempPath(file);
  saveCvae(w.path, w.source);
  torch::manual_seed(seed + 1);
  w.model = Cvae(to);
  w.model->eval();
  w.fresh = warmStartCvae(w.model, w.path);
  return w;
}

}  // namespace

TEST(Cvae, EveryScaleCodeWarmStartsFromABottleneckModel) {
  // latent_injection "every_scale" adds one projection of z per decoder scale and nothing else:
  // a warm start from a bottleneck model copies every other tensor, and with the projections
  // zeroed the two networks agree; with them the code changes the finest output.
  CvaeConfig c = tiny();
  c.latent_injection = "every_scale";
  WarmStart w = warmStart(tiny(), c, "simstack_warm_source.pt", 6);
  Cvae &source = w.source, &model = w.model;
  const std::string& path = w.path;
  std::vector<std::string> fresh = w.fresh;
  std::sort(fresh.begin(), fresh.end());
  std::vector<std::string> expected;
  for (int i = 0; i <= 4; ++i) {
    expected.push_back("dec_code" + std::to_string(i) + ".bias");
    expected.push_back("dec_code" + std::to_string(i) + ".weight");
  }
  EXPECT_EQ(fresh, expected);
  torch::NoGradGuard no_grad;
  const auto partial = torch::rand({1, 2, 16, 16, 16});
  const auto z = torch::randn({3, 8});
  const torch::Tensor before = model->generate(partial, z).tsdf;
  EXPECT_FALSE(torch::allclose(before, source->generate(partial, z).tsdf, 1e-5, 1e-6));
  for (auto& p : model->named_parameters())
    if (p.key().rfind("dec_code", 0) == 0) p.value().zero_();
  EXPECT_TRUE(torch::allclose(model->generate(partial, z).tsdf, source->generate(partial, z).tsdf,
                              1e-5, 1e-6));
  // The FC baseline has no code, so the setting adds nothing to it.
  CvaeConfig fc = tiny("fc");
  fc.latent_injection = "every_scale";
  EXPECT_EQ(Cvae(fc)->parameters().size(), Cvae(tiny("fc"))->parameters().size());
  // A tensor of the same name with another shape is an error that names the file and tensor.
  CvaeConfig wider = c;
  wider.base_channels = 8;
  wider.max_channels = 32;
  Cvae other(wider);
  try {
    warmStartCvae(other, path);
    ADD_FAILURE() << "a warm start into another shape did not throw";
  } catch (const std::runtime_error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find(path), std::string::npos) << m;
    EXPECT_NE(m.find("shape"), std::string::npos) << m;
  }
  EXPECT_THROW(warmStartCvae(other, "/nonexistent/model.pt"), std::runtime_error);
  c.latent_injection = "everywhere";
  EXPECT_THROW(c.validate(), std::invalid_argument);
  fs::remove(path);
}

TEST(Cvae, ConditionInjectionStartsAsTheFcModelItIsWarmStartedFrom) {
  // latent_injection "condition": the deepest map is fc's (the condition's) plus a projection of
  // z that starts at zero, so a C-VAE warm-started from an fc model decodes that model's scene
  // for every code; once the projection moves, the codes decode different scenes.
  CvaeConfig c = tiny();
  c.latent_injection = "condition";
  WarmStart w = warmStart(tiny("fc"), c, "simstack_warm_fc.pt", 8);
  Cvae &source = w.source, &model = w.model;
  const std::vector<std::string>& fresh = w.fresh;
  // The posterior encoder and the code's projection are new; the decoder and condition are fc's.
  for (const std::string& name : fresh) {
    EXPECT_TRUE(name.rfind("enc_", 0) == 0 || name.rfind("code_fc", 0) == 0) << name;
  }
  EXPECT_NE(std::find(fresh.begin(), fresh.end(), "code_fc2.weight"), fresh.end());
  // The code reaches the decoder through code_fc1/2 alone: no unused map of it is registered.
  for (const auto& p : model->named_parameters())
    EXPECT_NE(p.key().rfind("dec_fc", 0), 0u) << p.key();
  torch::NoGradGuard no_grad;
  const auto partial = torch::rand({1, 2, 16, 16, 16});
  const auto z = torch::randn({3, 8});
  const CvaeOutput fc_out = source->generate(partial, {});
  const torch::Tensor codes = model->generate(partial, z).tsdf;
  for (int i = 0; i < 3; ++i) {
    EXPECT_TRUE(torch::allclose(codes[i], fc_out.tsdf[0], 1e-5, 1e-6)) << "code " << i;
  }
  for (auto& p : model->named_parameters())
    if (p.key().rfind("code_fc2", 0) == 0) p.value().normal_(0.0, 0.5);
  const torch::Tensor moved = model->generate(partial, z).tsdf;
  EXPECT_FALSE(torch::allclose(moved[0], moved[1], 1e-4, 1e-5));
  EXPECT_FALSE(torch::allclose(moved[0], fc_out.tsdf[0], 1e-4, 1e-5));
  // The same code decodes the same scene when the condition is shared or repeated per code.
  const torch::Tensor repeated = model->generate(partial.repeat({3, 1, 1, 1, 1}), z).tsdf;
  EXPECT_TRUE(torch::allclose(repeated, moved, 1e-4, 1e-5));
  fs::remove(w.path);
}

TEST(Cvae, CoarseHiddenConditionHidesTheFineMapsWhereNothingWasSeen) {
  // hidden_condition "coarse": the condition's two finest maps are zero in unobserved voxels
  // (16^3: in cells with no observed voxel) and untouched elsewhere; the coarser maps are the
  // same as with "full", and so is every tensor (a "full" model warm-starts it).
  CvaeConfig c = tiny();
  c.hidden_condition = "coarse";
  torch::manual_seed(8);
  Cvae coarse(c);
  torch::manual_seed(8);
  Cvae full(tiny());
  coarse->eval();
  full->eval();
  EXPECT_EQ(coarse->parameters().size(), full->parameters().size());
  torch::NoGradGuard no_grad;
  torch::Tensor partial = torch::rand({1, 2, 16, 16, 16}) * 2 - 1;
  // Observed: the half x < 8, and one voxel beyond it, at (z, y, x) = (3, 5, 12).
  torch::Tensor observed = torch::zeros({1, 1, 16, 16, 16});
  observed.narrow(4, 0, 8).fill_(1.0);
  observed[0][0][3][5][12] = 1.0;
  partial.narrow(1, 1, 1).copy_(observed);
  const std::vector<torch::Tensor> a = coarse->encodeCondition(partial),
                                   b = full->encodeCondition(partial);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_TRUE(torch::equal(a[0], b[0] * observed));
  EXPECT_EQ(a[0][0].select(3, 12).select(2, 5).select(1, 3).abs().sum().item<double>(),
            b[0][0].select(3, 12).select(2, 5).select(1, 3).abs().sum().item<double>());
  EXPECT_NEAR(a[0].narrow(4, 8, 8).abs().sum().item<double>(),
              a[0][0].select(3, 12).select(2, 5).select(1, 3).abs().sum().item<double>(), 1e-3);
  // The 16^3 map at half size: cells x < 4 and the cell holding (3, 5, 12) stay.
  EXPECT_TRUE(torch::equal(a[1].narrow(4, 0, 4), b[1].narrow(4, 0, 4)));
  EXPECT_TRUE(torch::equal(a[1][0].select(3, 6).select(2, 2).select(1, 1),
                           b[1][0].select(3, 6).select(2, 2).select(1, 1)));
  EXPECT_GT(b[1].narrow(4, 4, 4).abs().sum().item<double>(), 0.0);
  EXPECT_NEAR(a[1].narrow(4, 4, 4).abs().sum().item<double>(),
              a[1][0].select(3, 6).select(2, 2).select(1, 1).abs().sum().item<double>(), 1e-3);
  for (size_t i = 2; i < a.size(); ++i) EXPECT_TRUE(torch::equal(a[i], b[i])) << i;
  c.hidden_condition = "none";
  EXPECT_THROW(c.validate(), std::invalid_argument);
}

TEST(Cvae, SaveLoadGivesIdenticalOutputs) {
  torch::manual_seed(1);
  Cvae model(tiny());
  model->eval();
  const std::string path = tempPath("simstack_test_model.pt");
  saveCvae(path, model, "note: test");
  std::string meta;
  Cvae loaded = loadCvae(path, nullptr, &meta);
  loaded->eval();
  EXPECT_EQ(meta, "note: test");
  torch::NoGradGuard no_grad;
  const auto partial = torch::rand({2, 2, 16, 16, 16});
  const auto z = torch::randn({2, 8});
  EXPECT_TRUE(torch::equal(model->generate(partial, z).tsdf, loaded->generate(partial, z).tsdf));
  // The inference API reads the same file.
  const CvaeInference net(path, 1);
  EXPECT_EQ(net.config().resolution, 16);
  fs::remove(path);
}

namespace {
// The grid's quarter turn about the vertical, written voxel by voxel: (x, y) goes to
// (r - 1 - y, x), a vector (vx, vy) to (-vy, vx); and its mirror in x.
template <class T, class F>
Grid3<T> moved(const Grid3<T>& g, bool mirror, F&& value) {
  const int r = g.spec.resolution;
  Grid3<T> out = g;
  for (int z = 0; z < r; ++z)
    for (int y = 0; y < r; ++y)
      for (int x = 0; x < r; ++x) {
        const T& v = g.at(x, y, z);
        if (mirror)
          out.at(r - 1 - x, y, z) = value(v, true);
        else
          out.at(r - 1 - y, x, z) = value(v, false);
      }
  return out;
}
Grid3<float> moved(const Grid3<float>& g, bool mirror) {
  return moved(g, mirror, [](float v, bool) { return v; });
}
Grid3<Vec3f> moved(const Grid3<Vec3f>& g, bool mirror) {
  return moved(g, mirror, [](const Vec3f& v, bool m) {
    return m ? Vec3f(-v.x(), v.y(), v.z()) : Vec3f(-v.y(), v.x(), v.z());
  });
}
// Largest difference between two sets of hypotheses, TSDF and votes.
double difference(const std::vector<CvaePrediction>& a, const std::vector<CvaePrediction>& b) {
  double worst = 0;
  for (size_t s = 0; s < a.size(); ++s)
    for (size_t i = 0; i < a[s].tsdf_m.data.size(); ++i) {
      worst = std::max(worst, double(std::abs(a[s].tsdf_m.data[i] - b[s].tsdf_m.data[i])));
      worst = std::max(worst, double((a[s].votes.data[i] - b[s].votes.data[i]).norm()));
    }
  return worst;
}
// The hypotheses moved (quarter turn or mirror).
std::vector<CvaePrediction> moved(std::vector<CvaePrediction> p, bool mirror) {
  for (CvaePrediction& h : p) h = {moved(h.tsdf_m, mirror), moved(h.votes, mirror)};
  return p;
}
}  // namespace

TEST(Cvae, SymmetricPassesTurnWithThePile) {
  torch::manual_seed(2);
  Cvae model(tiny());
  model->eval();
  const std::string path = tempPath("simstack_test_symmetries.pt");
  saveCvae(path, model, "");
  const CvaeInference net(path, 1);
  fs::remove(path);
  const GridSpec grid = GridSpec::sceneGrid(Vec2::Zero(), net.config().extent_m, 16);
  Grid3<float> tsdf(grid, 0.0f), weight(grid, 0.0f);
  std::mt19937 rng(4);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (size_t i = 0; i < tsdf.data.size(); ++i) {
    tsdf.data[i] = 0.03f * u(rng);
    weight.data[i] = u(rng) > 0 ? 1.0f : 0.0f;
  }
  auto error = [&](int symmetries, bool mirror) {
    const auto a = net.predict(tsdf, weight, 2, 9, false, symmetries);
    const auto b = net.predict(moved(tsdf, mirror), moved(weight, mirror), 2, 9, false, symmetries);
    return difference(moved(a, mirror), b);
  };
  // One pass of a random network does not turn with the pile; four turned passes do, and all
  // eight also mirror with it.
  EXPECT_GT(error(1, false), 1e-3);
  EXPECT_LT(error(4, false), 1e-5);
  EXPECT_GT(error(4, true), 1e-3);
  EXPECT_LT(error(8, false), 1e-5);
  EXPECT_LT(error(8, true), 1e-5);
  EXPECT_THROW(net.predict(tsdf, weight, 1, 0, false, 3), std::invalid_argument);
  // Two passes (the half turn) turn with a half-turned pile.
  auto half = [](const auto& g) { return moved(moved(g, false), false); };
  const auto a = net.predict(tsdf, weight, 2, 9, false, 2);
  const auto b = net.predict(half(tsdf), half(weight), 2, 9, false, 2);
  EXPECT_LT(difference(half(a), b), 1e-5);
  // Code fitting without fit_on_passes: the codes are fitted on the plain pass (the same
  // losses either way), and the kept codes decoded with the passes (as predict() decodes them).
  const std::vector<ViewEvidence> views = {{tsdf, weight}};
  RefineOptions plain_one{3, 0.3, 1}, plain_four{3, 0.3, 4};
  plain_one.fit_on_passes = plain_four.fit_on_passes = false;
  RefineReport one_report, four_report;
  const auto one = net.refine(tsdf, weight, views, 2, 9, false, plain_one, &one_report);
  const auto four = net.refine(tsdf, weight, views, 2, 9, false, plain_four, &four_report);
  EXPECT_EQ(one_report.code_loss, four_report.code_loss);
  EXPECT_GT(difference(one, four), 1e-3);
}

TEST(Cvae, BadModelFilesGiveClearErrors) {
  auto message = [](const std::string& path, const CvaeConfig* expect) {
    try {
      loadCvae(path, expect);
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message("/nonexistent/model.pt", nullptr).find("/nonexistent/model.pt"),
            std::string::npos);
  const std::string corrupt = tempPath("simstack_corrupt.pt");
  std::ofstream(corrupt) << "definitely not a model";
  const std::string m = message(corrupt, nullptr);
  EXPECT_NE(m.find(corrupt), std::string::npos) << m;
  fs::remove(corrupt);
  Cvae model(tiny());
  const std::string path = tempPath("simstack_mismatch.pt");
  saveCvae(path, model);
  CvaeConfig expect = tiny();
  expect.resolution = 32;
  const std::string mm = message(path, &expect);
  EXPECT_NE(mm.find("resolution"), std::string::npos) << mm;
  EXPECT_NE(mm.find(path), std::string::npos) << mm;
  EXPECT_THROW(CvaeInference("/nonexistent/model.pt"), std::runtime_error);

  // Weights of a 16-dimensional code under a config that says 8: the file names the tensor.
  torch::serialize::InputArchive saved;
  saved.load_from(path);
  torch::IValue format, yaml;
  ASSERT_TRUE(saved.try_read("simstack_format", format));
  ASSERT_TRUE(saved.try_read("simstack_config", yaml));
  CvaeConfig wide = tiny();
  wide.latent_size = 16;
  Cvae other(wide);
  torch::serialize::OutputArchive forged;
  other->save(forged);
  forged.write("simstack_format", format);
  forged.write("simstack_config", yaml);
  const std::string shapes = tempPath("simstack_shapes.pt");
  forged.save_to(shapes);
  const std::string ms = message(shapes, nullptr);
  EXPECT_NE(ms.find(shapes), std::string::npos) << ms;
  EXPECT_NE(ms.find("shape"), std::string::npos) << ms;
  EXPECT_NE(ms.find("tensor "), std::string::npos) << ms;  // it names the tensor
  fs::remove(shapes);
  // The archive's values of another type (the format as text): refused by name, not a
  // libtorch error.
  torch::serialize::OutputArchive typed;
  model->save(typed);
  typed.write("simstack_format", torch::IValue(std::string("1")));
  typed.write("simstack_config", yaml);
  const std::string texts = tempPath("simstack_types.pt");
  typed.save_to(texts);
  const std::string mt = message(texts, nullptr);
  EXPECT_NE(mt.find("simstack_format is not an integer"), std::string::npos) << mt;
  fs::remove(texts);
  fs::remove(path);
}

TEST(Cvae, DamagedModelFilesAreRefusedByTheCheckThatFails) {
  auto message = [](const std::string& path) {
    try {
      loadCvae(path);
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  // Its largest tensor all NaN (no card: only the weights' own check can tell).
  Cvae model(tiny());
  torch::Tensor largest;
  for (const auto& p : model->named_parameters())
    if (!largest.defined() || p.value().numel() > largest.numel()) largest = p.value();
  {
    torch::NoGradGuard no_grad;
    largest.fill_(std::numeric_limits<float>::quiet_NaN());
  }
  const std::string nan = tempPath("simstack_nan.pt");
  saveCvae(nan, model);
  const std::string mn = message(nan);
  EXPECT_NE(mn.find(nan), std::string::npos) << mn;
  EXPECT_NE(mn.find("not finite"), std::string::npos) << mn;
  fs::remove(nan);
  // A good file and its card, then one byte of the file flipped: the card's SHA-256 catches it.
  Cvae good(tiny());
  const std::string path = tempPath("simstack_flipped.pt");
  saveCvae(path, good);
  ModelIntegrity m;
  m.sha256 = sha256OfFile(path);
  m.format_version = modelFormatVersion();
  writeModelIntegrity(path, m);
  EXPECT_EQ(message(path), "no error");
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(static_cast<std::streamoff>(fs::file_size(path) / 2));
    const char c = static_cast<char>(f.peek());
    f.seekp(static_cast<std::streamoff>(fs::file_size(path) / 2));
    f.put(static_cast<char>(~c));
  }
  const std::string mf = message(path);
  EXPECT_NE(mf.find(path), std::string::npos) << mf;
  EXPECT_NE(mf.find("SHA-256"), std::string::npos) << mf;
  // A card of another format version.
  m.sha256 = sha256OfFile(path);
  m.format_version = modelFormatVersion() + 1;
  writeModelIntegrity(path, m);
  EXPECT_NE(message(path).find("format"), std::string::npos) << message(path);
  // A card that names its version by the field's former name is told how to restamp it.
  std::ofstream(modelCardPath(path)) << "integrity:\n  sha256: " << m.sha256 << "\n  format: 1\n";
  EXPECT_NE(message(path).find("simstack_check_model --stamp"), std::string::npos) << message(path);
  fs::remove(path);
  fs::remove(modelCardPath(path));
}

// A file that is no model is not stamped: its card stays as it was, or is not created.
TEST(ModelIntegrity, StampingADamagedFileLeavesTheCardAlone) {
  const std::string path = tempPath("simstack_not_a_model.pt");
  std::ofstream(path) << "not a model\n";
  fs::remove(modelCardPath(path));
  EXPECT_THROW(stampModel(path), std::runtime_error);
  EXPECT_FALSE(fs::exists(modelCardPath(path)));
  const std::string card = "perception:\n  samples: 3  # the user's card\n";
  std::ofstream(modelCardPath(path)) << card;
  EXPECT_THROW(stampModel(path), std::runtime_error);
  std::ifstream in(modelCardPath(path));
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()),
            card);
  fs::remove(path);
  fs::remove(modelCardPath(path));
}

// A model of a 0.32 m grid (`simstack_generate --extent 0.32`, then training) proves itself
// like the shipped ones: its self-test is one box in one tile, whatever the tile overlap a
// 0.64 m grid takes; the network sees it in 1 cm voxels.
TEST(ModelIntegrity, AModelOfASmallerGridIsStampedAndChecked) {
  const std::string shipped = std::string(SIMSTACK_SOURCE_DIR) + "/models/simstack_r32_fc.pt";
  CvaeConfig c = loadCvae(shipped)->config();
  c.extent_m = 0.32;
  Cvae small(c);
  EXPECT_TRUE(warmStartCvae(small, shipped).empty()) << "the same network, every tensor";
  const std::string path = tempPath("simstack_small_grid.pt");
  fs::remove(modelCardPath(path));
  saveCvae(path, small);
  const ModelIntegrity m = stampModel(path);
  EXPECT_EQ(m.self_test_objects, 1) << "the rendered box is one object";
  EXPECT_EQ(checkModel(path).objects, 1);
  fs::remove(path);
  fs::remove(modelCardPath(path));
}

TEST(Cvae, TinyModelOverfitsOneScene) {
  torch::manual_seed(5);
  CvaeConfig c = tiny();
  c.delta = 1.0;
  const Scene scene = test::sphereScene(0.1, Vec3(0, 0, 0.1));
  const GridSpec grid = GridSpec::sceneGrid(Vec2::Zero(), c.extent_m, c.resolution);
  const GroundTruthGrids gt = computeGroundTruth(scene, grid, c.truncation_m());
  const PinholeCamera camera = scaledKinect(160, 120);
  const Transform T = lookAt(Vec3(0.6, -0.3, 0.5), Vec3(0, 0, 0.1));
  ProjectiveTsdfConfig tc;
  tc.truncation_m = c.truncation_m();
  ProjectiveTsdf partial(grid, tc);
  partial.integrate(DepthRenderer(scene).render(camera, T).depth, camera, T);
  const std::vector<float> in = partialChannels(partial.tsdf(), partial.weight(), c.truncation_m());
  const int n = grid.voxelCount();
  auto p = torch::from_blob(const_cast<float*>(in.data()), {1, 2, 16, 16, 16})
               .clone()
               .repeat({2, 1, 1, 1, 1});
  auto t = torch::empty({1, 1, 16, 16, 16});
  auto v = torch::empty({1, 3, 16, 16, 16});
  for (int i = 0; i < n; ++i) {
    t.data_ptr<float>()[i] = gt.tsdf.data[i] / static_cast<float>(c.truncation_m());
    for (int k = 0; k < 3; ++k) v.data_ptr<float>()[k * n + i] = gt.votes.data[i][k];
  }
  t = t.repeat({2, 1, 1, 1, 1});
  v = v.repeat({2, 1, 1, 1, 1});
  Cvae model(c);
  torch::optim::Adam opt(model->parameters(), torch::optim::AdamOptions(3e-3));
  double first = 0, last = 0, last_votes = 0;
  const auto start = std::chrono::steady_clock::now();
  for (int step = 0; step < 300; ++step) {
    opt.zero_grad();
    const CvaeLosses l = computeLosses(model->forward(p, t, v), p, t, v, c);
    l.total.backward();
    opt.step();
    const double fit = (l.tsdf + l.votes).item<double>();
    if (step == 0) first = fit;
    last = fit;
    last_votes = l.votes.item<double>();
  }
  int inside = 0;
  for (int i = 0; i < n; ++i) inside += gt.votes.data[i].squaredNorm() > 0.25f;
  std::cout << "overfit: tsdf + votes loss " << first << " -> " << last << " in 300 steps, "
            << std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count()
            << " s; vote loss " << last_votes << " over " << inside << " object voxels\n";
  EXPECT_LT(last, first / 10.0);
  // The votes are learned, not collapsed to zero (which would cost 1 per object voxel).
  EXPECT_LT(last_votes, 0.5 * inside);
}

std::string shippedModel() { return std::string(SIMSTACK_SOURCE_DIR) + "/models/simstack_r32.pt"; }

// Latent optimisation (the paper's section 4.2) on the shipped model: a generated pile seen
// first from one side, then from more; the codes are fitted to the further views' TSDFs.
struct PileViews {
  const CvaeInference& net;
  Scene scene = PileGenerator(PileConfig()).generate(11).scene;
  Vec3 centre = scene.surfaceCentroid();
  GridSpec grid = GridSpec::sceneGrid(centre.head<2>(), 0.64, 32);
  PinholeCamera camera = scaledKinect(320, 240);

  Transform pose(double azimuth) const {
    return lookAt(centre + Vec3(0.7 * std::cos(azimuth), 0.7 * std::sin(azimuth), 0.45), centre);
  }
  /// The partial TSDF of the views from these azimuths, fused.
  ViewEvidence seenFrom(const std::vector<double>& azimuths) const {
    ProjectiveTsdfConfig tc;
    tc.truncation_m = net.config().truncation_m();
    ProjectiveTsdf partial(grid, tc);
    for (double a : azimuths)
      partial.integrate(DepthRenderer(scene).render(camera, pose(a)).depth, camera, pose(a));
    return ViewEvidence{partial.tsdf(), partial.weight()};
  }
  /// The two views the latent-optimisation tests fit to, after the first from azimuth 0.
  std::vector<ViewEvidence> twoFurther() const { return {seenFrom({2.1}), seenFrom({4.2})}; }
  double iou(const std::vector<CvaePrediction>& preds) const {
    const GroundTruthGrids gt = computeGroundTruth(scene, grid, net.config().truncation_m());
    std::vector<std::vector<float>> p;
    for (const CvaePrediction& x : preds) p.push_back(x.tsdf_m.data);
    return scoreOccupancy(gt.tsdf.data, p).iou;
  }
};

/// Share of the voxels occupied in some hypothesis that are not occupied in all.
double disagreement(const std::vector<CvaePrediction>& preds) {
  int some = 0, split = 0;
  for (size_t i = 0; i < preds.front().tsdf_m.data.size(); ++i) {
    int n = 0;
    for (const CvaePrediction& p : preds) n += p.tsdf_m.data[i] <= 0.0f;
    some += n > 0;
    split += n > 0 && n < static_cast<int>(preds.size());
  }
  return some > 0 ? static_cast<double>(split) / some : 0.0;
}

TEST(ShippedModel, LatentOptimisationLowersItsLossOnFurtherViews) {
  ASSERT_TRUE(fs::exists(shippedModel())) << shippedModel();
  const CvaeInference net(shippedModel(), 2);
  const PileViews pile{net};
  const ViewEvidence first = pile.seenFrom({0.0});
  const std::vector<ViewEvidence> further = pile.twoFurther();
  RefineReport report;
  const auto preds =
      net.refine(first.tsdf_m, first.weight, further, 3, 5, false, RefineOptions{8, 0.3}, &report);
  ASSERT_EQ(preds.size(), 3u);
  ASSERT_EQ(report.loss.size(), 9u);  // before the first step, then after each
  std::cout << "latent optimisation: loss " << report.loss.front() << " -> " << report.loss.back()
            << " in 8 steps, " << report.ms << " ms\n";
  EXPECT_LT(report.loss.back(), report.loss.front());
  for (size_t i = 1; i < report.loss.size(); ++i) EXPECT_LE(report.loss[i], report.loss[i - 1]);
  // No iterations: predict()'s hypotheses; a view on another grid is refused.
  const auto same = net.refine(first.tsdf_m, first.weight, further, 3, 5, false, {0, 0.3});
  EXPECT_EQ(same[0].tsdf_m.data, net.predict(first.tsdf_m, first.weight, 3, 5)[0].tsdf_m.data);
  const GridSpec other = GridSpec::sceneGrid(Vec2(0.1, 0.0), 0.64, 32);
  EXPECT_THROW(net.refine(first.tsdf_m, first.weight,
                          {ViewEvidence{Grid3<float>(other, 0.f), Grid3<float>(other, 0.f)}}, 3, 5,
                          false, {4, 0.3}),
               std::invalid_argument);
}

TEST(ShippedModel, LatentOptimisationStartsFromTheDrawsThatFitTheViewsBest) {
  ASSERT_TRUE(fs::exists(shippedModel())) << shippedModel();
  const CvaeInference net(shippedModel(), 2);
  const PileViews pile{net};
  const ViewEvidence first = pile.seenFrom({0.0});
  const std::vector<ViewEvidence> further = pile.twoFurther();
  // 12 prior draws scored, no step taken: the 3 kept are the 3 that fit the views best.
  RefineOptions choose{0, 0.3};
  choose.starts = 12;
  RefineReport report;
  net.refine(first.tsdf_m, first.weight, further, 3, 5, false, choose, &report);
  ASSERT_EQ(report.start_loss.size(), 12u);
  ASSERT_EQ(report.code_loss.size(), 3u);
  std::vector<double> drawn = report.start_loss;
  std::sort(drawn.begin(), drawn.end());
  EXPECT_GT(drawn.back(), drawn.front());  // the draws differ, so choosing means something
  for (size_t k = 0; k < 3; ++k)           // best first
    EXPECT_NEAR(report.code_loss[k], drawn[k], 1e-4 * drawn[k]) << k;
  // Sign evidence scores only disagreement on occupancy: a view whose distances are half the
  // mean scene's, with its signs, costs that scene nothing, while the distances' terms do.
  CvaePrediction mean_scene = net.predict(first.tsdf_m, first.weight, 1, 5, true)[0];
  ViewEvidence halved{mean_scene.tsdf_m, Grid3<float>(mean_scene.tsdf_m.spec, 1.0f)};
  for (float& t : halved.tsdf_m.data) t *= 0.5f;
  RefineOptions one_step{1, 0.3};
  one_step.evidence = "sign";
  net.refine(first.tsdf_m, first.weight, {halved}, 1, 5, true, one_step, &report);
  EXPECT_EQ(report.loss.front(), 0.0);
  one_step.evidence = "tsdf";
  net.refine(first.tsdf_m, first.weight, {halved}, 1, 5, true, one_step, &report);
  EXPECT_GT(report.loss.front(), 10.0);
  one_step.evidence = "depth";
  EXPECT_THROW(net.refine(first.tsdf_m, first.weight, {halved}, 1, 5, true, one_step),
               std::invalid_argument);
  // A prior that outweighs the evidence keeps the mean scene's code where it is.
  RefineOptions anchored{4, 0.3};
  anchored.prior_weight = 1e6;
  const auto held = net.refine(first.tsdf_m, first.weight, further, 3, 5, true, anchored);
  for (size_t i = 0; i < held[0].tsdf_m.data.size(); ++i)
    ASSERT_NEAR(held[0].tsdf_m.data[i], mean_scene.tsdf_m.data[i], 1e-5) << i;
  anchored.prior_weight = -1;
  EXPECT_THROW(net.refine(first.tsdf_m, first.weight, further, 3, 5, true, anchored),
               std::invalid_argument);
}

/// refine()'s sign evidence of one hypothesis: over the views, the mean of the sum over each
/// view's observed voxels of max(0, -tsdf * view tsdf), both in tau (the view's clamped).
double signEvidence(const CvaePrediction& p, const std::vector<ViewEvidence>& views, double tau) {
  double sum = 0;
  for (const ViewEvidence& v : views)
    for (size_t i = 0; i < p.tsdf_m.data.size(); ++i) {
      if (!(v.weight.data[i] > 0)) continue;
      const double seen = std::clamp(v.tsdf_m.data[i] / tau, -1.0, 1.0);
      sum += std::max(0.0, -(p.tsdf_m.data[i] / tau) * seen);
    }
  return sum / views.size();
}

TEST(ShippedModel, CodesFittedOnTheSymmetricPassesScoreAsTheyAreDecoded) {
  ASSERT_TRUE(fs::exists(shippedModel())) << shippedModel();
  const CvaeInference net(shippedModel(), 2);
  const PileViews pile{net};
  const ViewEvidence first = pile.seenFrom({0.0});
  const std::vector<ViewEvidence> further = pile.twoFurther();
  RefineOptions options{2, 0.3, 4};
  options.fit_on_passes = true;
  RefineReport report;
  const auto fitted =
      net.refine(first.tsdf_m, first.weight, further, 2, 5, false, options, &report);
  const double tau = net.config().truncation_m();
  for (size_t k = 0; k < fitted.size(); ++k) {
    const double loss = signEvidence(fitted[k], further, tau);
    EXPECT_GT(loss, 0.0) << k;
    EXPECT_NEAR(loss, report.code_loss[k], 1e-3 * loss) << k;
  }
}

TEST(ShippedModel, APileSeenFromAllSidesIsReconstructedBetterAndAgreedOn) {
  ASSERT_TRUE(fs::exists(shippedModel())) << shippedModel();
  const CvaeInference net(shippedModel(), 2);
  const PileViews pile{net};
  const ViewEvidence one = pile.seenFrom({0.0});
  std::vector<double> around;
  std::vector<ViewEvidence> each;
  for (int k = 0; k < 6; ++k) {
    around.push_back(k * M_PI / 3.0);
    each.push_back(pile.seenFrom({around.back()}));
  }
  const ViewEvidence all = pile.seenFrom(around);
  const auto alone = net.predict(one.tsdf_m, one.weight, 8, 3);
  const auto conditioned = net.predict(all.tsdf_m, all.weight, 8, 3);
  const auto refined = net.refine(all.tsdf_m, all.weight, each, 8, 3, false, {6, 0.3});
  const double iou_one = pile.iou(alone), iou_all = pile.iou(conditioned),
               iou_refined = pile.iou(refined);
  std::cout << "IoU: one view " << iou_one << ", six views " << iou_all << ", six views refined "
            << iou_refined << "; hypotheses disagree on " << 100 * disagreement(alone)
            << " % (one view) and " << 100 * disagreement(conditioned) << " % (six views)\n";
  EXPECT_GT(iou_all, iou_one + 0.05);
  EXPECT_GT(iou_refined, iou_one + 0.05);
  // What the views leave open is where hypotheses differ: less of it seen from all sides.
  EXPECT_LT(disagreement(conditioned), disagreement(alone));
}

TEST(ShippedModel, LoadsAndPredictsThreeSamplesInOnePass) {
  ASSERT_TRUE(fs::exists(shippedModel())) << shippedModel();
  const CvaeInference net(shippedModel(), 2);
  EXPECT_EQ(net.config().resolution, 32);
  EXPECT_EQ(net.config().architecture, "cvae");
  EXPECT_NE(net.metadata().find("dataset_seed"), std::string::npos);
  const Scene scene = test::sphereScene(0.08, Vec3(0, 0, 0.08));
  const GridSpec grid = GridSpec::sceneGrid(Vec2::Zero(), 0.64, 32);
  const PinholeCamera camera = scaledKinect(320, 240);
  const Transform T = lookAt(Vec3(0.6, -0.2, 0.5), Vec3(0, 0, 0.08));
  ProjectiveTsdfConfig tc;
  tc.truncation_m = net.config().truncation_m();
  ProjectiveTsdf partial(grid, tc);
  partial.integrate(DepthRenderer(scene).render(camera, T).depth, camera, T);
  const auto preds = net.predict(partial.tsdf(), partial.weight(), 3, 11, true);
  ASSERT_EQ(preds.size(), 3u);
  for (const auto& p : preds) {
    for (float v : p.tsdf_m.data) ASSERT_TRUE(std::isfinite(v));
  }
  // The sphere's centre is seen as solid; far empty space stays free.
  const Vec3i c = grid.voxelIndex(Vec3(0, 0, 0.08));
  EXPECT_LT(preds[0].tsdf_m.at(c.x(), c.y(), c.z()), 0.0f);
  const Vec3i far = grid.voxelIndex(Vec3(0.25, 0.25, 0.5));
  EXPECT_GT(preds[0].tsdf_m.at(far.x(), far.y(), far.z()), 0.0f);
  // A grid of another resolution is refused with the reason.
  const GridSpec small = GridSpec::sceneGrid(Vec2::Zero(), 0.64, 16);
  EXPECT_THROW(net.predict(Grid3<float>(small, 0.0f), Grid3<float>(small, 0.0f), 1),
               std::invalid_argument);
}

TEST(CvaeConfig, RoundTripsThroughYaml) {
  CvaeConfig c = tiny();
  c.mmd_kernel_widths = {0.2, 1.0, 5.0};
  c.vote_loss = "all";
  c.condition_dropout = 0.25;
  c.latent_injection = "every_scale";
  c.occupancy_weight = 0.5;
  c.occupancy_sharpness = 4.0;
  c.iou_weight = 300.0;
  EXPECT_EQ(CvaeConfig::fromYaml(c.toYaml()).toYaml(), c.toYaml());
  EXPECT_EQ(CvaeConfig::fromYaml(c.toYaml()).iou_weight, 300.0);
  EXPECT_EQ(CvaeConfig::fromYaml(c.toYaml()).occupancy_sharpness, 4.0);
  TrainConfig t;
  t.init_from = "models/some model.pt";
  EXPECT_EQ(TrainConfig::fromYaml(t.toYaml()).init_from, t.init_from);
  t.sensor_model = "realsense";
  EXPECT_EQ(TrainConfig::fromYaml(t.toYaml()).sensor_model, "realsense");
  EXPECT_NO_THROW(t.validate());
  t.sensor_model = "kinect2";
  EXPECT_THROW(t.validate(), std::invalid_argument);
  // Fields absent keep their defaults (model files older than a field).
  EXPECT_EQ(CvaeConfig::fromYaml("resolution: 16").mmd_kernel_widths, std::vector<double>{1.0});
  EXPECT_THROW(CvaeConfig::fromYaml("mmd_kernel_widths: []"), std::invalid_argument);
  EXPECT_THROW(CvaeConfig::fromYaml("mmd_kernel_widths: 2"), std::invalid_argument);
  EXPECT_THROW(CvaeConfig::fromYaml("occupancy_weight: -1"), std::invalid_argument);
  EXPECT_THROW(CvaeConfig::fromYaml("occupancy_sharpness: 0"), std::invalid_argument);
  EXPECT_THROW(CvaeConfig::fromYaml("iou_weight: -1"), std::invalid_argument);
}

TEST(CvaeConfig, TrainingFilesRejectMisspeltFieldsAndNameThem) {
  const std::string dir = testing::TempDir() + "/train_yaml";
  fs::create_directories(dir);
  // The shipped configs load with their own values, not the defaults.
  for (const auto& [shipped, resolution, steps] :
       {std::tuple<const char*, int, int64_t>{"config/train_r32.yaml", 32, 6000},
        std::tuple<const char*, int, int64_t>{"config/train_r64_gpu.yaml", 64, 100000}}) {
    CvaeConfig model;
    TrainConfig training;
    ASSERT_NO_THROW(
        loadTrainingYaml(std::string(SIMSTACK_SOURCE_DIR) + "/" + shipped, &model, &training))
        << shipped;
    EXPECT_EQ(model.resolution, resolution) << shipped;
    EXPECT_EQ(training.steps, steps) << shipped;
  }
  const auto expectError = [&](const std::string& text, const std::string& words) {
    const std::string path = dir + "/bad.yaml";
    std::ofstream(path) << text;
    CvaeConfig model;
    TrainConfig training;
    try {
      loadTrainingYaml(path, &model, &training);
      ADD_FAILURE() << "accepted: " << text;
    } catch (const std::runtime_error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(path), std::string::npos) << what;
      EXPECT_NE(what.find(words), std::string::npos) << what;
    }
  };
  expectError("model:\n  latnet_size: 8\n", "unknown field model.latnet_size");
  expectError("training:\n  lerning_rate: 0.1\n", "unknown field training.lerning_rate");
  expectError("trainig:\n  steps: 3\n", "unknown section 'trainig'");
  expectError("training: 3\n", "'training' must be a map");
  // Dropped variants' settings stand under experimental: and are refused elsewhere.
  expectError("model:\n  prior: learned\n", "write it under model.experimental");
  expectError("training:\n  overhead_share: 0.5\n", "under training.experimental");
  expectError("model:\n  experimental:\n    prior_kind: learned\n",
              "unknown field model.experimental.prior_kind");
  expectError("model:\n  experimental:\n    latent_size: 8\n",
              "unknown field model.experimental.latent_size");
  expectError("model:\n  experimental:\n    kl_free_nats: abc\n", "line 3,");  // the file's line
  expectError("model:\n  experimental:\n    kl_free_nats: abc\n",
              "field 'model.experimental.kl_free_nats'");
  const std::string path = dir + "/experimental.yaml";
  std::ofstream(path) << "model:\n  latent_size: 8\n  experimental:\n    prior: learned\n"
                         "    kl_free_nats: 4\ntraining:\n  experimental:\n"
                         "    overhead_share: 0.5\n";
  CvaeConfig model;
  TrainConfig training;
  ASSERT_NO_THROW(loadTrainingYaml(path, &model, &training));
  EXPECT_EQ(model.latent_size, 8);
  EXPECT_EQ(model.prior, "learned");
  EXPECT_DOUBLE_EQ(model.kl_free_nats, 4.0);
  EXPECT_DOUBLE_EQ(training.overhead_share, 0.5);
  // A model file stores every field flat; it reads back whole.
  EXPECT_EQ(CvaeConfig::fromYaml(model.toYaml()).prior, "learned");
}
