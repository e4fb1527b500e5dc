// simstack_evaluate: the paper's single-view protocol (DESIGN.md section 5) for one or more
// trained models on a test dataset. Today: expected occupancy (BCE, eq. 8) and IoU at 0.5.
#include <CLI/CLI.hpp>

#include <cmath>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>

#include "simstack/dataset/dataset.h"
#include "simstack/eval/occupancy.h"
#include "simstack/model/cvae_inference.h"
#include "simstack/model/training_sample.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/tools/progress.h"

using namespace simstack;

namespace {
struct Stats {
  std::vector<double> iou, bce;
  static double mean(const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x;
    return v.empty() ? 0.0 : s / v.size();
  }
  static double stddev(const std::vector<double>& v) {
    const double m = mean(v);
    double s = 0;
    for (double x : v) s += (x - m) * (x - m);
    return v.size() > 1 ? std::sqrt(s / (v.size() - 1)) : 0.0;
  }
};
}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> models;
  std::string dataset, output, mesh_dir;
  int views = 3, samples = 3, scenes = 0, threads = 2;
  uint64_t seed = 7;
  bool noise = false;
  CLI::App app{
      "Evaluate trained models on a test dataset: every scene from random viewpoints in the "
      "paper's ranges, "
      "S latent samples per view (1 for the FC baseline); writes JSON."};
  app.add_option("--model", models, "model file(s), e.g. models/simstack_r32.pt models/fc_r32.pt")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--dataset", dataset, "test dataset (a seed never used for training)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--output", output, "results JSON")->required();
  app.add_option("--views", views, "viewpoints per scene")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--samples", samples, "latent samples per viewpoint")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--scenes", scenes, "evaluate only the first N scenes (0 = all)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--seed", seed, "viewpoint and code seed")->capture_default_str();
  app.add_option("--ycb", mesh_dir, "mesh directory for YCB datasets");
  app.add_flag("--noise", noise, "Kinect-like sensor noise in the rendered views");
  app.add_option("--threads", threads, "torch threads")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  try {
    const DatasetReader reader(dataset, mesh_dir);
    const int n = scenes > 0 ? std::min(scenes, reader.size()) : reader.size();
    nlohmann::json results;
    results["dataset"] = dataset;
    results["dataset_seed"] = reader.info().seed;
    results["scenes"] = n;
    results["views"] = views;
    results["seed"] = seed;
    results["image"] = "640x480";
    results["noise"] = noise;
    for (const auto& path : models) {
      const CvaeInference net(path, threads);
      const CvaeConfig& c = net.config();
      const int s_count = c.architecture == "fc" ? 1 : samples;
      const TrainingSampleBuilder builder(c, scaledKinect(640, 480), noise);
      Stats stats;
      ProgressBar bar("evaluating " + path, n);
      for (int k = 0; k < n; ++k) {
        const SceneRecord rec = reader.read(k);
        std::mt19937_64 rng(seed * 1000003ull + static_cast<uint64_t>(k));
        for (int v = 0; v < views; ++v) {
          const TrainingSample t = builder.build(rec, rng);
          Grid3<float> tsdf(t.grid, 0.0f), weight(t.grid, 0.0f);
          const size_t nv = tsdf.data.size();
          for (size_t i = 0; i < nv; ++i) {
            tsdf.data[i] = t.partial[i] * static_cast<float>(c.truncation_m());
            weight.data[i] = t.partial[nv + i];
          }
          const auto preds = net.predict(tsdf, weight, s_count, rng());
          std::vector<std::vector<float>> p;
          for (const auto& pr : preds) p.push_back(pr.tsdf_m.data);
          const OccupancyScores sc = scoreOccupancy(t.tsdf, p);
          stats.iou.push_back(sc.iou);
          stats.bce.push_back(sc.bce);
        }
        bar.update(k + 1);
      }
      bar.finish();
      nlohmann::json m;
      m["model"] = path;
      m["architecture"] = c.architecture;
      m["resolution"] = c.resolution;
      m["samples"] = s_count;
      m["iou_mean"] = Stats::mean(stats.iou);
      m["iou_std"] = Stats::stddev(stats.iou);
      m["bce_mean"] = Stats::mean(stats.bce);
      m["bce_std"] = Stats::stddev(stats.bce);
      results["methods"][c.architecture] = m;
      std::cout << c.architecture << " (" << path << "): IoU " << m["iou_mean"].get<double>()
                << " +- " << m["iou_std"].get<double>() << ", BCE " << m["bce_mean"].get<double>()
                << " +- " << m["bce_std"].get<double>() << " over " << stats.iou.size()
                << " views\n";
    }
    std::ofstream f(output);
    if (!f) throw std::runtime_error("cannot write " + output);
    f << results.dump(2) << "\n";
    std::cout << "results: " << output << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_evaluate: error: " << e.what() << "\n";
    return 1;
  }
}
