// Inference latency (1 and 3 samples, R = 32 and 64), latent optimisation against further
// views, and training throughput of the C-VAE.
#include <benchmark/benchmark.h>

#include <filesystem>

#include "simstack/model/cpu_allocator.h"
#include "simstack/model/cvae.h"
#include "simstack/model/cvae_inference.h"
#include "simstack/offline/training/cvae_losses.h"
#include "simstack/offline/training/model_writer.h"

using namespace simstack;

namespace {
// The network's sizes (random weights: the time does not depend on them). R = 32: the shipped
// C-VAE's (models/simstack_r32.yaml: the library's default widths, the code added to the
// condition's deepest map); R = 64: config/train_r64_gpu.yaml's, the paper's resolution.
CvaeConfig configFor(int r) {
  CvaeConfig c;
  c.resolution = r;
  if (r == 32) c.latent_injection = "condition";
  if (r == 64) {
    c.base_channels = 16;
    c.max_channels = 128;
    c.hidden_size = 256;
  }
  return c;
}
}  // namespace

static void BM_CvaeInference(benchmark::State& state) {
  const int r = static_cast<int>(state.range(0));
  const int samples = static_cast<int>(state.range(1));
  torch::set_num_threads(2);
  Cvae model(configFor(r));
  model->eval();
  torch::NoGradGuard no_grad;
  const auto partial = torch::rand({1, 2, r, r, r});  // one frame, S codes
  const auto z = torch::randn({samples, 96});
  for (auto _ : state) benchmark::DoNotOptimize(model->generate(partial, z).tsdf.data_ptr<float>());
}
BENCHMARK(BM_CvaeInference)
    ->Args({32, 1})
    ->Args({32, 3})
    ->Args({64, 1})
    ->Args({64, 3})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// The paper's section 4.2 at R = 32: S = 3 codes, 10 Adam steps against 3 views' partial TSDFs
// (a network of the shipped size with random weights: the time does not depend on them);
// the second argument: prior draws scored first, the best 3 kept (RefineOptions::starts); the
// third: symmetric passes, the codes fitted on their average.
static void BM_RefineThreeViews(benchmark::State& state) {
  const int r = 32, iterations = static_cast<int>(state.range(0));
  RefineOptions options{iterations, 0.3, static_cast<int>(state.range(2))};
  options.starts = static_cast<int>(state.range(1));
  const std::string path =
      (std::filesystem::temp_directory_path() / "simstack_bench_refine.pt").string();
  {
    Cvae model(configFor(r));
    saveCvae(path, model);
  }
  const CvaeInference net(path, 2);
  std::filesystem::remove(path);
  const GridSpec grid = GridSpec::sceneGrid(Vec2::Zero(), 0.64, r);
  torch::manual_seed(3);
  auto randomGrid = [&](float lo, float hi) {
    Grid3<float> g(grid, 0.0f);
    const torch::Tensor t = torch::rand({grid.voxelCount()}) * (hi - lo) + lo;
    std::copy(t.data_ptr<float>(), t.data_ptr<float>() + grid.voxelCount(), g.data.begin());
    return g;
  };
  std::vector<ViewEvidence> views;
  for (int k = 0; k < 3; ++k) views.push_back({randomGrid(-0.06f, 0.06f), randomGrid(-1.0f, 1.0f)});
  for (auto _ : state)
    benchmark::DoNotOptimize(
        net.refine(views[0].tsdf_m, views[0].weight, views, 3, 1, false, options));
}
BENCHMARK(BM_RefineThreeViews)
    ->ArgNames({"steps", "starts", "passes"})
    ->Args({0, 0, 1})
    ->Args({10, 0, 1})
    ->Args({0, 24, 1})
    ->Args({10, 24, 1})
    ->Args({10, 0, 4})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

static void BM_CvaeTrainingStep(benchmark::State& state) {
  const int r = 32, b = 8;
  torch::set_num_threads(2);
  Cvae model(configFor(r));
  torch::optim::Adam opt(model->parameters());
  const auto partial = torch::rand({b, 2, r, r, r});
  const auto tsdf = torch::rand({b, 1, r, r, r});
  const auto votes = torch::rand({b, 3, r, r, r});
  for (auto _ : state) {
    opt.zero_grad();
    const auto l =
        computeLosses(model->forward(partial, tsdf, votes), partial, tsdf, votes, model->config());
    l.total.backward();
    opt.step();
  }
  state.SetItemsProcessed(state.iterations() * b);
}
BENCHMARK(BM_CvaeTrainingStep)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(5.0);

int main(int argc, char** argv) {
  keepFreedMemoryForReuse();
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  return 0;
}
