// simstack_generate: random piles settled under physics -> HDF5 dataset of ground-truth grids,
// optionally with rendered views (16-bit depth PNG in mm, instance mask, YAML) and pictures.
#include <omp.h>
#include <CLI/CLI.hpp>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <map>
#include <mutex>
#include <thread>

#include "simstack/dataset/dataset.h"
#include "simstack/io/image_io.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/scene/mesh_catalogue.h"
#include "simstack/scene/pile_generator.h"
#include "simstack/tools/progress.h"

namespace fs = std::filesystem;
using namespace simstack;

namespace {

struct Options {
  int scenes = 10;
  uint64_t seed = 1;
  int resolution = 32;
  std::string output;
  std::string objects = "3:4";
  std::string ycb_dir;
  int views = 0;
  std::string views_dir;
  bool pictures = false;
  bool noise = false;
  double extent_m = 0.64;
  double truncation_vox = 3.0;
  double max_tilt_deg = 180.0;
  int threads = 2;
};

struct SceneResult {
  Pile pile;
  GroundTruthGrids gt;
};

// Per-scene seeds are a hash of (seed, index), so a scene never depends on the thread count.
uint64_t sceneSeed(uint64_t seed, int index) {
  uint64_t z = seed * 0x9E3779B97F4A7C15ull + static_cast<uint64_t>(index) + 1;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

void writeViews(const Options& o, const fs::path& dir, int index, const Scene& scene,
                uint64_t seed) {
  DepthRenderer renderer(scene);
  std::mt19937_64 rng(seed ^ 0x5157u);
  const Vec3 centre = scene.surfaceCentroid();
  PinholeCamera camera;
  for (int v = 0; v < o.views; ++v) {
    ViewDescription view;
    view.camera = camera;
    view.T_table_camera = sampleViewpoint(centre, ViewpointRange(), rng);
    const SensorNoiseConfig noise =
        o.noise ? SensorNoiseConfig::kinect(seed + v) : SensorNoiseConfig();
    const RenderResult r = renderer.render(camera, view.T_table_camera, noise);
    char stem[64];
    std::snprintf(stem, sizeof(stem), "scene_%06d_view_%d", index, v);
    const std::string base = (dir / stem).string();
    writeDepthPng(base + "_depth.png", r.depth);
    writeMaskPng(base + "_mask.png", r.instances);
    writeViewYaml(base + ".yaml", view);
    if (o.pictures) {
      writeDepthPicture(base + "_depth_colour.png", r.depth);
      // The ground-truth picture shows the objects, not the sensor: render it without noise.
      const RenderResult clean =
          renderer.render(camera, view.T_table_camera, SensorNoiseConfig(), true);
      writeShadedPicture(base + "_shaded.png", clean.instances, clean.normals_table,
                         view.T_table_camera);
    }
  }
}

std::pair<int, int> parseRange(const std::string& s) {
  const auto colon = s.find(':');
  try {
    if (colon == std::string::npos) {
      const int n = std::stoi(s);
      return {n, n};
    }
    return {std::stoi(s.substr(0, colon)), std::stoi(s.substr(colon + 1))};
  } catch (const std::exception&) {
    throw CLI::ValidationError("--objects", "expected MIN:MAX or N, got '" + s + "'");
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  CLI::App app{
      "Generate random piles settled under Bullet physics and write the HDF5 dataset "
      "of ground-truth TSDF, centre votes and labels (DESIGN.md section 4)."};
  app.add_option("--scenes", o.scenes, "number of piles")->required()->check(CLI::PositiveNumber);
  app.add_option("--seed", o.seed, "random seed (scene i uses a hash of seed and i)")->required();
  app.add_option("--resolution", o.resolution, "grid resolution R (R^3 voxels)")
      ->check(CLI::Range(4, 256))
      ->capture_default_str();
  app.add_option("--output", o.output, "output HDF5 file")->required();
  app.add_option("--objects", o.objects, "objects per pile, MIN:MAX")->capture_default_str();
  app.add_option("--ycb", o.ycb_dir,
                 "directory of YCB meshes (<dir>/<object>/nontextured.stl): mesh piles instead of "
                 "superquadrics");
  app.add_option("--views", o.views, "rendered views per scene written beside the dataset")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--views-dir", o.views_dir, "where views go (default: <output stem>_views/)");
  app.add_flag("--pictures", o.pictures,
               "also write colour depth and shaded PNG pictures of each view");
  app.add_flag("--noise", o.noise, "Kinect-like noise and missing pixels in the rendered views");
  app.add_option("--extent", o.extent_m, "scene grid side in metres")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--truncation-vox", o.truncation_vox, "TSDF truncation in voxels")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--max-tilt", o.max_tilt_deg,
                 "drop orientation: a face down, random yaw, tilt up to this many degrees; 180 = "
                 "uniformly random (the paper); 0 is about 2x faster but gives neater, taller piles")
      ->check(CLI::Range(0.0, 180.0))
      ->capture_default_str();
  app.add_option("--threads", o.threads, "worker threads")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  try {
    const auto [min_objects, max_objects] = parseRange(o.objects);
    PileConfig config;
    config.min_objects = min_objects;
    config.max_objects = max_objects;
    config.grid_extent_m = o.extent_m;
    config.max_tilt_deg = o.max_tilt_deg;
    std::unique_ptr<PileGenerator> generator;
    DatasetInfo info;
    if (!o.ycb_dir.empty()) {
      if (!fs::is_directory(o.ycb_dir))
        throw std::runtime_error("--ycb: not a directory: " + o.ycb_dir);
      generator = std::make_unique<PileGenerator>(config, loadMeshCatalogue(o.ycb_dir));
      info.mesh_names = ycbObjectNames();
    } else {
      generator = std::make_unique<PileGenerator>(config);
    }
    info.num_scenes = o.scenes;
    info.resolution = o.resolution;
    info.extent_m = o.extent_m;
    info.truncation_m = o.truncation_vox * o.extent_m / o.resolution;
    info.max_objects_per_scene = max_objects;
    info.seed = o.seed;
    info.min_objects = min_objects;
    info.max_objects = max_objects;
    if (fs::path(o.output).has_parent_path()) {
      std::error_code ec;
      fs::create_directories(fs::path(o.output).parent_path(), ec);
      if (ec)
        throw std::runtime_error("cannot create the directory of --output " + o.output + ": " +
                                 ec.message());
    }
    DatasetWriter writer(o.output, info);
    fs::path views_dir;
    if (o.views > 0) {
      views_dir = o.views_dir.empty()
                      ? fs::path(fs::path(o.output).replace_extension("").string() + "_views")
                      : fs::path(o.views_dir);
      fs::create_directories(views_dir);
    }

    std::mutex mutex;
    std::condition_variable ready;
    std::map<int, SceneResult> done;
    std::string failure;
    std::atomic<int> next{0};
    const int threads = std::min(o.threads, o.scenes);
    auto worker = [&] {
      omp_set_num_threads(threads > 1 ? 1 : 2);  // parallelism across scenes, not inside
      for (int i = next++; i < o.scenes; i = next++) {
        try {
          const uint64_t seed = sceneSeed(o.seed, i);
          SceneResult r;
          r.pile = generator->generate(seed);
          const Vec3 centre = r.pile.scene.surfaceCentroid();
          const GridSpec grid = GridSpec::sceneGrid(centre.head<2>(), o.extent_m, o.resolution);
          r.gt = computeGroundTruth(r.pile.scene, grid, info.truncation_m);
          if (o.views > 0) writeViews(o, views_dir, i, r.pile.scene, seed);
          std::lock_guard<std::mutex> lock(mutex);
          done.emplace(i, std::move(r));
        } catch (const std::exception& e) {
          std::lock_guard<std::mutex> lock(mutex);
          if (failure.empty()) failure = "scene " + std::to_string(i) + ": " + e.what();
          next = o.scenes;
        }
        ready.notify_all();
      }
    };
    std::vector<std::thread> pool;
    const auto t0 = std::chrono::steady_clock::now();
    for (int t = 0; t < threads; ++t) pool.emplace_back(worker);
    ProgressBar bar("generating", o.scenes);
    long attempts = 0, objects = 0;
    double undone_steps = 0, all_steps = 0;
    for (int i = 0; i < o.scenes; ++i) {
      SceneResult r;
      {
        std::unique_lock<std::mutex> lock(mutex);
        ready.wait(lock, [&] { return done.count(i) > 0 || !failure.empty(); });
        if (!failure.empty() && done.count(i) == 0) break;
        r = std::move(done.at(i));
        done.erase(i);
      }
      writer.write(i, r.pile.scene, r.gt);
      attempts += r.pile.attempts;
      objects += static_cast<long>(r.pile.scene.objects.size());
      const auto& st = r.pile.object_steps;
      undone_steps += st.undone_drops + st.rejected_piles;
      all_steps += st.placed + st.undone_drops + st.rest_checks + st.rejected_piles;
      bar.update(i + 1);
    }
    for (auto& t : pool) t.join();
    bar.finish();
    if (!failure.empty()) throw std::runtime_error(failure);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::cout << "wrote " << o.scenes << " scenes (" << objects << " objects, "
              << (o.ycb_dir.empty() ? "superquadrics" : "YCB meshes") << ") to " << o.output << "\n"
              << "  grid " << o.resolution << "^3, " << o.extent_m / o.resolution * 100.0
              << " cm voxels, truncation " << info.truncation_m * 100.0 << " cm\n"
              << "  " << attempts << " piles drawn for " << o.scenes << " accepted ("
              << 100.0 * o.scenes / attempts << " % accepted), " << o.scenes / seconds
              << " scenes/s on " << threads << " threads; "
              << (all_steps > 0 ? 100.0 * undone_steps / all_steps : 0.0)
              << " % of the physics went to drops and piles that were undone\n";
    if (o.views > 0)
      std::cout << "  " << o.views << " views per scene in " << views_dir.string() << "/\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_generate: error: " << e.what() << "\n";
    return 1;
  }
}
