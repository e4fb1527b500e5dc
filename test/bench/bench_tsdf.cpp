// Partial TSDF of one 640x480 depth frame into 32^3 and 64^3 grids (on 2 threads and on 1),
// beside OctoMap's insertPointCloud of the same frame at the same voxel size, of every valid
// pixel (crop:0) and of the points inside the TSDF's grid alone (crop:1; OctoMap still clears
// each ray from the camera); scripts/bench prints the ratios.
#include <benchmark/benchmark.h>
#include <octomap/octomap.h>
#include <omp.h>

#include "simstack/offline/piles/pile_generator.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/tsdf/projective_tsdf.h"

using namespace simstack;

namespace {
struct Frame {
  Scene scene;
  PinholeCamera camera;
  Transform T_table_camera;
  DepthImage depth;
  Vec3 centre;
};

const Frame& frame() {
  static const Frame f = [] {
    Frame f;
    f.scene = PileGenerator(PileConfig()).generate(1).scene;
    f.centre = f.scene.surfaceCentroid();
    f.T_table_camera = lookAt(f.centre + Vec3(0.5, -0.4, 0.45), f.centre);
    f.depth = DepthRenderer(f.scene).render(f.camera, f.T_table_camera).depth;
    return f;
  }();
  return f;
}
}  // namespace

static void BM_PartialTsdf(benchmark::State& state) {
  const Frame& f = frame();
  const GridSpec grid =
      GridSpec::sceneGrid(f.centre.head<2>(), 0.64, static_cast<int>(state.range(0)));
  omp_set_num_threads(static_cast<int>(state.range(1)));
  ProjectiveTsdfConfig config;
  config.truncation_m = 3 * grid.voxel_size_m;
  ProjectiveTsdf tsdf(grid, config);
  for (auto _ : state) {
    tsdf.reset();
    tsdf.integrate(f.depth, f.camera, f.T_table_camera);
    benchmark::DoNotOptimize(tsdf.tsdf().data.data());
  }
  state.counters["pixels"] = f.depth.width * f.depth.height;
  omp_set_num_threads(omp_get_num_procs());
}
BENCHMARK(BM_PartialTsdf)
    ->ArgNames({"", "threads"})
    ->Args({32, 2})
    ->Args({64, 2})
    ->Args({32, 1})
    ->Args({64, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

static void BM_OctomapInsertPointCloud(benchmark::State& state) {
  const Frame& f = frame();
  const double voxel = 0.64 / static_cast<double>(state.range(0));
  const GridSpec grid =
      GridSpec::sceneGrid(f.centre.head<2>(), 0.64, static_cast<int>(state.range(0)));
  const bool crop = state.range(1) != 0;
  octomap::Pointcloud cloud;
  for (int v = 0; v < f.depth.height; ++v) {
    for (int u = 0; u < f.depth.width; ++u) {
      const float d = f.depth.at(u, v);
      if (!validDepth(d)) continue;
      const Vec3 p = f.T_table_camera * f.camera.backproject(u, v, d);
      const Vec3 g = (p - grid.origin_table) / grid.extent_m();
      if (crop && (g.minCoeff() < 0.0 || g.maxCoeff() >= 1.0)) continue;
      cloud.push_back(static_cast<float>(p.x()), static_cast<float>(p.y()),
                      static_cast<float>(p.z()));
    }
  }
  const Vec3 o = f.T_table_camera.translation();
  for (auto _ : state) {
    octomap::OcTree tree(voxel);
    tree.insertPointCloud(cloud, octomap::point3d(o.x(), o.y(), o.z()));
    benchmark::DoNotOptimize(tree.size());
  }
  state.counters["points"] = static_cast<double>(cloud.size());
}
BENCHMARK(BM_OctomapInsertPointCloud)
    ->ArgNames({"", "crop"})
    ->Args({32, 0})
    ->Args({64, 0})
    ->Args({32, 1})
    ->Args({64, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

BENCHMARK_MAIN();
