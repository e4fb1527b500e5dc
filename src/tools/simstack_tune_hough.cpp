// simstack_tune_hough: chooses the Hough-voting parameters (perception.yaml's `hough:`
// section) for one model, on validation piles. How sharp a model's votes are decides which
// traversal threshold and mean-shift radius separate its objects, so the setting belongs to
// the model and is re-chosen whenever the model changes. The network runs once per view; the
// settings are then scored on its grids against the ground truth: the share of views whose
// instance count is exact first, then the voxel segmentation agreement. When the config enables
// the regrouping along the observed surface (`segments:`), it runs after each setting, as in
// the pipeline.
#include <omp.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cmath>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <optional>
#include <random>
#include <sstream>

#include "simstack/dataset/dataset.h"
#include "simstack/eval/segmentation.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/model/training_sample.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/tools/progress.h"
#include "simstack/tsdf/ground_truth.h"

using namespace simstack;

namespace {

/// The network's grids for one validation view and the ground truth on the same grid.
struct ViewGrids {
  Grid3<float> tsdf_m;
  Grid3<Vec3f> votes;
  std::vector<int> truth;  ///< object index per voxel, -1 free
  int objects = 0;
  std::optional<SurfaceSegments> segments;  ///< the view's convex patches, when regrouping
};

struct Score {
  HoughConfig hough;
  double exact = 0, abs_error = 0, under = 0, over = 0, agreement = 0;
};

bool better(const Score& a, const Score& b) {
  if (a.exact != b.exact) return a.exact > b.exact;
  return a.agreement > b.agreement;
}

// Scored as the pipeline decomposes: Hough voting, then the regrouping along the observed
// surface when the config enables it.
Score score(const std::vector<ViewGrids>& views, const HoughConfig& hough,
            const SurfaceSegmentConfig& segments) {
  Score s;
  s.hough = hough;
  for (const ViewGrids& v : views) {
    const InstanceSegmentation seg =
        findInstances(v.tsdf_m, v.votes, hough, segments, v.segments ? &*v.segments : nullptr);
    const int error = seg.size() - v.objects;
    s.exact += error == 0;
    s.under += error < 0;
    s.over += error > 0;
    s.abs_error += std::abs(error);
    s.agreement += segmentationAgreement(v.truth, seg.labels.data).agreement;
  }
  const double n = static_cast<double>(views.size());
  s.exact /= n;
  s.under /= n;
  s.over /= n;
  s.abs_error /= n;
  s.agreement /= n;
  return s;
}

bool sameSetting(const HoughConfig& a, const HoughConfig& b) {
  return a.refinement == b.refinement && a.min_traversals == b.min_traversals &&
         a.gamma == b.gamma && a.bandwidth_m == b.bandwidth_m &&
         a.min_instance_voxels == b.min_instance_voxels && a.min_vote_norm == b.min_vote_norm &&
         a.outside_tolerance_vox == b.outside_tolerance_vox &&
         a.reversed_vote_stop_vox == b.reversed_vote_stop_vox &&
         a.split_below_solidity == b.split_below_solidity &&
         (a.split_below_solidity == 0 || a.split_accept_solidity == b.split_accept_solidity);
}

std::string row(const Score& s) {
  std::ostringstream o;
  o << "| " << s.hough.refinement << " | " << s.hough.min_traversals << " | " << std::fixed
    << std::setprecision(3) << s.hough.bandwidth_m << " | " << s.hough.min_instance_voxels << " | "
    << std::setprecision(1) << s.hough.min_vote_norm << " | " << s.hough.reversed_vote_stop_vox
    << " | " << std::setprecision(2) << s.hough.split_below_solidity << " / "
    << s.hough.split_accept_solidity << " | " << std::setprecision(1) << 100 * s.exact << " % | "
    << 100 * s.under << " % | " << 100 * s.over << " % | " << std::setprecision(2) << s.abs_error
    << " | " << std::setprecision(3) << s.agreement << " |";
  return o.str();
}

std::string defaultPath(const char* relative) {
  return std::string(SIMSTACK_SOURCE_DIR) + "/" + relative;
}

}  // namespace

