// simstack_evaluate_grasps: what the grasp ranking is worth (eval/grasp_evaluation.h): grasps
// chosen on each method's estimate of generated piles, executed in the true piles.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <fstream>
#include <iostream>

#include "cli_checks.h"
#include "perception_options.h"
#include "progress.h"
#include "sensor_option.h"
#include "simstack/io/staged_output.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/offline/eval/evaluated_methods.h"
#include "simstack/offline/eval/grasp_evaluation.h"

using namespace simstack;

namespace {

/// The network of `c` with `hypotheses` of its samples decomposed; more hypotheses than it
/// draws distinct samples is an error that says why, rather than a run reporting fewer.
std::unique_ptr<NetworkMethod> networkMethod(PerceptionConfig c, int hypotheses) {
  c.decompose_samples = std::min(std::max(c.decompose_samples, hypotheses), c.samples);
  auto method = std::make_unique<NetworkMethod>(c);
  const std::string asked = "--hypotheses " + std::to_string(hypotheses) + ": " + c.model_path;
  if (hypotheses > 1 && method->architecture() != "cvae")
    throw std::runtime_error(asked +
                             " has no latent code: one scene; take the C-VAE (--model "
                             "models/simstack_r32.pt)");
  if (hypotheses > c.samples)
    throw std::runtime_error(asked + " draws " + std::to_string(c.samples) +
                             " samples; raise --samples");
  return method;
}

/// The methods compared, as the node runs them (hypothesis 0 the mean scene, `hypotheses` of
/// them decomposed): one per model, two of one architecture named apart, then the classical
/// baseline when `classical`.
std::vector<std::unique_ptr<EvaluatedMethod>> graspMethods(const PerceptionOptions& perception,
                                                           int hypotheses, bool classical,
                                                           const DatasetInfo& data) {
  std::vector<std::unique_ptr<EvaluatedMethod>> methods;
  for (const PerceptionConfig& c : perception.configs()) {
    auto m = networkMethod(c, hypotheses);
    m->rename(distinctName(m->name(), methods));
    methods.push_back(std::move(m));
  }
  if (classical) {
    ClassicalConfig cc;
    cc.threads = perception.config().threads;
    cc.fit = perception.config().fit;
    methods.push_back(std::make_unique<ClassicalMethod>(cc, data.extent_m, data.resolution));
  }
  return methods;
}

/// How seals are judged, and the perturbed copies.
void addSealOptions(CLI::App& app, GraspEvaluationOptions* o, bool* superquadric_seal) {
  CLI::Option* copies =
      app.add_option("--perturbed", o->ranking.perturbation.copies,
                     "perturbed copies of the estimate each candidate is also pulled in (the "
                     "oracle's ranking on the true pile takes none)")
          ->capture_default_str()
          ->check(CLI::Range(0, 64));
  app.add_flag("--best-in-truth", o->best_in_truth,
               "also pick each estimate's candidate whose pull does best in the true pile (what "
               "a perfect ranking of those candidates would do)");
  PerturbationConfig& p = o->ranking.perturbation;
  app.add_option("--perturb-position", p.position_m,
                 "standard deviation of a copy's shift across the table (m)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 0.1))
      ->needs(copies);
  app.add_option("--perturb-rotation", p.rotation_deg,
                 "standard deviation of a copy's turn about a random axis (degrees)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 45.0))
      ->needs(copies);
  app.add_option("--perturb-scale", p.scale_share,
                 "standard deviation of a copy's semi-axes, as a share of each")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 0.5))
      ->needs(copies);
  // The copies' spreads do nothing without copies: refused, not recorded as if used.
  app.final_callback([&app, o] {
    const size_t spreads = app.count("--perturb-position") + app.count("--perturb-rotation") +
                           app.count("--perturb-scale");
    if (o->ranking.perturbation.copies == 0 && spreads > 0)
      throw CLI::RequiresError(
          "--perturb-position, --perturb-rotation and --perturb-scale need --perturbed N above 0",
          CLI::ExitCodes::RequiresError);
  });
  app.add_flag("--true-seal", o->true_seal,
               "a grasp executed in the true pile must also seal on the true surface where it "
               "lands (else it holds nothing), not only withstand the pull");
  app.add_flag("--superquadric-seal", *superquadric_seal,
               "judge seals on the estimated superquadrics alone, not on the depth points "
               "measured on the target (the ranking without the measured surface)");
}

/// A "best in truth" pick's candidates: what the ranking saw on the estimate, what the pull did
/// in the true pile.
nlohmann::json trialRows(const std::vector<CandidateTrial>& trials) {
  nlohmann::json rows = nlohmann::json::array();
  for (const CandidateTrial& t : trials) {
    const RankedGrasp& g = t.estimate;
    const SuctionCandidate& c = g.candidate;
    rows.push_back(
        {{"contact", {c.contact_table.x(), c.contact_table.y(), c.contact_table.z()}},
         {"approach", {c.approach_table.x(), c.approach_table.y(), c.approach_table.z()}},
         {"measured", c.measured},
         {"rim_deviation_m", c.rim_deviation_m},
         {"com_offset_m", g.com_offset_m},
         {"failed_share", g.failed_share},
         {"freed_share", g.freed_share},
         {"toppled", g.mean_toppled},
         {"score_m", g.score_m},
         {"peak_load", g.peak_load},
         {"lift_m", g.outcomes.empty() ? 0.0 : g.outcomes.front().target_lift_m},
         {"true_failed", t.truth.failed()},
         {"true_freed", t.truth.target_freed},
         {"true_toppled", t.truth.toppled},
         {"true_displacement_m", t.truth.mean_displacement_m},
         {"true_peak_load", t.truth.peak_load}});
  }
  return rows;
}

/// Every pick, one JSON object each.
nlohmann::json pickRows(const std::vector<PickResult>& picks) {
  nlohmann::json rows = nlohmann::json::array();
  for (const PickResult& p : picks) {
    // A pick never pulled (no match, or nothing sealable) has no pull to report: null, not a
    // gentle 0 mm or a seal that broke.
    const nlohmann::json none;
    nlohmann::json row = {
        {"scene", p.scene},
        {"target", p.target},
        {"method", p.method},
        {"chooser", p.chooser},
        {"found", p.found},
        {"grasped", p.grasped},
        {"mean_displacement_m", p.grasped ? nlohmann::json(p.outcome.mean_displacement_m) : none},
        {"max_displacement_m", p.grasped ? nlohmann::json(p.outcome.max_displacement_m) : none},
        {"toppled", p.grasped ? nlohmann::json(p.outcome.toppled) : none},
        {"freed", p.outcome.target_freed},
        {"failed", p.grasped ? nlohmann::json(p.outcome.failed()) : none}};
    // The matched estimate's error; null for the oracle and for a target the method missed.
    const bool estimated = p.found && p.method != "truth";
    const EstimateError& e = p.error;
    row["centre_error_m"] = estimated
                                ? nlohmann::json{e.centre_m.x(), e.centre_m.y(), e.centre_m.z()}
                                : nlohmann::json(nullptr);
    row["rotation_error_deg"] =
        estimated ? nlohmann::json(e.rotation_deg) : nlohmann::json(nullptr);
    row["scale_ratio"] =
        estimated ? nlohmann::json{e.scale_ratio.x(), e.scale_ratio.y(), e.scale_ratio.z()}
                  : nlohmann::json(nullptr);
    if (!p.trials.empty()) row["trials"] = trialRows(p.trials);
    rows.push_back(std::move(row));
  }
  return rows;
}

/// The run's settings, as the results file records them.
nlohmann::json runSettings(const GraspEvaluationOptions& o) {
  const PerturbationConfig& p = o.ranking.perturbation;
  return {{"candidates", o.ranking.candidates.max_candidates},
          {"noise", o.noise},
          {"sensor", o.noise ? sensorModelName(o.sensor) : ""},
          {"seed", o.seed},
          {"hypotheses", o.hypotheses},
          {"measured_seal", o.measured_seal},
          {"perturbed_copies", p.copies},
          {"perturb_position_m", p.position_m},
          {"perturb_rotation_deg", p.rotation_deg},
          {"perturb_scale_share", p.scale_share},
          {"true_seal", o.true_seal},
          {"best_in_truth", o.best_in_truth}};
}

/// Each method's estimate error, as estimateErrorSummary gives it.
void printEstimateErrors(const nlohmann::json& errors) {
  for (const auto& e : errors)
    std::printf(
        "%s, %d targets: estimates off by %.1f mm per axis across the table, %.1f mm in "
        "height, %.1f deg, %.1f %% of each semi-axis (rms; as a normal's deviation from the "
        "median: %.1f mm, %.1f mm, %.1f deg, %.1f %%)\n",
        e["method"].get<std::string>().c_str(), e["targets"].get<int>(),
        1e3 * e["position_rms_m"].get<double>(), 1e3 * e["height_rms_m"].get<double>(),
        e["rotation_rms_deg"].get<double>(), 100 * e["scale_rms_share"].get<double>(),
        1e3 * e["position_robust_sd_m"].get<double>(), 1e3 * e["height_robust_sd_m"].get<double>(),
        e["rotation_robust_sd_deg"].get<double>(), 100 * e["scale_robust_sd_share"].get<double>());
}

}  // namespace

