// simstack_tune_hough: chooses the Hough-voting setting of one model on validation piles
// (offline/tuning/hough_tuning.h) and writes it as a model card's `perception:` section to paste.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <iterator>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "cli_checks.h"
#include "perception_options.h"
#include "progress.h"
#include "simstack/io/staged_output.h"
#include "simstack/io/yaml_file.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/offline/tuning/hough_tuning.h"

using namespace simstack;

namespace {

/// The views of every dataset in turn; `ends[d]` is where dataset d's views end.
std::vector<TuningView> pooledViews(const std::vector<std::string>& datasets,
                                    const std::string& mesh_dir, const PerceptionConfig& pc,
                                    int scenes, int views_per_scene, uint64_t seed, bool noise,
                                    std::vector<size_t>* ends) {
  // Every file opened first, so that a bad one is named before any network runs.
  std::vector<std::unique_ptr<DatasetReader>> readers;
  for (const std::string& dataset : datasets)
    readers.push_back(std::make_unique<DatasetReader>(dataset, mesh_dir));
  std::vector<TuningView> views;
  for (size_t d = 0; d < datasets.size(); ++d) {
    const DatasetReader& reader = *readers[d];
    ProgressBar bar("running the network on " + datasets[d],
                    scenes > 0 ? std::min(scenes, reader.size()) : reader.size());
    std::vector<TuningView> more = tuningViews(reader, pc, scenes, views_per_scene, seed, noise,
                                               [&](int k, int) { bar.update(k); });
    bar.finish();
    std::move(more.begin(), more.end(), std::back_inserter(views));
    ends->push_back(views.size());
  }
  return views;
}

/// Count exact on each dataset's views alone, for the chosen setting and the model's own.
void reportPerDataset(const std::vector<std::string>& datasets,
                      const std::vector<TuningView>& views, const std::vector<size_t>& ends,
                      const HoughScore& chosen, const HoughScore& own, const PerceptionConfig& pc) {
  std::cout << "\nper dataset, count exact: chosen / the model's setting\n";
  for (size_t d = 0; d < datasets.size(); ++d) {
    const std::vector<TuningView> part(views.begin() + (d == 0 ? 0 : ends[d - 1]),
                                       views.begin() + ends[d]);
    std::cout << "  " << datasets[d] << " (" << part.size() << " views): ";
    if (part.empty()) {
      std::cout << "no views\n";
      continue;
    }
    const double a = scoreHoughSetting(part, chosen.hough, pc.segments, pc.crowded).exact;
    const double b = scoreHoughSetting(part, own.hough, pc.segments, pc.crowded).exact;
    std::cout << std::fixed << std::setprecision(1) << 100 * a << " % / " << 100 * b << " %\n";
  }
}

/// Whether the perception config file sets hough: (then it overrides every model card's).
bool configSetsHough(const std::string& config_path) {
  const YAML::Node hough = loadYamlFile(config_path, "perception config")["hough"];
  return hough && hough.IsMap() && hough.size() > 0;  // an empty hough: sets nothing
}

/// The best `top` settings, then the one in effect (the model's own, or the config's).
void printScores(size_t views, const PerceptionConfig& pc, const std::string& config_path,
                 const std::vector<HoughScore>& scores, const HoughScore& own, int top) {
  std::cout << "\n"
            << views << " views, model " << pc.model_path << "\n\n"
            << houghScoreHeader() << "\n";
  for (int i = 0; i < std::min<int>(top, scores.size()); ++i)
    std::cout << houghScoreRow(scores[i]) << "\n";
  std::string source = "the model's setting (defaults: no model card)";
  if (configSetsHough(config_path)) {
    source = "the setting in effect (the hough: of " + config_path +
             ", which overrides the model card's)";
  } else if (!pc.model_card_path.empty()) {
    const YAML::Node card = loadYamlFile(pc.model_card_path, "model card");
    source = "the model's setting (" +
             (card["perception"]["hough"] ? pc.model_card_path
                                          : "defaults: " + pc.model_card_path + " has no hough:") +
             ")";
  }
  std::cout << "\n" << source << ":\n" << houghScoreRow(own) << "\n";
}

/// The chosen setting as a model card's perception: section, under a comment saying where it
/// was chosen and how it scored.
std::string chosenSection(const std::vector<std::string>& datasets, size_t views,
                          const HoughScore& best, int samples) {
  std::string sets;
  for (const std::string& d : datasets) sets += (sets.empty() ? "" : " + ") + d;
  std::ostringstream out;
  out << "# chosen by simstack_tune_hough on " << sets << " (" << views << " views): count exact "
      << std::fixed << std::setprecision(3) << best.exact << ", voxel agreement " << best.agreement
      << "\n"
      << modelCardPerceptionYaml(samples, best.hough) << "\n";
  return out.str();
}

/// The values of each Hough field to try, as repeatable options.
void addSweepOptions(CLI::App& app, HoughSweep& sweep) {
  auto values = [&app](const char* name, auto& list, const char* what, CLI::Validator check) {
    app.add_option(name, list, what)->capture_default_str()->check(check);
  };
  values("--refinement", sweep.refinements, "fine cells per voxel to try", CLI::Range(1, 16));
  values("--min-traversals", sweep.traversals, "mu values to try", FiniteNonNegative);
  values("--bandwidth", sweep.bandwidths, "mean-shift radii to try (m)",
         FinitePositive & CLI::Range(0.001, 10.0));
  values("--min-instance-voxels", sweep.min_voxels, "minimum instance sizes to try (>= 1)",
         FinitePositive);
  values("--min-vote-norm", sweep.min_norms,
         "vote lengths to try below which a voxel casts no ray (blunt, unsure votes)",
         finiteNumber([](double v) { return v >= 0.0 && v < 1.0; }, "in [0, 1)", "[0,1)"));
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> datasets;
  std::string output, mesh_dir;
  int views_per_scene = 2, scenes = 0, top = 10;
  uint64_t seed = 7;
  bool noise = false, allow_held_out = false;
  HoughSweep sweep;
  CLI::App app{
      "Choose the Hough-voting setting of a model on validation piles (a seed used neither for "
      "training nor for testing): the network runs once per rendered view, every combination "
      "of the listed values is scored by the share of views whose instance count is exact "
      "(then by voxel segmentation agreement), and the best is written to --output as a model "
      "card's perception: section, to paste into the model's card (models/<name>.yaml) in "
      "place of the card's own. Several --dataset files pool their "
      "views (piles of 3-4 objects and of 5-8, say), so that one setting serves both."};
  const PerceptionOptions perception(app, {false, false, false});
  app.add_option("--dataset", datasets, "validation piles (simstack_generate); repeatable")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option(
         "--ycb", mesh_dir,
         "the mesh directory of YCB datasets among --dataset (<dir>/<object>/nontextured.stl)")
      ->check(CLI::ExistingDirectory);
  app.add_option("--output", output, "YAML with the model card's perception: section")
      ->required()
      ->check(WritablePath);
  app.add_option("--views", views_per_scene, "random viewpoints per scene")
      ->capture_default_str()
      ->check(FinitePositive);
  app.add_option("--scenes", scenes, "only the first N scenes of each dataset (0 = all)")
      ->capture_default_str()
      ->check(FiniteNonNegative);
  app.add_option("--seed", seed, "viewpoint seed")->capture_default_str()->transform(SeedNumber);
  app.add_flag("--noise", noise, "Kinect-like sensor noise in the rendered views");
  app.add_flag("--allow-held-out", allow_held_out,
               "tune on piles of a held-out test seed all the same (their figures then measure "
               "what was tuned on them)");
  addSweepOptions(app, sweep);
  app.add_option("--top", top, "rows of the table")->capture_default_str()->check(FinitePositive);
  readIntegersInDecimal(app);
  CLI11_PARSE(app, argc, argv);
  keepFreedMemoryForReuse();  // the network runs in this process
  try {
    std::vector<std::string> inputs = perception.inputFiles();
    inputs.insert(inputs.end(), datasets.begin(), datasets.end());
    requireNotAnInput("--output", output, inputs);
    if (!allow_held_out) refuseHeldOutDatasets(datasets, "tune on validation");
    StagedFile written(output);  // a path that cannot be written fails now, not after the sweep
    const PerceptionConfig pc = perception.config();
    // The model's own setting is the first candidate: a tie keeps it, so the chosen setting is
    // never worse on these views than the one it replaces. Each is checked before the network
    // runs on the views.
    const std::vector<HoughConfig> candidates = houghCandidates(pc.hough, sweep);
    for (const HoughConfig& c : candidates) c.validate();
    std::vector<size_t> ends;  // each dataset's views end here
    const std::vector<TuningView> views =
        pooledViews(datasets, mesh_dir, pc, scenes, views_per_scene, seed, noise, &ends);
    ProgressBar bar2("scoring " + std::to_string(candidates.size()) + " settings",
                     static_cast<long>(candidates.size()));
    std::vector<HoughScore> scores =
        scoreHoughSettings(views, candidates, pc.segments, pc.crowded, pc.threads,
                           [&](long done, long) { bar2.update(done); });
    bar2.finish();
    const HoughScore before = scores.front();
    std::stable_sort(scores.begin(), scores.end(), betterHoughScore);

    printScores(views.size(), pc, perception.configPath(), scores, before, top);
    if (datasets.size() > 1) reportPerDataset(datasets, views, ends, scores.front(), before, pc);
    const std::string chosen = chosenSection(datasets, views.size(), scores.front(), pc.samples);
    std::ofstream f(written.path());
    f << "# for the card " << modelCardPath(pc.model_path) << "\n" << chosen;
    f.close();  // a failed flush shows only here
    if (!f) throw std::runtime_error("cannot write " + output);
    written.commit();
    std::cout << "\nchosen setting written to " << output << ": paste its perception: section "
              << "into " << modelCardPath(pc.model_path) << " in place of the card's own";
    if (configSetsHough(perception.configPath()))
      std::cout << ", and remove the hough: of " << perception.configPath()
                << ", which overrides every model's";
    std::cout << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_tune_hough: error: " << e.what() << "\n";
    return 1;
  }
}
