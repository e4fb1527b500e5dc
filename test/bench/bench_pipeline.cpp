// Scene decomposition: Hough voting at R = 32 and 64, the joint fit of a 4-object scene, and a
// whole ScenePerception::perceive() with the shipped config: with its model (`fc`), with the
// C-VAE and 3 samples with and without the regrouping along the observed surface, and with one
// and with four tiles.
#include <benchmark/benchmark.h>

#include <functional>

#include "../test_scenes.h"
#include "simstack/fitting/superquadric_fit.h"
#include "simstack/instances/hough_voting.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/pipeline/perception_config.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack/render/depth_renderer.h"

using namespace simstack;

namespace {

/// A fixed 4-object pile and its ground-truth grids at resolution r (the ideal network output,
/// so that the benchmark depends neither on a model's quality nor on the pile generator).
struct BenchScene {
  Scene scene;
  GroundTruthGrids gt;
};
const BenchScene& benchScene(int r) {
  static std::map<int, BenchScene> cache;
  auto it = cache.find(r);
  if (it != cache.end()) return it->second;
  BenchScene b;
  b.scene = test::fourObjectPile();
  const GridSpec g = GridSpec::sceneGrid(b.scene.surfaceCentroid().head<2>(), 0.64, r);
  b.gt = computeGroundTruth(b.scene, g, 3 * g.voxel_size_m);
  return cache.emplace(r, std::move(b)).first->second;
}

/// config/perception.yaml as shipped, with `model` (relative to the package; empty: the
/// config's) and its card.
PerceptionConfig shippedConfig(const std::string& model = "") {
  const std::string dir = SIMSTACK_SOURCE_DIR;
  return loadPerceptionYaml(dir + "/config/perception.yaml", dir,
                            model.empty() ? "" : dir + "/" + model);
}

}  // namespace

