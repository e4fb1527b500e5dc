#include "simstack/offline/dataset/dataset_generation.h"

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <set>
#include <stdexcept>
#include <thread>
#include <vector>

#include "simstack/io/image_io.h"
#include "simstack/io/staged_output.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/offline/dataset/viewpoints.h"
#include "simstack/offline/piles/mesh_catalogue.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/seeds.h"

namespace fs = std::filesystem;

namespace simstack {
namespace {

constexpr double kLooseDropRadius_m = 0.15;

struct SceneResult {
  Pile pile;
  GroundTruthGrids gt;
};

uint64_t sceneSeed(uint64_t seed, int index) {
  return splitMix64(seed * 0x9E3779B97F4A7C15ull + static_cast<uint64_t>(index) + 1);
}

void writeViews(const GenerationOptions& o, const fs::path& dir, int index, const Scene& scene,
                uint64_t seed) {
  DepthRenderer renderer(scene);
  std::mt19937_64 rng(seed ^ 0x5157u);
  const Vec3 centre = scene.surfaceCentroid();
  const PinholeCamera& camera = o.camera;
  for (int v = 0; v < o.views; ++v) {
    ViewDescription view;
    view.camera = camera;
    view.T_table_camera = sampleViewpoint(centre, ViewpointRange(), rng);
    view.depth_scale_m = 0.001;  // writeDepthPng's millimetres
    const SensorNoiseConfig noise =
        o.noise ? SensorNoiseConfig::preset(o.sensor, seed + v) : SensorNoiseConfig();
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

std::unique_ptr<PileGenerator> makeGenerator(const GenerationOptions& o, DatasetInfo* info) {
  PileConfig config;
  config.min_objects = o.min_objects;
  config.max_objects = o.max_objects;
  config.grid_extent_m = o.extent_m;
  config.max_tilt_deg = o.max_tilt_deg;
  if (!(o.min_size_m > 0.0 && o.min_size_m <= o.max_size_m && o.max_size_m < o.extent_m))
    throw std::invalid_argument("object sizes must satisfy 0 < min (" +
                                std::to_string(o.min_size_m) + " m) <= max (" +
                                std::to_string(o.max_size_m) + " m) < the grid's side (" +
                                std::to_string(o.extent_m) + " m)");
  // A superquadric narrower than a voxel may hold no voxel centre: its labels would be empty.
  // (YCB meshes keep their own size.)
  const double voxel_m = o.extent_m / o.resolution;
  if (o.ycb_dir.empty() && o.min_size_m < voxel_m)
    throw std::invalid_argument(
        "object sizes: the smallest (" + std::to_string(o.min_size_m) +
        " m) is below one voxel (the grid's side / resolution = " + std::to_string(voxel_m) +
        " m): such an object may cover no voxel, its ground truth empty; raise --sizes' minimum "
        "(the default is 0.05:0.3) or --resolution");
  config.min_size_m = o.min_size_m;
  config.max_size_m = o.max_size_m;
  config.household_share = o.household_share;
  if (o.loose) {
    config.require_stack = false;
    config.drop_radius_m = kLooseDropRadius_m;
  }
  if (o.ycb_dir.empty()) {
    if (!o.ycb_objects.empty())
      throw std::invalid_argument("--ycb-objects names meshes of --ycb's directory: give --ycb");
    auto generator = std::make_unique<PileGenerator>(config);
    for (const auto& shape : generator->catalogue()) info->mesh_names.push_back(shape->name());
    return generator;
  }
  if (o.household_share > 0.0)
    throw std::invalid_argument("--household draws into superquadric piles: not with --ycb");
  if (!fs::is_directory(o.ycb_dir))
    throw std::runtime_error("--ycb: not a directory: " + o.ycb_dir);
  info->mesh_names = o.ycb_objects.empty() ? ycbObjectNames() : o.ycb_objects;
  // A missing or unreadable mesh is named by the catalogue; the file stores the names joined
  // by commas.
  std::set<std::string> seen;
  for (const std::string& name : info->mesh_names) {
    if (name.find(',') != std::string::npos)
      throw std::invalid_argument("--ycb-objects: '" + name + "' holds a comma");
    if (!seen.insert(name).second)
      throw std::invalid_argument("--ycb-objects: " + name + " is named twice");
  }
  return std::make_unique<PileGenerator>(config, loadMeshCatalogue(o.ycb_dir, info->mesh_names));
}

DatasetInfo datasetInfo(const GenerationOptions& o) {
  DatasetInfo info;
  info.num_scenes = o.scenes;
  info.resolution = o.resolution;
  info.extent_m = o.extent_m;
  info.truncation_m = o.truncation_vox * o.extent_m / o.resolution;
  info.max_objects_per_scene = o.max_objects;
  info.seed = o.seed;
  info.min_objects = o.min_objects;
  info.max_objects = o.max_objects;
  return info;
}

/// Scenes made by worker threads in any order, taken in index order by the writer. A worker
/// starts scene i only when i lies within kAhead scenes per thread of the next one the writer
/// takes: a slow
/// scene (a pile drawn again and again) does not let the finished ones after it fill memory.
class SceneWorkers {
 public:
  SceneWorkers(const GenerationOptions& o, const PileGenerator& generator, const DatasetInfo& info,
               const fs::path& views_dir)
      : scenes_(o.scenes) {
    const int threads = std::min(o.threads, o.scenes);
    for (int t = 0; t < threads; ++t)
      pool_.emplace_back([this, &o, &generator, &info, views_dir, threads] {
        omp_set_num_threads(threads > 1 ? 1 : 2);  // parallelism across scenes, not inside
        for (int i = next_++; i < scenes_; i = next_++) {
          {
            std::unique_lock<std::mutex> lock(mutex_);
            room_.wait(lock, [&] { return i < taken_ + kAhead * threads || stop_; });
            if (stop_) break;
          }
          try {
            uint64_t seed = sceneSeed(o.seed, i);
            SceneResult r;
            for (int redraw = 0;; ++redraw) {
              try {
                r.pile = generator.generate(seed);
                break;
              } catch (const std::runtime_error&) {
                if (redraw >= o.redraws) throw;
                ++skipped_;
                seed = sceneSeed(seed ^ 0x5EEDu, i);  // another pile for scene i
              }
            }
            const Vec3 centre = r.pile.scene.surfaceCentroid();
            const GridSpec grid = GridSpec::sceneGrid(centre.head<2>(), o.extent_m, o.resolution);
            r.gt = computeGroundTruth(r.pile.scene, grid, info.truncation_m);
            if (o.views > 0) writeViews(o, views_dir, i, r.pile.scene, seed);
            std::lock_guard<std::mutex> lock(mutex_);
            done_.emplace(i, std::move(r));
          } catch (const std::exception& e) {
            std::lock_guard<std::mutex> lock(mutex_);
            if (failure_.empty()) failure_ = "scene " + std::to_string(i) + ": " + e.what();
            next_ = scenes_;
          }
          ready_.notify_all();
        }
      });
  }
  ~SceneWorkers() {
    next_ = scenes_;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    room_.notify_all();
    for (auto& t : pool_) t.join();
  }
  int threads() const { return static_cast<int>(pool_.size()); }
  int skipped() const { return skipped_; }
  /// Scene i once made; throws std::runtime_error with the first failure.
  SceneResult take(int i) {
    std::unique_lock<std::mutex> lock(mutex_);
    ready_.wait(lock, [&] { return done_.count(i) > 0 || !failure_.empty(); });
    if (done_.count(i) == 0) throw std::runtime_error(failure_);
    SceneResult r = std::move(done_.at(i));
    done_.erase(i);
    taken_ = i + 1;
    room_.notify_all();
    return r;
  }

 private:
  const int scenes_;
  std::atomic<int> next_{0};
  std::atomic<int> skipped_{0};
  static constexpr int kAhead = 4;  ///< scenes ahead of the writer, per thread
  std::mutex mutex_;
  std::condition_variable ready_;
  std::condition_variable room_;
  int taken_ = 0;  ///< scenes the writer has taken
  bool stop_ = false;
  std::map<int, SceneResult> done_;
  std::string failure_;
  std::vector<std::thread> pool_;  // last: the threads use the members above
};

}  // namespace

GenerationSummary generateDataset(const GenerationOptions& o,
                                  const std::function<void(int, int)>& progress) {
  DatasetInfo info = datasetInfo(o);
  const std::unique_ptr<PileGenerator> generator = makeGenerator(o, &info);
  // Written beside the target and renamed onto it when complete: a failed run leaves no
  // partial dataset that training would later read.
  StagedFile staged(o.output);
  auto writer = std::make_unique<DatasetWriter>(staged.path(), info);
  GenerationSummary summary;
  summary.truncation_m = info.truncation_m;
  // The views too: staged, and replacing an earlier run's views whole (none of its scenes stay
  // beside the new ones).
  std::optional<StagedDirectory> views;
  if (o.views > 0) {
    summary.views_dir = o.views_dir.empty()
                            ? fs::path(o.output).replace_extension("").string() + "_views"
                            : o.views_dir;
    // The views directory is replaced whole: it may not hold the dataset itself.
    if (pathHolds(summary.views_dir, o.output))
      throw std::invalid_argument("--views-dir " + summary.views_dir + " holds the dataset " +
                                  o.output + ": give the views a directory of their own");
    views.emplace(summary.views_dir, "simstack_generate");
  }
  const auto t0 = std::chrono::steady_clock::now();
  double undone_steps = 0, all_steps = 0;
  {
    SceneWorkers workers(o, *generator, info, views ? views->path() : std::string());
    summary.threads = workers.threads();
    for (int i = 0; i < o.scenes; ++i) {
      const SceneResult r = workers.take(i);
      writer->write(i, r.pile.scene, r.gt);
      summary.attempts += r.pile.attempts;
      const size_t count = r.pile.scene.objects.size();
      summary.objects += static_cast<long>(count);
      if (summary.piles_with.size() <= count) summary.piles_with.resize(count + 1, 0);
      ++summary.piles_with[count];
      const auto& st = r.pile.object_steps;
      undone_steps += st.undone_drops + st.rejected_piles;
      all_steps += st.placed + st.undone_drops + st.rest_checks + st.rejected_piles;
      if (progress) progress(i + 1, o.scenes);
    }
    summary.skipped = workers.skipped();
  }
  writer.reset();  // closes the file
  staged.commit();
  if (views) views->commit();
  summary.undone_share = all_steps > 0 ? undone_steps / all_steps : 0.0;
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return summary;
}

}  // namespace simstack