int main(int argc, char** argv) {
  std::string dataset, model, config_path = defaultPath("config/perception.yaml"), output;
  int views_per_scene = 2, scenes = 0, threads = 2, top = 10;
  uint64_t seed = 7;
  bool noise = false;
  std::vector<int> refinements = {3, 5, 8, 10}, traversals = {2, 3, 4, 5, 7, 10},
                   min_voxels = {10, 15, 25}, reversed_stops = {0};
  std::vector<double> bandwidths = {0.04, 0.05, 0.06, 0.07}, min_norms = {0.0, 0.3, 0.6};
  // The split test is off unless asked for: its values multiply the other settings.
  std::vector<double> split_below = {0.0}, split_accept = {0.9};
  CLI::App app{
      "Choose the Hough-voting parameters for a model on validation piles (a seed used neither "
      "for training nor for testing): the network runs once per rendered view, every "
      "combination of the listed values is scored by the share of views whose instance count "
      "is exact (then by voxel segmentation agreement), and the best is written into a copy of "
      "the perception config."};
  app.add_option("--dataset", dataset, "validation piles (simstack_generate)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--model", model, "model file (default: the config's)")->check(CLI::ExistingFile);
  app.add_option("--config", config_path, "perception config whose other sections are kept")
      ->capture_default_str()
      ->check(CLI::ExistingFile);
  app.add_option("--output", output, "perception config with the chosen hough section")->required();
  app.add_option("--views", views_per_scene, "random viewpoints per scene")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--scenes", scenes, "only the first N scenes (0 = all)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--seed", seed, "viewpoint seed")->capture_default_str();
  app.add_flag("--noise", noise, "Kinect-like sensor noise in the rendered views");
  app.add_option("--threads", threads, "threads")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--refinement", refinements, "fine cells per voxel to try")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--min-traversals", traversals, "mu values to try")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--bandwidth", bandwidths, "mean-shift radii to try (m)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--min-instance-voxels", min_voxels, "minimum instance sizes to try")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--min-vote-norm", min_norms,
                 "vote lengths to try below which a voxel casts no ray (blunt, unsure votes)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--reversed-stop", reversed_stops,
                 "consecutive voxels of reversed votes that stop a ray (0 = off) to try")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--split-below", split_below,
                 "split test: solidities below which an instance is cut (0 = off) to try")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--split-accept", split_accept,
                 "split test: joint solidities of the two parts that keep a cut, to try")
      ->capture_default_str()
      ->check(CLI::Range(0.01, 1.0));
  app.add_option("--top", top, "rows of the table")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  CLI11_PARSE(app, argc, argv);
  keepFreedMemoryForReuse();  // the network runs in this process
  try {
    // As written (relative model path kept), for the output; and resolved, for running.
    const PerceptionConfig original = loadPerceptionYaml(config_path, "");
    PerceptionConfig pc = loadPerceptionYaml(config_path, SIMSTACK_SOURCE_DIR);
    if (!model.empty()) pc.model_path = model;
    pc.threads = threads;
    // The product decomposes hypothesis 0, the mean scene (zero code): tune on that one.
    pc.samples = 1;
    pc.zero_code_first = true;
    pc.decompose_samples = 0;
    const ScenePerception perception(pc);
    const DatasetReader reader(dataset);
    const int n = scenes > 0 ? std::min(scenes, reader.size()) : reader.size();
    const PinholeCamera camera = scaledKinect(640, 480);

    std::vector<ViewGrids> views;
    ProgressBar bar("running the network", n);
    for (int k = 0; k < n; ++k) {
      const SceneRecord rec = reader.read(k);
      const DepthRenderer renderer(rec.scene);
      std::mt19937_64 rng(seed * 1000003ull + static_cast<uint64_t>(k));
      for (int v = 0; v < views_per_scene; ++v) {
        const Transform T = sampleViewpoint(rec.scene.surfaceCentroid(), ViewpointRange(), rng);
        const uint64_t noise_seed = rng();
        const RenderResult r = renderer.render(
            camera, T, noise ? SensorNoiseConfig::kinect(noise_seed) : SensorNoiseConfig());
        SceneEstimate est = perception.perceive(DepthView{r.depth, camera, T});
        const GroundTruthGrids gt =
            computeGroundTruth(rec.scene, est.grid, reader.info().truncation_m);
        ViewGrids g;
        g.tsdf_m = std::move(est.hypotheses[0].tsdf_m);
        g.votes = std::move(est.hypotheses[0].votes);
        g.truth.resize(gt.labels.data.size());
        for (size_t i = 0; i < g.truth.size(); ++i)
          g.truth[i] = static_cast<int>(gt.labels.data[i]) - 1;
        g.objects = static_cast<int>(rec.scene.objects.size());
        if (pc.segments.enabled)
          g.segments = segmentVisibleSurface(r.depth, camera, T, pc.min_pile_height_m, pc.segments);
        views.push_back(std::move(g));
      }
      bar.update(k + 1);
    }
    bar.finish();

    // The config's own setting is a candidate too, listed first: a tie keeps it, so the
    // chosen setting is never worse on these views than the one it replaces.
    HoughConfig current = pc.hough;
    current.threads = 1;  // the settings run in parallel instead
    std::vector<HoughConfig> settings = {current};
    for (int ref : refinements)
      for (int mu : traversals)
        for (double bw : bandwidths)
          for (int mv : min_voxels)
            for (double norm : min_norms)
              for (int stop : reversed_stops)
                for (double below : split_below)
                  for (double accept : split_accept) {
                    HoughConfig h = pc.hough;
                    h.reversed_vote_stop_vox = stop;
                    h.split_below_solidity = below;
                    h.split_accept_solidity = accept;
                    h.refinement = ref;
                    h.min_traversals = mu;
                    h.bandwidth_m = bw;
                    h.min_instance_voxels = mv;
                    h.min_vote_norm = norm;
                    h.threads = 1;                          // the settings run in parallel instead
                    if (sameSetting(h, current)) continue;  // already the first candidate
                    settings.push_back(h);
                  }
    if (views.empty()) throw std::runtime_error(dataset + " holds no scene to score on");
    std::vector<Score> scores(settings.size());
    std::exception_ptr failure;  // an exception must not leave the parallel loop
    ProgressBar sweep("scoring " + std::to_string(settings.size()) + " settings", settings.size());
    long done = 0;
#pragma omp parallel for schedule(dynamic) num_threads(threads)
    for (long i = 0; i < static_cast<long>(settings.size()); ++i) {
      try {
        scores[i] = score(views, settings[i], pc.segments);
      } catch (...) {
#pragma omp critical
        if (!failure) failure = std::current_exception();
      }
#pragma omp critical
      sweep.update(++done);
    }
    sweep.finish();
    if (failure) std::rethrow_exception(failure);
    const Score before = scores.front();
    std::stable_sort(scores.begin(), scores.end(), better);

    std::cout << "\n"
              << views.size() << " views (" << n << " scenes x " << views_per_scene << "), model "
              << pc.model_path << "\n\n"
              << "| refinement | mu | bandwidth (m) | min voxels | min vote norm | reversed stop | "
                 "split below / accept | count exact | under | over | mean abs error | voxel "
                 "agreement |\n"
                 "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    for (int i = 0; i < std::min<int>(top, scores.size()); ++i) std::cout << row(scores[i]) << "\n";
    std::cout << "\nthe config's setting (" << config_path << "):\n" << row(before) << "\n";

    PerceptionConfig tuned = original;
    tuned.hough = scores.front().hough;
    // Relative paths in a config are read from the package directory: write the model absolute.
    if (!model.empty()) tuned.model_path = std::filesystem::absolute(model).string();
    std::ofstream f(output);
    if (!f) throw std::runtime_error("cannot write " + output);
    f << "# simstack_tune_hough on " << dataset << " (" << views.size() << " views): count exact "
      << std::fixed << std::setprecision(3) << scores.front().exact << ", voxel agreement "
      << scores.front().agreement << "\n"
      << perceptionYaml(tuned) << "\n";
    std::cout << "\nchosen setting written to " << output << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_tune_hough: error: " << e.what() << "\n";
    return 1;
  }
}
