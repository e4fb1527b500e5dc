// simstack_evaluate: the paper's single-view protocol (docs/design.md section 6, Table 1) for
// trained models and the classical baseline in one run on the same rendered views
// (eval/evaluator.h), or the labelled real scenes (eval/real_scenes.h).
#include <CLI/CLI.hpp>

#include <fstream>
#include <iostream>
#include <optional>

#include "cli_checks.h"
#include "perception_options.h"
#include "progress.h"
#include "sensor_option.h"
#include "simstack/io/staged_output.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/offline/eval/evaluated_methods.h"
#include "simstack/offline/eval/real_scenes.h"

using namespace simstack;

namespace {

/// Writes `j` into its staged file (ResultFiles::commit puts it in place).
void writeJson(StagedFile& file, const std::string& path, const nlohmann::json& j) {
  std::ofstream f(file.path());
  f << j.dump(1) << "\n";
  f.close();  // a failed flush shows only here
  if (!f) throw std::runtime_error("cannot write " + path);
}

/// The result files, made (with their directories) before the work, so that a path that
/// cannot be written, or one that would replace an input or each other, fails at once rather
/// than after the evaluation.
struct ResultFiles {
  ResultFiles(const std::string& output, const std::string& summary,
              std::vector<std::string> inputs) {
    requireNotAnInput("--output", output, inputs);
    requireNotAnInput("--summary", summary, inputs);
    requireNotAnInput("--summary", summary, {output}, "the --output file");
    results.emplace(output);
    if (!summary.empty()) this->summary.emplace(summary);
  }
  /// Both files in place once both are written: a run that fails keeps the earlier ones.
  void commit() {
    results->commit();
    if (summary) summary->commit();
  }
  std::optional<StagedFile> results;
  std::optional<StagedFile> summary;
};

/// Every method on the dataset's views; writes the results and prints the table.
void runDataset(const DatasetReader& reader, const std::string& dataset,
                const std::vector<std::unique_ptr<EvaluatedMethod>>& methods,
                const EvaluationOptions& o, const std::string& output, const std::string& summary,
                ResultFiles& files) {
  std::vector<EvaluatedMethod*> run;
  for (const auto& m : methods) run.push_back(m.get());
  const int scenes = o.scenes > 0 ? std::min(o.scenes, reader.size()) : reader.size();
  ProgressBar bar("evaluating " + std::to_string(run.size()) +
                      (run.size() == 1 ? " method" : " methods") + ", scenes",
                  scenes);
  const EvaluationResults results =
      evaluateDataset(reader, run, o, [&](int done, int) { bar.update(done); });
  bar.finish();
  for (const bool with_views : {true, false}) {
    nlohmann::json j = resultsJson(results, with_views);
    j["dataset"] = dataset;
    if (with_views)
      writeJson(*files.results, output, j);
    else if (files.summary)
      writeJson(*files.summary, summary, j);
  }
  files.commit();
  std::cout << "\n"
            << resultsTable(results) << "\n"
            << results.scenes << " scenes x " << o.views << " views"
            << (o.views_per_estimate > 1
                    ? " of " + std::to_string(o.views_per_estimate) + " posed views each"
                    : std::string())
            << "; results: " << output << "\n";
}

/// Every model, and the classical baseline unless `classical` is false, on the labelled real
/// scenes of `real_dir`; writes the results and prints the table.
void runRealScenes(const std::vector<PerceptionConfig>& configs, bool classical,
                   const std::string& real_dir, int max_scenes, const std::string& output,
                   const std::string& summary, ResultFiles& files) {
  std::vector<std::unique_ptr<EvaluatedMethod>> methods;
  for (const PerceptionConfig& c : configs) {
    auto m = std::make_unique<NetworkMethod>(c, true);
    for (const auto& other : methods)
      if (other->name() == m->name()) m->rename(m->name() + "_" + std::to_string(methods.size()));
    methods.push_back(std::move(m));
  }
  if (classical) {  // it takes every point; its grid only serves the unused occupancy
    ClassicalConfig cc;
    cc.threads = configs.front().threads;
    cc.fit = configs.front().fit;
    methods.push_back(std::make_unique<ClassicalMethod>(cc, 0.64, 32, true));
  }
  std::vector<EvaluatedMethod*> run;
  for (const auto& m : methods) run.push_back(m.get());
  int scenes = static_cast<int>(labelledCloudFiles(real_dir).size());
  if (max_scenes > 0) scenes = std::min(scenes, max_scenes);
  ProgressBar bar(
      "real scenes, " + std::to_string(run.size()) + (run.size() == 1 ? " method" : " methods"),
      scenes);
  const std::vector<RealMethodResults> results = evaluateRealScenes(
      real_dir, run, [&](int done, int) { bar.update(done); }, max_scenes);
  bar.finish();
  nlohmann::json j = {{"real_dir", real_dir}, {"methods", realScenesJson(results)}};
  writeJson(*files.results, output, j);
  if (files.summary) {
    for (auto& [name, m] : j["methods"].items()) m.erase("scenes");
    writeJson(*files.summary, summary, j);
  }
  files.commit();
  std::cout << "\n"
            << realScenesTable(results) << "\n"
            << scenes << " scenes; results: " << output << "\n";
}

/// The options of the rendered views and their scores (`o`), and the intrinsics' text.
void addViewOptions(CLI::App& app, EvaluationOptions* o, std::string* intrinsics) {
  app.add_option("--width", o->width,
                 "rendered view width (pixels; the protocol's 640): fx scales with the width, fy "
                 "with the height, so keep 4:3 for square pixels")
      ->capture_default_str()
      ->check(CLI::Range(16, 4096));
  app.add_option("--height", o->height, "rendered view height (the protocol's 480)")
      ->capture_default_str()
      ->check(CLI::Range(16, 4096));
  app.add_option("--intrinsics", *intrinsics,
                 "fx,fy,cx,cy (pixels) of another camera for the --width x --height views, "
                 "instead of the scaled Kinect: its field of view (the noise is --sensor's)");
  app.add_option("--views", o->views, "viewpoints per scene")
      ->capture_default_str()
      ->check(FinitePositive);
  app.add_option("--scenes", o->scenes, "evaluate only the first N scenes (0 = all)")
      ->capture_default_str()
      ->check(FiniteNonNegative);
  app.add_option("--seed", o->seed, "viewpoint and Chamfer-sample seed")
      ->capture_default_str()
      ->transform(SeedNumber);
  CLI::Option* noise_flag =
      app.add_flag("--noise", o->noise, "sensor noise in the rendered views (--sensor's)");
  addSensorOption(app, &o->sensor, "with --noise, ")->needs(noise_flag);
  app.add_option("--chamfer-points", o->chamfer_points, "surface samples per Chamfer set")
      ->capture_default_str()
      ->check(FinitePositive)
      ->check(CLI::Range(1, 1000000));
  app.add_option("--seen-pixels", o->seen_pixels,
                 "a true object counts as seen from this many valid pixels of the view "
                 "(count_exact_seen in the summary: the count against the objects seen)")
      ->capture_default_str()
      ->check(FiniteNonNegative);
}

}  // namespace

