// Piles per second including ground truth (the dataset generator's inner loop), and its parts.
#include <benchmark/benchmark.h>
#include <omp.h>

#include <atomic>

#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/render/depth_renderer.h"

using namespace simstack;

// The same 200 piles (seeds 1000..1199) for every thread count, handed out one at a time as
// simstack_generate does (the cost of a pile varies several-fold with how many drops it
// needs, so a fixed split leaves one thread idle at the end, and runs over different seeds
// are not comparable).
static std::atomic<int> next_pile{0};
static void BM_PileWithGroundTruth(benchmark::State& state) {
  omp_set_num_threads(1);  // parallel across piles, as simstack_generate runs
  const int resolution = static_cast<int>(state.range(0));
  const int piles = static_cast<int>(state.range(1));
  const PileGenerator gen{PileConfig()};
  // Reset before this thread reaches the start barrier of the timed loop, which every thread
  // passes before taking a pile.
  if (state.thread_index() == 0) next_pile = 0;
  int made = 0;
  for (auto _ : state) {
    for (int k = next_pile++; k < piles; k = next_pile++) {
      const Scene scene = gen.generate(1000 + k).scene;
      const GridSpec grid =
          GridSpec::sceneGrid(scene.surfaceCentroid().head<2>(), 0.64, resolution);
      benchmark::DoNotOptimize(
          computeGroundTruth(scene, grid, 3 * grid.voxel_size_m).tsdf.data.data());
      ++made;
    }
  }
  state.SetItemsProcessed(made);
}
BENCHMARK(BM_PileWithGroundTruth)
    ->Args({32, 200})
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
