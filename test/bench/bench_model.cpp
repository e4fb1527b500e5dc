// Inference latency (1 and 3 samples, R = 32 and 64) and training throughput of the C-VAE.
#include <benchmark/benchmark.h>

#include "simstack/model/cpu_allocator.h"
#include "simstack/model/cvae.h"

using namespace simstack;

namespace {
CvaeConfig configFor(int r) {
  CvaeConfig c;
  c.resolution = r;
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
