// Piles per second including ground truth (the dataset generator's inner loop), and its parts.
#include <benchmark/benchmark.h>
#include <omp.h>

#include "simstack/render/depth_renderer.h"
#include "simstack/scene/pile_generator.h"
#include "simstack/tsdf/ground_truth.h"

using namespace simstack;

// The same 60 piles (seeds 1000..1059) for every thread count, split across the threads: the
// cost of a pile varies several-fold with how many drops it needs, so runs over different
// seeds are not comparable.
static void BM_PileWithGroundTruth(benchmark::State& state) {
  omp_set_num_threads(1);  // parallel across piles, as simstack_generate runs
  const int resolution = static_cast<int>(state.range(0));
  const int piles = static_cast<int>(state.range(1));
  const PileGenerator gen{PileConfig()};
  int made = 0;
  for (auto _ : state) {
    for (int k = state.thread_index(); k < piles; k += state.threads()) {
      const Scene scene = gen.generate(1000 + k).scene;
      const GridSpec grid = GridSpec::sceneGrid(scene.surfaceCentroid().head<2>(), 0.64, resolution);
      benchmark::DoNotOptimize(
          computeGroundTruth(scene, grid, 3 * grid.voxel_size_m).tsdf.data.data());
      ++made;
    }
  }
  state.SetItemsProcessed(made);
}
BENCHMARK(BM_PileWithGroundTruth)
    ->Args({32, 60})
    ->Threads(1)
    ->Threads(2)
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

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