int main(int argc, char** argv) {
  std::string dataset, output;
  GraspEvaluationOptions o;
  o.scenes = 30;
  o.ranking.candidates.max_candidates = 32;
  o.ranking.threads = 2;
  bool no_classical = false, no_noise = false;
  CLI::App app{
      "Evaluate suction-grasp choice on a test dataset of superquadric piles: for every object of "
      "each pile, grasps chosen on each method's estimate from one noisy view (ranked, random, "
      "top-most) and on the true pile (the oracle), each executed in the true pile; prints the "
      "table and writes JSON."};
  const PerceptionOptions perception(app, {true, false, false});
  app.add_option("--dataset", dataset, "test dataset of superquadric piles")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--output", output, "results JSON (summary and every pick)")
      ->required()
      ->check(WritablePath);
  app.add_option("--scenes", o.scenes, "the first N scenes (0 = all)")
      ->capture_default_str()
      ->check(FiniteNonNegative);
  app.add_option("--candidates", o.ranking.candidates.max_candidates, "candidates per ranking")
      ->capture_default_str()
      ->check(CLI::Range(1, 1024));
  app.add_option("--sim-threads", o.ranking.threads, "threads simulating pulls (0 = all cores)")
      ->capture_default_str()
      ->check(CLI::Range(0, 1024));
  app.add_option("--hypotheses", o.hypotheses,
                 "scene hypotheses each candidate is simulated in (the C-VAE's decomposed latent "
                 "samples; at most the model's samples)")
      ->capture_default_str()
      ->check(CLI::Range(1, 16));
  app.add_option("--seed", o.seed, "viewpoints, noise and the random chooser")
      ->capture_default_str()
      ->transform(SeedNumber);
  CLI::Option* no_noise_flag =
      app.add_flag("--no-noise", no_noise, "clean rendered views instead of --sensor's noise");
  addSensorOption(app, &o.sensor, "")->excludes(no_noise_flag);
  app.add_flag("--no-classical", no_classical, "skip the classical baseline");
  bool superquadric_seal = false;
  addSealOptions(app, &o, &superquadric_seal);
  readIntegersInDecimal(app);
  CLI11_PARSE(app, argc, argv);
  keepFreedMemoryForReuse();  // the network runs in this process
  o.noise = !no_noise;
  o.measured_seal = !superquadric_seal;
  try {
    std::vector<std::string> inputs = perception.inputFiles();
    inputs.push_back(dataset);
    requireNotAnInput("--output", output, inputs);
    StagedFile staged(output);  // a bad --output is found (its directory made) before the work
    const DatasetReader reader(dataset);
    // The pulls are simulated in the true pile's superquadrics: piles with meshes (household
    // containers) are refused before the models load.
    if (!reader.info().mesh_names.empty())
      throw std::runtime_error("dataset " + dataset +
                               " holds mesh objects (household or YCB piles): the grasp "
                               "evaluation simulates pulls on superquadric piles only");
    const std::vector<std::unique_ptr<EvaluatedMethod>> methods =
        graspMethods(perception, o.hypotheses, !no_classical, reader.info());
    std::vector<EvaluatedMethod*> run;
    for (const auto& m : methods) run.push_back(m.get());
    const int n = o.scenes > 0 ? std::min(o.scenes, reader.size()) : reader.size();
    ProgressBar bar("grasps on " + std::to_string(n) + (n == 1 ? " pile" : " piles"), n);
    const std::vector<PickResult> picks =
        evaluateGrasps(reader, run, o, [&](int done, int) { bar.update(done); });
    bar.finish();
    const nlohmann::json summary = graspSummary(picks);
    const nlohmann::json errors = estimateErrorSummary(picks);
    const nlohmann::json rows = pickRows(picks);
    std::ofstream f(staged.path());
    nlohmann::json doc = runSettings(o);
    doc["dataset"] = dataset;
    doc["scenes"] = n;
    doc["summary"] = summary;
    doc["estimate_error"] = errors;
    doc["picks"] = rows;
    f << doc.dump(1) << "\n";
    f.close();
    if (!f) throw std::runtime_error("cannot write " + output);
    staged.commit();
    std::cout << "\n" << graspSummaryTable(summary) << "\n";
    printEstimateErrors(errors);
    std::cout << "results: " << output << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_evaluate_grasps: error: " << e.what() << "\n";
    return 1;
  }
}