// Hough voting with the shipped config's setting (its model's card; `card:1`), and with the
// library's built-in defaults as its peer (`card:0`: refinement 5, mu 4, instances from 15
// voxels).
static void BM_HoughVoting(benchmark::State& state) {
  const BenchScene& b = benchScene(static_cast<int>(state.range(0)));
  HoughConfig hc;
  if (state.range(1) != 0) {
    try {
      hc = shippedConfig().hough;
    } catch (const std::exception& e) {
      state.SkipWithError(e.what());
      return;
    }
  }
  hc.threads = 2;
  InstanceSegmentation seg;
  double rays = 0, shift = 0, assign = 0;
  for (auto _ : state) {
    seg = houghInstances(b.gt.tsdf, b.gt.votes, hc);
    rays += seg.timings.rays_ms;
    shift += seg.timings.mean_shift_ms;
    assign += seg.timings.assign_ms;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["instances"] = seg.size();
  state.counters["rays_ms"] = rays / n;
  state.counters["mean_shift_ms"] = shift / n;
  state.counters["assign_ms"] = assign / n;
  state.counters["count_MB"] = seg.count_bytes / 1e6;
  state.counters["candidates"] = seg.candidate_cells;
  state.counters["traversals"] = static_cast<double>(seg.traversals);
}
BENCHMARK(BM_HoughVoting)
    ->ArgNames({"", "card"})
    ->Args({32, 1})
    ->Args({64, 1})
    ->Args({32, 0})
    ->Args({64, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

static void BM_JointFitFourObjects(benchmark::State& state) {
  const BenchScene& b = benchScene(32);
  // Exact surface samples of the 4 objects, 1000 each, as the pipeline hands them over.
  std::vector<Points3> pts;
  std::mt19937_64 rng(3);
  for (const SceneObject& o : b.scene.objects) {
    Points3 p;
    for (const SurfacePoint& s : o.superquadricTable().sampleSurfaceObject(1000, rng))
      p.push_back(o.T_table_object * s.position);
    pts.push_back(p);
  }
  FitConfig fc;
  fc.threads = 2;
  // Its peer: final solves on the 600-point cover alone (these surfaces surround their shapes,
  // so by default the fits end with a few steps on all 1000 points).
  if (state.range(0) == 0) fc.surrounded_share = 2.0;
  // Its other peer: 3 rounds of the joint refinement.
  if (state.range(1) == 1) fc.joint_rounds = 3;
  for (auto _ : state) benchmark::DoNotOptimize(fitInstances(pts, fc, true));
}
BENCHMARK(BM_JointFitFourObjects)
    ->ArgNames({"all_points", "three_rounds"})
    ->Args({1, 0})
    ->Args({0, 0})
    ->Args({1, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// perceive() on a rendered view of `scene`, with the stage timings, the grid side and the
// tiles as counters.
void perceivePile(benchmark::State& state, PerceptionConfig pc, const Scene& scene) {
  PinholeCamera camera;
  const Vec3 c = scene.surfaceCentroid();
  const Transform T = lookAt(c + Vec3(0.55, -0.35, 0.55), Vec3(c.x(), c.y(), 0.05));
  const RenderResult r = DepthRenderer(scene).render(camera, T, SensorNoiseConfig::kinect(1));
  pc.threads = 2;
  const ScenePerception perception(pc);
  StageTimings sum;
  for (auto _ : state) {
    const SceneEstimate e = perception.perceive(DepthView{r.depth, camera, T});
    state.counters["grid_side_m"] = e.tile_side_m;
    state.counters["tiles"] = e.tiles;
    sum.tsdf_ms += e.timings.tsdf_ms;
    sum.network_ms += e.timings.network_ms;
    sum.instances_ms += e.timings.instances_ms;
    sum.mesh_ms += e.timings.mesh_ms;
    sum.fitting_ms += e.timings.fitting_ms;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["tsdf_ms"] = sum.tsdf_ms / n;
  state.counters["network_ms"] = sum.network_ms / n;
  state.counters["instances_ms"] = sum.instances_ms / n;
  state.counters["mesh_ms"] = sum.mesh_ms / n;
  state.counters["fitting_ms"] = sum.fitting_ms / n;
}

// The same on the bench pile.
void perceiveBenchPile(benchmark::State& state, const PerceptionConfig& pc) {
  perceivePile(state, pc, benchScene(32).scene);
}

// perceive() with config/perception.yaml as shipped and `model` (empty: the config's) with its
// card, after `change`.
void perceiveShippedConfig(benchmark::State& state, const std::string& model,
                           const std::function<void(PerceptionConfig*)>& change) {
  try {
    PerceptionConfig pc = shippedConfig(model);
    change(&pc);
    perceiveBenchPile(state, pc);
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
  }
}

// The shipped config with the C-VAE (its card's setting, `samples` codes), with and without
// the regrouping along the observed surface (its peer: the same frame, `segments:0`).
static void BM_Perceive(benchmark::State& state) {
  perceiveShippedConfig(state, "models/simstack_r32.pt", [&](PerceptionConfig* pc) {
    pc->samples = static_cast<int>(state.range(0));
    pc->segments.enabled = state.range(1) != 0;
    pc->symmetries = static_cast<int>(state.range(2));
  });
}
BENCHMARK(BM_Perceive)
    ->ArgNames({"samples", "segments", "symmetries"})
    ->Args({3, 1, 1})
    ->Args({3, 0, 1})
    ->Args({3, 1, 4})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// The labels image (pixelInstances) of the bench pile's frame, which the node makes for every
// frame while its outputs are latched; its peer is the frame itself (BM_PerceiveDefaultConfig).
static void BM_PixelLabels(benchmark::State& state) {
  try {
    PerceptionConfig pc = shippedConfig();
    pc.threads = 2;
    const BenchScene& b = benchScene(32);
    PinholeCamera camera;
    const Vec3 c = b.scene.surfaceCentroid();
    const Transform T = lookAt(c + Vec3(0.55, -0.35, 0.55), Vec3(c.x(), c.y(), 0.05));
    const RenderResult r = DepthRenderer(b.scene).render(camera, T, SensorNoiseConfig::kinect(1));
    const ScenePerception perception(pc);
    const DepthView view{r.depth, camera, T};
    const SceneEstimate e = perception.perceive(view);
    for (auto _ : state)
      benchmark::DoNotOptimize(pixelInstances(view, e, 0, labelMinHeight(perception.config())));
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
  }
}
BENCHMARK(BM_PixelLabels)->Unit(benchmark::kMillisecond)->UseRealTime();

// What a user runs: config/perception.yaml as shipped (its model, `fc`, with its card; its
// symmetries: 4; the seen surface fitted to the depth points), and its peers with one network
// pass and with mesh samples alone.
static void BM_PerceiveDefaultConfig(benchmark::State& state) {
  perceiveShippedConfig(state, "", [&](PerceptionConfig* pc) {
    pc->symmetries = static_cast<int>(state.range(0));
    pc->observed_points = state.range(1) != 0;
  });
}
BENCHMARK(BM_PerceiveDefaultConfig)
    ->ArgNames({"symmetries", "observed_points"})
    ->Args({4, 1})
    ->Args({1, 1})
    ->Args({4, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// On one frame of a pile of 6 objects of 5-15 cm (`pile:1`), which the shipped config
// (`config:1`) perceives a second time in a finer grid, and on the bench pile (`pile:0`), whose
// objects look ordinary to the network: their peer is the shipped config perceiving once and
// joining no overlapping fits (`config:0`; grid.object_voxels and
// surface_instances.fit_overlap_share 0).
static void BM_PerceiveSmallObjects(benchmark::State& state) {
  try {
    const std::string dir = SIMSTACK_SOURCE_DIR;
    PerceptionConfig pc = loadPerceptionYaml(dir + "/config/perception.yaml", dir);
    if (state.range(0) == 0) {
      pc.grid.object_voxels = 0.0;
      pc.surface_instances.fit_overlap_share = 0.0;
    }
    PileConfig small;
    small.min_objects = small.max_objects = 6;
    small.max_size_m = 0.15;
    perceivePile(state, pc,
                 state.range(1) ? PileGenerator(small).generate(3).scene : benchScene(32).scene);
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
  }
}
BENCHMARK(BM_PerceiveSmallObjects)
    ->ArgNames({"config", "pile"})
    ->Args({0, 1})
    ->Args({1, 1})
    ->Args({0, 0})
    ->Args({1, 0})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// Its peer without the open-container test (surface_instances.container_profile_m: 0), on
// the same frame: what the test costs where nothing joins.
static void BM_PerceiveWithoutContainerTest(benchmark::State& state) {
  perceiveShippedConfig(
      state, "", [&](PerceptionConfig* pc) { pc->surface_instances.container_profile_m = 0; });
}
BENCHMARK(BM_PerceiveWithoutContainerTest)->Unit(benchmark::kMillisecond)->UseRealTime();

// Its peer without the depth steps (segments.depth_jump_ratio: 0), on the same frame: what
// finding the steps and cutting the patches at them costs.
static void BM_PerceiveWithoutDepthSteps(benchmark::State& state) {
  perceiveShippedConfig(state, "",
                        [&](PerceptionConfig* pc) { pc->segments.depth_jump_ratio = 0; });
}
BENCHMARK(BM_PerceiveWithoutDepthSteps)->Unit(benchmark::kMillisecond)->UseRealTime();

// Its peer with the creases on (segments.crease_angle_deg: 20; off in the shipped config), on
// the same frame: what finding the valleys of the depth image and cutting the patches costs.
static void BM_PerceiveWithCreases(benchmark::State& state) {
  perceiveShippedConfig(state, "",
                        [&](PerceptionConfig* pc) { pc->segments.crease_angle_deg = 20; });
}
BENCHMARK(BM_PerceiveWithCreases)->Unit(benchmark::kMillisecond)->UseRealTime();

// Its peer with the occluded-sides test on (surface_instances.occluded_plane_m: 0.006; off in
// the shipped config): what the test costs where nothing joins.
static void BM_PerceiveWithOccludedTest(benchmark::State& state) {
  perceiveShippedConfig(
      state, "", [&](PerceptionConfig* pc) { pc->surface_instances.occluded_plane_m = 0.006; });
}
BENCHMARK(BM_PerceiveWithOccludedTest)->Unit(benchmark::kMillisecond)->UseRealTime();

// What grasps.launch runs by default: the shipped config with the C-VAE and its card, three
// hypotheses decomposed for the grasp ranking; its peer decomposes the first alone.
static void BM_PerceiveGraspHypotheses(benchmark::State& state) {
  perceiveShippedConfig(state, "models/simstack_r32.pt", [&](PerceptionConfig* pc) {
    pc->decompose_samples = static_cast<int>(state.range(0));
  });
}
BENCHMARK(BM_PerceiveGraspHypotheses)
    ->ArgName("decomposed")
    ->Arg(3)
    ->Arg(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// A 1280x720 frame seen from 1 m above the table, holding one 4-object pile (one tile) or four
// copies of it 0.8 m apart (four tiles), with the shipped config: the cost of a scene wider
// than one grid.
static void BM_PerceiveTiles(benchmark::State& state) {
  const Scene pile = test::fourObjectPile();
  const Vec3 c = pile.surfaceCentroid();
  Scene scene;
  const int piles = static_cast<int>(state.range(0));
  for (int k = 0; k < piles; ++k)
    for (SceneObject o : pile.objects) {
      const Vec2 shift = piles == 1 ? Vec2::Zero() : Vec2(k % 2 ? 0.4 : -0.4, k / 2 ? 0.4 : -0.4);
      o.T_table_object.translation() += Vec3(shift.x() - c.x(), shift.y() - c.y(), 0.0);
      scene.objects.push_back(o);
    }
  const PinholeCamera camera = test::wideCamera();
  const Transform T = lookAt(Vec3(0.0, -0.3, 1.0), Vec3(0.0, 0.0, 0.0));
  RenderConfig rc;
  rc.table_half_size_m = 1.5;
  const RenderResult r = DepthRenderer(scene, rc).render(camera, T, SensorNoiseConfig::kinect(1));
  try {
    PerceptionConfig pc = shippedConfig();
    pc.threads = 2;
    const ScenePerception perception(pc);
    int tiles = 0;
    size_t objects = 0;
    for (auto _ : state) {
      const SceneEstimate e = perception.perceive(DepthView{r.depth, camera, T});
      tiles = e.tiles;
      objects = e.instances().size();
    }
    state.counters["tiles"] = tiles;
    state.counters["objects"] = static_cast<double>(objects);
  } catch (const std::exception& e) {
    state.SkipWithError(e.what());
  }
}
BENCHMARK(BM_PerceiveTiles)
    ->ArgNames({"piles"})
    ->Arg(1)
    ->Arg(4)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

int main(int argc, char** argv) {
  keepFreedMemoryForReuse();
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  return 0;
}
