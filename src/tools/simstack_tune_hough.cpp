// simstack_tune_hough: chooses the Hough-voting setting of one model on validation piles
// (pipeline/hough_tuning.h) and writes it as the `perception:` section of the model's card.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <fstream>
#include <iomanip>
#include <iostream>

#include "perception_options.h"
#include "progress.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/pipeline/hough_tuning.h"

using namespace simstack;

int main(int argc, char** argv) {
  std::string dataset, output;
  int views_per_scene = 2, scenes = 0, top = 10;
  uint64_t seed = 7;
  bool noise = false;
  HoughSweep sweep;
  CLI::App app{
      "Choose the Hough-voting setting of a model on validation piles (a seed used neither for "
      "training nor for testing): the network runs once per rendered view, every combination "
      "of the listed values is scored by the share of views whose instance count is exact "
      "(then by voxel segmentation agreement), and the best is written as the perception: "
      "section of the model's card (models/<name>.yaml)."};
  const PerceptionOptions perception(app, {false, false, false});
  app.add_option("--dataset", dataset, "validation piles (simstack_generate)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--output", output, "YAML with the model card's perception: section")->required();
  app.add_option("--views", views_per_scene, "random viewpoints per scene")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--scenes", scenes, "only the first N scenes (0 = all)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--seed", seed, "viewpoint seed")->capture_default_str();
  app.add_flag("--noise", noise, "Kinect-like sensor noise in the rendered views");
  auto values = [&](const char* name, auto& list, const char* what, CLI::Validator check) {
    app.add_option(name, list, what)->capture_default_str()->check(check);
  };
  values("--refinement", sweep.refinements, "fine cells per voxel to try", CLI::PositiveNumber);
  values("--min-traversals", sweep.traversals, "mu values to try", CLI::NonNegativeNumber);
  values("--bandwidth", sweep.bandwidths, "mean-shift radii to try (m)", CLI::PositiveNumber);
  values("--min-instance-voxels", sweep.min_voxels, "minimum instance sizes to try",
         CLI::NonNegativeNumber);
  values("--min-vote-norm", sweep.min_norms,
         "vote lengths to try below which a voxel casts no ray (blunt, unsure votes)",
         CLI::Range(0.0, 1.0));
  values("--reversed-stop", sweep.reversed_stops,
         "consecutive voxels of reversed votes that stop a ray (0 = off) to try",
         CLI::NonNegativeNumber);
  values("--split-below", sweep.split_below,
         "split test: solidities below which an instance is cut (0 = off) to try",
         CLI::Range(0.0, 1.0));
  values("--split-accept", sweep.split_accept,
         "split test: joint solidities of the two parts that keep a cut, to try",
         CLI::Range(0.01, 1.0));
  app.add_option("--top", top, "rows of the table")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  CLI11_PARSE(app, argc, argv);
  keepFreedMemoryForReuse();  // the network runs in this process
  try {
    const PerceptionConfig pc = perception.config();
    const DatasetReader reader(dataset);
    ProgressBar bar("running the network",
                    scenes > 0 ? std::min(scenes, reader.size()) : reader.size());
    const std::vector<TuningView> views = tuningViews(reader, pc, scenes, views_per_scene, seed,
                                                      noise, [&](int k, int) { bar.update(k); });
    bar.finish();
    // The model's own setting is the first candidate: a tie keeps it, so the chosen setting is
    // never worse on these views than the one it replaces.
    const std::vector<HoughConfig> candidates = houghCandidates(pc.hough, sweep);
    ProgressBar bar2("scoring " + std::to_string(candidates.size()) + " settings",
                     static_cast<long>(candidates.size()));
    std::vector<HoughScore> scores = scoreHoughSettings(
        views, candidates, pc.segments, pc.threads, [&](long done, long) { bar2.update(done); });
    bar2.finish();
    const HoughScore before = scores.front();
    std::stable_sort(scores.begin(), scores.end(), betterHoughScore);

    std::cout << "\n"
              << views.size() << " views, model " << pc.model_path << "\n\n"
              << houghScoreHeader() << "\n";
    for (int i = 0; i < std::min<int>(top, scores.size()); ++i)
      std::cout << houghScoreRow(scores[i]) << "\n";
    std::cout << "\nthe model's setting ("
              << (pc.model_card_path.empty() ? "defaults: no model card" : pc.model_card_path)
              << "):\n"
              << houghScoreRow(before) << "\n";
    std::ofstream f(output);
    f << "# simstack_tune_hough on " << dataset << " (" << views.size() << " views): count exact "
      << std::fixed << std::setprecision(3) << scores.front().exact << ", voxel agreement "
      << scores.front().agreement << "\n# the perception: section of "
      << modelCardPath(pc.model_path) << "\n"
      << modelCardPerceptionYaml(pc.samples, scores.front().hough) << "\n";
    if (!f) throw std::runtime_error("cannot write " + output);
    std::cout << "\nchosen setting written to " << output << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_tune_hough: error: " << e.what() << "\n";
    return 1;
  }
}