constexpr const char* kDescription =
    "Evaluate trained models and the classical baseline on a test dataset (docs/design.md "
    "section 6): every scene from random viewpoints in the paper's ranges, S latent samples "
    "per view (1 for the FC baselines); writes JSON and prints the table.";

int main(int argc, char** argv) {
  std::string dataset, output, summary, mesh_dir, real_dir, intrinsics;
  EvaluationOptions o;
  bool no_classical = false, no_stability = false;
  int refine_iterations = 0;
  CLI::App app{kDescription};
  const PerceptionOptions perception(app, {true, false, false});
  app.add_option("--dataset", dataset, "test dataset (a seed never used for training)")
      ->check(CLI::ExistingFile);
  app.add_option("--real", real_dir,
                 "labelled PCDs (mOSD: label / 10 the object) instead of --dataset: Overlap "
                 "P/R/F, %75 and object counts, overall and by mOSD category")
      ->check(CLI::ExistingDirectory);
  app.add_option("--output", output, "results JSON (every view)")->required()->check(WritablePath);
  app.add_option("--summary", summary, "also a small JSON: per method its means and bins")
      ->check(WritablePath);
  addViewOptions(app, &o, &intrinsics);
  app.add_option("--ycb", mesh_dir, "mesh directory for YCB datasets")
      ->check(CLI::ExistingDirectory);
  app.add_flag("--overhead", o.overhead,
               "views from above, as on a pick station (elevation 60-89 degrees, 0.6-1.0 m "
               "away) instead of the paper's ranges");
  app.add_option("--multi-view", o.views_per_estimate,
                 "posed views per estimate (the paper's multi-view experiment): the first as "
                 "without it, the others turned about the pile by 360/K degrees each; each model "
                 "conditioned on all views and on the first alone (_first), and TSDF fusion; no "
                 "classical baseline")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  app.add_option("--refine", refine_iterations,
                 "with --multi-view: also each C-VAE with this many Adam steps fitting its codes "
                 "to every view (_opt, _first_opt; the config's refine_iterations)")
      ->check(FinitePositive);
  app.add_flag("--no-classical", no_classical, "skip the classical baseline");
  app.add_flag("--no-stability", no_stability, "skip the physics stability test");
  readIntegersInDecimal(app);
  CLI11_PARSE(app, argc, argv);
  keepFreedMemoryForReuse();  // the network runs in this process
  if (dataset.empty() == real_dir.empty()) {
    std::cerr << "simstack_evaluate: give either --dataset or --real\n";
    return 2;
  }
  o.stability = !no_stability;
  if (refine_iterations > 0 && o.views_per_estimate < 2) {
    std::cerr << "simstack_evaluate: --refine needs --multi-view 2 or more\n";
    return 2;
  }
  // The rendered views' options mean nothing to a real scene, one view of its own camera.
  for (const char* name :
       {"--multi-view", "--intrinsics", "--views", "--width", "--height", "--noise", "--sensor",
        "--overhead", "--ycb", "--chamfer-points", "--seen-pixels", "--seed"})
    if (!real_dir.empty() && app.get_option(name)->count() > 0) {
      std::cerr << "simstack_evaluate: error: " << name
                << " needs --dataset (a real scene is one view of its own camera)\n";
      return 2;
    }
  try {
    if (!intrinsics.empty()) o.camera = parseIntrinsics(intrinsics, o.width, o.height);
    std::vector<std::string> inputs = perception.inputFiles();
    inputs.push_back(dataset);
    if (!real_dir.empty())  // the labelled scenes are inputs too
      for (const std::string& f : labelledCloudFiles(real_dir)) inputs.push_back(f);
    ResultFiles files(output, summary, inputs);
    const std::vector<PerceptionConfig> configs = perception.configs();
    if (!real_dir.empty()) {
      runRealScenes(configs, !no_classical, real_dir, o.scenes, output, summary, files);
      return 0;
    }
    const DatasetReader reader(dataset, mesh_dir);
    const auto methods =
        o.views_per_estimate > 1
            ? multiViewMethods(configs, refine_iterations, reader.info().extent_m,
                               reader.info().resolution, reader.info().truncation_m)
            : evaluatedMethods(configs, !no_classical, reader.info().extent_m,
                               reader.info().resolution);
    runDataset(reader, dataset, methods, o, output, summary, files);
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_evaluate: error: " << e.what() << "\n";
    return 1;
  }
}
