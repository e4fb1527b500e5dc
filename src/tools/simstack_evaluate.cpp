// simstack_evaluate: the paper's single-view protocol (DESIGN.md section 5, Table 1) for
// trained models and the classical baseline, in one run on the same rendered views:
// visible and full Chamfer distance, expected occupancy (BCE, IoU), stability under physics
// and object counts, binned by the visible share of the pile's surface.
#include <CLI/CLI.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iomanip>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>

#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include "simstack/dataset/dataset.h"
#include "simstack/eval/occupancy.h"
#include "simstack/eval/scene_metrics.h"
#include "simstack/eval/segmentation.h"
#include "simstack/mesh/marching_cubes.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/model/training_sample.h"
#include "simstack/pipeline/classical_baseline.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/tools/progress.h"
#include "simstack/tsdf/ground_truth.h"

using namespace simstack;
using nlohmann::json;

namespace {

const std::vector<double> kBinEdges = {0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 1.01};
const std::vector<std::string> kMetrics = {
    "chamfer_visible_m", "chamfer_full_m", "chamfer_full_sq_m", "iou",        "bce",
    "displacement_m",    "stable",         "count_error",       "count_exact"};

struct Method {
  std::string name;
  std::unique_ptr<ScenePerception> perception;  // null for the classical baseline
  std::vector<std::map<std::string, double>> rows;
};

double mean(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? std::nan("") : s / v.size();
}
double stddev(const std::vector<double>& v) {
  const double m = mean(v);
  double s = 0;
  for (double x : v) s += (x - m) * (x - m);
  return v.size() > 1 ? std::sqrt(s / (v.size() - 1)) : 0.0;
}

json summarise(const std::vector<std::map<std::string, double>>& rows) {
  json out;
  for (const auto& m : kMetrics) {
    std::vector<double> v;
    for (const auto& r : rows)
      if (r.count(m) && std::isfinite(r.at(m))) v.push_back(r.at(m));
    out[m] = {{"mean", mean(v)}, {"std", stddev(v)}, {"n", v.size()}};
  }
  json bins = json::array();
  for (size_t b = 0; b + 1 < kBinEdges.size(); ++b) {
    std::vector<std::map<std::string, double>> in;
    for (const auto& r : rows)
      if (r.at("visible_ratio") >= kBinEdges[b] && r.at("visible_ratio") < kBinEdges[b + 1])
        in.push_back(r);
    json bin = {{"visible_from", kBinEdges[b]},
                {"visible_to", std::min(kBinEdges[b + 1], 1.0)},
                {"views", in.size()}};
    for (const auto& m : kMetrics) {
      std::vector<double> v;
      for (const auto& r : in)
        if (r.count(m) && std::isfinite(r.at(m))) v.push_back(r.at(m));
      bin[m] = mean(v);
    }
    bins.push_back(bin);
  }
  out["by_visible_ratio"] = bins;
  return out;
}

/// The real-data check of DESIGN.md section 5 on labelled organized clouds (mOSD): object
/// count and agreement of the visible-point segmentation with the labels (label / 10 = object,
/// labels < 20 = table or invalid).
json evaluateReal(const std::string& dir, PerceptionConfig pc) {
  std::vector<std::filesystem::path> files;
  for (const auto& e : std::filesystem::directory_iterator(dir))
    if (e.path().extension() == ".pcd") files.push_back(e.path());
  std::sort(files.begin(), files.end());
  if (files.empty()) throw std::runtime_error("no .pcd files in " + dir);
  const ScenePerception perception(pc);
  json out = json::array();
  std::cout << "\n| scene | objects (labels) | objects found | segmentation agreement "
               "|\n|---|---|---|---|\n";
  for (const auto& f : files) {
    pcl::PointCloud<pcl::PointXYZL> cloud;
    if (pcl::io::loadPCDFile(f.string(), cloud) != 0 || !cloud.isOrganized())
      throw std::runtime_error(f.string() + " is not an organized labelled PCD");
    DepthView view;
    view.camera.width = cloud.width;
    view.camera.height = cloud.height;  // mOSD intrinsics: fx = fy = 525, cx = 319.5, cy = 239.5
    view.depth = DepthImage(cloud.width, cloud.height, std::nanf(""));
    Image<int> truth(cloud.width, cloud.height, -1);
    std::map<int, int> object_pixels;
    for (uint32_t v = 0; v < cloud.height; ++v)
      for (uint32_t u = 0; u < cloud.width; ++u) {
        const auto& p = cloud.at(u, v);
        if (std::isfinite(p.z) && p.z > 0) view.depth.at(u, v) = p.z;
        if (std::isfinite(p.z) && p.label >= 20) {
          truth.at(u, v) = static_cast<int>(p.label / 10);
          ++object_pixels[truth.at(u, v)];
        }
      }
    const SceneEstimate est = perception.perceive(view);
    const Image<int> found = pixelInstances(view, est);
    const double agreement = segmentationAgreement(truth.pixels, found.pixels).agreement;
    out.push_back({{"scene", f.filename().string()},
                   {"objects", object_pixels.size()},
                   {"found", est.instances().size()},
                   {"agreement", agreement},
                   {"table_estimated", est.table_estimated},
                   {"perceive_ms", est.timings.total_ms}});
    std::cout << "| " << f.filename().string() << " | " << object_pixels.size() << " | "
              << est.instances().size() << " | " << std::fixed << std::setprecision(3) << agreement
              << " |\n";
  }
  return out;
}

std::string defaultModel() {
  const std::filesystem::path p =
      std::filesystem::path(SIMSTACK_SOURCE_DIR) / "models/simstack_r32.pt";
  return p.string();
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> models;
  std::string dataset, output, mesh_dir;
  int views = 3, samples = 3, scenes = 0, threads = 2, chamfer_points = 1000;
  int width = 640, height = 480;
  uint64_t seed = 7;
  bool noise = false, no_classical = false, no_stability = false;
  CLI::App app{
      "Evaluate trained models and the classical baseline on a test dataset (DESIGN.md section "
      "5): every scene from random viewpoints in the paper's ranges, S latent samples per view "
      "(1 for the FC baseline); writes JSON and prints the table."};
  app.add_option("--model", models,
                 "model file(s), e.g. models/simstack_r32.pt runs/fc/model.pt (default: the "
                 "configs' models, else models/simstack_r32.pt)")
      ->check(CLI::ExistingFile);
  std::string real_dir;
  std::vector<std::string> config_paths;
  app.add_option("--config", config_paths,
                 "perception parameters (config/perception.yaml): once for every model, or once "
                 "per --model in the same order (each model's own Hough setting, "
                 "simstack_tune_hough); without --model, the configs' models are evaluated. The "
                 "classical baseline uses the first config's fitting section")
      ->check(CLI::ExistingFile);
  app.add_option("--dataset", dataset, "test dataset (a seed never used for training)")
      ->check(CLI::ExistingFile);
  app.add_option("--real", real_dir,
                 "directory of labelled organized PCDs (../shared/data/real/mosd): object counts "
                 "and segmentation agreement with the first --model, instead of --dataset")
      ->check(CLI::ExistingDirectory);
  app.add_option("--output", output, "results JSON")->required();
  app.add_option("--width", width,
                 "rendered view width (pixels; the protocol's 640): fx scales with the width, fy "
                 "with the height, so keep 4:3 for square pixels")
      ->capture_default_str()
      ->check(CLI::Range(16, 4096));
  app.add_option("--height", height, "rendered view height (the protocol's 480)")
      ->capture_default_str()
      ->check(CLI::Range(16, 4096));
  app.add_option("--views", views, "viewpoints per scene")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--samples", samples, "latent samples per viewpoint")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--scenes", scenes, "evaluate only the first N scenes (0 = all)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--seed", seed, "viewpoint and code seed")->capture_default_str();
  app.add_option("--ycb", mesh_dir, "mesh directory for YCB datasets")
      ->check(CLI::ExistingDirectory);
  app.add_flag("--noise", noise, "Kinect-like sensor noise in the rendered views");
  app.add_flag("--no-classical", no_classical, "skip the classical baseline");
  app.add_flag("--no-stability", no_stability, "skip the physics stability test");
  app.add_option("--chamfer-points", chamfer_points, "surface samples per Chamfer set")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--threads", threads, "threads")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  CLI11_PARSE(app, argc, argv);
  keepFreedMemoryForReuse();  // the network runs in this process
  if (dataset.empty() == real_dir.empty()) {
    std::cerr << "simstack_evaluate: give either --dataset or --real\n";
    return 2;
  }
  if (!models.empty() && config_paths.size() > 1 && config_paths.size() != models.size()) {
    std::cerr << "simstack_evaluate: " << config_paths.size() << " --config for " << models.size()
              << " --model: give one config for all models or one per model\n";
    return 2;
  }
  try {
    // One perception config per method, in the order of the models.
    std::vector<PerceptionConfig> configs;
    for (const auto& path : config_paths)
      configs.push_back(loadPerceptionYaml(path, SIMSTACK_SOURCE_DIR));
    if (configs.empty()) configs.emplace_back();
    if (models.empty()) {
      if (config_paths.empty()) {
        models.push_back(defaultModel());
      } else {
        for (const auto& c : configs) models.push_back(c.model_path);
      }
    }
    if (configs.size() == 1) configs.resize(models.size(), configs.front());
    for (size_t i = 0; i < models.size(); ++i) {
      configs[i].model_path = models[i];
      configs[i].threads = threads;
    }
    const PerceptionConfig& base = configs.front();
    if (!real_dir.empty()) {
      const json real = {{"real_dir", real_dir},
                         {"model", models.front()},
                         {"config", perceptionYaml(base)},
                         {"scenes", evaluateReal(real_dir, base)}};
      std::ofstream f(output);
      if (!f) throw std::runtime_error("cannot write " + output);
      f << real.dump(1) << "\n";
      std::cout << "results: " << output << "\n";
      return 0;
    }
    const DatasetReader reader(dataset, mesh_dir);
    const int n = scenes > 0 ? std::min(scenes, reader.size()) : reader.size();
    std::vector<Method> methods;
    for (const PerceptionConfig& config : configs) {
      PerceptionConfig pc = config;
      pc.zero_code_first = false;  // random codes, as the paper evaluates
      pc.samples = samples;        // an FC model runs with 1
      Method m;
      m.perception = std::make_unique<ScenePerception>(pc);
      m.name = m.perception->modelConfig().architecture;
      for (const auto& other : methods)
        if (other.name == m.name) m.name += "_" + std::to_string(methods.size());
      methods.push_back(std::move(m));
    }
    if (!no_classical) methods.push_back(Method{"classical", nullptr, {}});

    const PinholeCamera camera = scaledKinect(width, height);
    const double truncation = reader.info().truncation_m;
    ProgressBar bar("evaluating " + std::to_string(methods.size()) + " methods", n);
    // The true piles under the same stability test: the reference for the methods' rows (the
    // generator verified them at rest for one second; the test runs 42 s).
    std::vector<double> truth_stable, truth_displacement;
    for (int k = 0; k < n; ++k) {
      const SceneRecord rec = reader.read(k);
      if (!no_stability) {
        const StabilityResult st = simulateStability(rec.scene);
        truth_stable.push_back(st.stable);
        truth_displacement.push_back(st.mean_displacement_m);
      }
      const DepthRenderer renderer(rec.scene);
      TriangleMesh gt_mesh;
      for (const SceneObject& o : rec.scene.objects)
        gt_mesh.append(o.shape->mesh().transformed(o.T_table_object));
      // Separate random streams per scene, per view and per method: the views, and each
      // method's Chamfer samples, do not depend on which other methods are in the run.
      std::mt19937_64 scene_rng(seed * 1000003ull + static_cast<uint64_t>(k));
      const Points3 gt_full = samplePoints(gt_mesh, chamfer_points, scene_rng);
      const uint64_t scene_seed = scene_rng();
      for (int v = 0; v < views; ++v) {
        std::mt19937_64 rng(scene_seed + 7919ull * static_cast<uint64_t>(v + 1));
        const Transform T = sampleViewpoint(rec.scene.surfaceCentroid(), ViewpointRange(), rng);
        const uint64_t view_seed = rng();
        const RenderResult r = renderer.render(
            camera, T, noise ? SensorNoiseConfig::kinect(view_seed) : SensorNoiseConfig());
        const std::vector<bool> vis = visibleTriangles(gt_mesh, camera, T);
        const TriangleMesh gt_visible = subMesh(gt_mesh, vis);
        const Points3 gt_vis_pts = samplePoints(gt_visible, chamfer_points, rng);
        const double visible_ratio = gt_visible.area() / gt_mesh.area();
        const DepthView view{r.depth, camera, T};
        GridSpec grid;
        GroundTruthGrids gt;
        bool have_gt = false;
        const uint64_t method_seed = rng();
        for (Method& m : methods) {
          std::mt19937_64 rng(method_seed ^ std::hash<std::string>{}(m.name));
          std::map<std::string, double> row{
              {"scene", k},
              {"view", v},
              {"visible_ratio", visible_ratio},
              {"objects", static_cast<double>(rec.scene.objects.size())}};
          std::vector<Superquadric> shapes;
          std::vector<std::vector<float>> occupancy;
          if (m.perception) {
            const SceneEstimate est = m.perception->perceive(view);
            if (!have_gt) {
              grid = est.grid;
              gt = computeGroundTruth(rec.scene, grid, truncation);
              have_gt = true;
            }
            double full = 0, visible = 0;
            for (const SceneHypothesis& h : est.hypotheses) {
              occupancy.push_back(h.tsdf_m.data);
              const TriangleMesh surface = h.surface.empty() ? extractSurface(h.tsdf_m) : h.surface;
              full += chamferDistance(samplePoints(surface, chamfer_points, rng), gt_full);
              visible += chamferDistance(
                  samplePoints(subMesh(surface, visibleTriangles(surface, camera, T)),
                               chamfer_points, rng),
                  gt_vis_pts);
            }
            row["chamfer_full_m"] = full / est.hypotheses.size();
            row["chamfer_visible_m"] = visible / est.hypotheses.size();
            for (const InstanceEstimate& e : est.instances()) shapes.push_back(e.superquadric);
            row["perceive_ms"] = est.timings.total_ms;
          } else {
            if (!have_gt) {
              // The grid the networks would use, for the occupancy scores.
              const Vec2 c =
                  visiblePileCentre(r.depth, camera, T, rec.scene.surfaceCentroid().head<2>(),
                                    0.5 * reader.info().extent_m);
              grid = GridSpec::sceneGrid(c, reader.info().extent_m, reader.info().resolution);
              gt = computeGroundTruth(rec.scene, grid, truncation);
              have_gt = true;
            }
            ClassicalConfig cc;
            cc.threads = threads;
            cc.fit = base.fit;
            shapes = classicalBaseline(r.depth, camera, T, cc, &grid);
            occupancy.push_back(superquadricOccupancy(shapes, grid));
            const TriangleMesh sq_mesh = superquadricsMesh(shapes);
            row["chamfer_full_m"] =
                chamferDistance(samplePoints(sq_mesh, chamfer_points, rng), gt_full);
            row["chamfer_visible_m"] =
                chamferDistance(samplePoints(subMesh(sq_mesh, visibleTriangles(sq_mesh, camera, T)),
                                             chamfer_points, rng),
                                gt_vis_pts);
          }
          const OccupancyScores sc = scoreOccupancy(gt.tsdf.data, occupancy);
          row["iou"] = sc.iou;
          row["bce"] = sc.bce;
          row["chamfer_full_sq_m"] = chamferDistance(
              samplePoints(superquadricsMesh(shapes), chamfer_points, rng), gt_full);
          row["count"] = shapes.size();
          row["count_error"] =
              std::abs(static_cast<double>(shapes.size()) - rec.scene.objects.size());
          row["count_exact"] = shapes.size() == rec.scene.objects.size();
          if (!no_stability && !shapes.empty()) {
            const StabilityResult st = simulateStability(shapes);
            row["displacement_m"] = st.mean_displacement_m;
            row["stable"] = st.stable;
          }
          m.rows.push_back(row);
        }
      }
      bar.update(k + 1);
    }
    bar.finish();

    json results;
    results["dataset"] = dataset;
    results["dataset_seed"] = reader.info().seed;
    results["scenes"] = n;
    results["views"] = views;
    results["samples"] = samples;
    results["seed"] = seed;
    results["image"] = std::to_string(width) + "x" + std::to_string(height);
    results["noise"] = noise;
    results["chamfer_points"] = chamfer_points;
    results["config"] = perceptionYaml(base);
    if (!truth_stable.empty())
      results["ground_truth"] = {{"stable", mean(truth_stable)},
                                 {"displacement_m", mean(truth_displacement)}};
    for (const Method& m : methods) {
      json j = summarise(m.rows);
      j["model"] = m.perception ? m.perception->config().model_path : "";
      j["samples"] = m.perception ? m.perception->config().samples : 1;
      if (m.perception) j["config"] = perceptionYaml(m.perception->config());
      j["views"] = json(m.rows);
      results["methods"][m.name] = j;
    }
    std::ofstream f(output);
    if (!f) throw std::runtime_error("cannot write " + output);
    f << results.dump(1) << "\n";

    std::cout
        << "\n| method | CD visible (mm) | CD full (mm) | CD full, superquadrics (mm) | IoU | BCE "
           "| displacement (mm) | stable | objects exact "
           "|\n|---|---|---|---|---|---|---|---|---|\n";
    for (const Method& m : methods) {
      const json s = summarise(m.rows);
      auto val = [&](const char* key, double scale, int digits) {
        std::ostringstream o;
        o << std::fixed << std::setprecision(digits) << s[key]["mean"].get<double>() * scale;
        return o.str();
      };
      std::cout << "| " << m.name << " | " << val("chamfer_visible_m", 1000, 1) << " | "
                << val("chamfer_full_m", 1000, 1) << " | " << val("chamfer_full_sq_m", 1000, 1)
                << " | " << val("iou", 1, 3) << " | " << val("bce", 1, 3) << " | "
                << val("displacement_m", 1000, 1) << " | " << val("stable", 100, 0) << " % | "
                << val("count_exact", 100, 0) << " % |\n";
    }
    if (!truth_stable.empty())
      std::cout << "\nthe true piles under the same stability test: " << std::fixed
                << std::setprecision(0) << 100 * mean(truth_stable)
                << " % stable, mean displacement " << std::setprecision(1)
                << 1000 * mean(truth_displacement) << " mm\n";
    std::cout << "\n" << n << " scenes x " << views << " views; results: " << output << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_evaluate: error: " << e.what() << "\n";
    return 1;
  }
}
