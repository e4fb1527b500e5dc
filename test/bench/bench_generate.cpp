// Piles per second including ground truth (the dataset generator's inner loop), and its parts.
#include <benchmark/benchmark.h>
#include <omp.h>

#include <atomic>

#include "simstack/render/depth_renderer.h"
#include "simstack/scene/pile_generator.h"
#include "simstack/tsdf/ground_truth.h"

using namespace simstack;

static void BM_PileWithGroundTruth(benchmark::State& state) {
  static std::atomic<uint64_t> seed{1000};
  omp_set_num_threads(1);  // parallel across piles, as simstack_generate runs
  const PileGenerator gen{PileConfig()};
  for (auto _ : state) {
    const Scene scene = gen.generate(seed++).scene;
    const GridSpec grid = GridSpec::sceneGrid(scene.surfaceCentroid().head<2>(), 0.64,
                                              static_cast<int>(state.range(0)));
    benchmark::DoNotOptimize(
        computeGroundTruth(scene, grid, 3 * grid.voxel_size_m).tsdf.data.data());
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_PileWithGroundTruth)
    ->Arg(32)
    ->Threads(1)
    ->Threads(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(5.0);

static void BM_GroundTruth(benchmark::State& state) {
  omp_set_num_threads(1);
  const Scene scene = PileGenerator(PileConfig()).generate(7).scene;
  const GridSpec grid = GridSpec::sceneGrid(scene.surfaceCentroid().head<2>(), 0.64,
                                            static_cast<int>(state.range(0)));
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        computeGroundTruth(scene, grid, 3 * grid.voxel_size_m).tsdf.data.data());
  }
}
BENCHMARK(BM_GroundTruth)->Arg(32)->Arg(64)->Unit(benchmark::kMillisecond)->UseRealTime();

static void BM_RenderView640x480(benchmark::State& state) {
  omp_set_num_threads(static_cast<int>(state.range(0)));
  const Scene scene = PileGenerator(PileConfig()).generate(7).scene;
  const DepthRenderer renderer(scene);
  const Vec3 c = scene.surfaceCentroid();
  const Transform T = lookAt(c + Vec3(0.6, 0.3, 0.5), c);
  for (auto _ : state)
    benchmark::DoNotOptimize(renderer.render(PinholeCamera(), T).depth.pixels.data());
}
BENCHMARK(BM_RenderView640x480)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK_MAIN();
