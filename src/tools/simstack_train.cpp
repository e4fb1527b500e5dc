// simstack_train: trains the C-VAE (or the FC baseline) on a dataset from simstack_generate.
#include <CLI/CLI.hpp>

#include <unistd.h>

#include <atomic>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "cli_checks.h"
#include "progress.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/model/model_integrity.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/offline/training/cvae_trainer.h"
#include "simstack/pipeline/scene_perception.h"

using namespace simstack;

namespace {

/// What --validate-only prints: the validation's measures of one model file.
void printValidation(const std::string& model, const std::string& dataset,
                     const TrainConfig& training, const TrainingReport& r) {
  // A model without a latent code (FC: no posterior) gives one estimate per view.
  if (!std::isfinite(r.validation_posterior_iou)) {
    std::printf(
        "validation of %s: the last %d scenes of %s x %d views, one estimate each (the model "
        "has no latent code)\n  IoU %.4f +- %.4f (standard error over scenes), BCE %.4f\n",
        model.c_str(), training.validation_scenes, dataset.c_str(), training.validation_views,
        r.validation_iou, r.validation_iou_se, r.validation_bce);
    return;
  }
  std::printf(
      "validation of %s: the last %d scenes of %s x %d views, %d codes each\n"
      "  IoU of the codes' mean occupancy %.4f +- %.4f (standard error over scenes), "
      "BCE %.4f\n  IoU of one code %.4f, of the best of %d (oracle) %.4f, of the posterior mean "
      "(encoder seeing the truth) %.4f",
      model.c_str(), training.validation_scenes, dataset.c_str(), training.validation_views,
      training.validation_samples, r.validation_iou, r.validation_iou_se, r.validation_bce,
      r.validation_single_iou, training.validation_samples, r.validation_best_iou,
      r.validation_posterior_iou);
  std::printf(
      "\n  hypotheses disagree on %.2f %% of their occupied voxels: %.2f %% where the view "
      "observed, %.2f %% where it did not; %.1f %% of the disagreement is unobserved\n",
      100.0 * r.validation_disagreement, 100.0 * r.validation_disagreement_seen,
      100.0 * r.validation_disagreement_unseen, 100.0 * r.validation_unseen_share);
}

/// What a finished run prints: its losses and validation.
void printTrained(const std::string& architecture, const std::string& output,
                  const TrainingReport& r) {
  std::cout << "trained " << architecture << " to step " << r.steps << " (" << r.samples_per_second
            << " samples/s)\n  final losses: total " << r.total << ", tsdf " << r.tsdf
            << ", partial " << r.partial << ", votes " << r.votes << ", mmd " << r.mmd
            << ", occupancy " << r.occupancy << ", iou " << r.iou << "\n  validation: IoU "
            << r.validation_iou << " +- " << r.validation_iou_se << ", BCE " << r.validation_bce
            << ", hypotheses disagree on " << 100.0 * r.validation_disagreement
            << " % of their voxels";
  if (std::isfinite(r.validation_posterior_iou))
    std::cout << ", IoU from the posterior code " << r.validation_posterior_iou;
  if (std::isfinite(r.posterior_mu_rms)) {
    std::cout << "\n  posterior on the last training batches: mu RMS " << r.posterior_mu_rms
              << ", mean sigma " << r.posterior_sigma;
  }
  std::cout << "\n  model: " << output << "/model.pt (provenance in model.yaml)\n";
}

/// The command line; zero and empty mean "as the config says".
struct Options {
  std::vector<std::string> datasets;
  std::string config_path, output;
  bool resume = false, allow_held_out = false;
  int threads = 0;
  std::string architecture;
  int64_t steps = 0;
  int validation_scenes = 0, validation_views = 0, validation_samples = 0;
  std::string init_from, validate_only, mesh_dir;
};

void addOptions(CLI::App& app, Options& o) {
  app.add_option("--dataset", o.datasets,
                 "HDF5 dataset from simstack_generate; repeated, the files are read as one, "
                 "interleaved in proportion to their sizes (the validation scenes come from "
                 "the end of each)")
      ->required()
      ->take_all()
      ->check(CLI::ExistingFile);
  app.add_option("--config", o.config_path,
                 "YAML with `model:` and `training:` sections (see config/train_r32.yaml)")
      ->required()
      ->check(CLI::ExistingFile);
  CLI::Option* output =
      app.add_option(
             "--output", o.output,
             "output directory (model.pt, model.yaml, checkpoints, train_log.csv); required "
             "unless --validate-only")
          ->check(WritablePath);
  CLI::Option* resume = app.add_flag("--resume", o.resume, "continue from OUTPUT/checkpoint.pt");
  app.add_flag("--allow-held-out", o.allow_held_out,
               "train on piles of a held-out test seed all the same (their figures then measure "
               "what was trained on)");
  app.add_option("--threads", o.threads, "torch threads (overrides training.threads)")
      ->check(CLI::Range(1, 256));
  app.add_option("--architecture", o.architecture,
                 "cvae, fc or fc_plain (overrides model.architecture)")
      ->check(CLI::IsMember({"cvae", "fc", "fc_plain"}));
  CLI::Option* steps =
      app.add_option("--steps", o.steps, "optimiser steps (overrides training.steps)")
          ->check(FinitePositive);
  CLI::Option* init_from =
      app.add_option("--init-from", o.init_from,
                     "warm start from this model file: its tensors of the same name and shape "
                     "(overrides training.init_from; not read with --resume from a checkpoint)")
          ->check(CLI::ExistingFile);
  app.add_option("--validation-scenes", o.validation_scenes,
                 "held-out scenes at the end of the dataset (overrides training.validation_scenes)")
      ->check(FinitePositive);
  app.add_option("--validation-views", o.validation_views,
                 "viewpoints per validation scene (overrides training.validation_views)")
      ->check(FinitePositive);
  app.add_option("--validation-samples", o.validation_samples,
                 "latent codes per validation view (overrides training.validation_samples)")
      ->check(CLI::Range(2, 256));
  app.add_option("--validate-only", o.validate_only,
                 "score this model file on the dataset's validation scenes as a run's validation "
                 "does (training.validation_scenes x validation_views) and exit; no training")
      ->check(CLI::ExistingFile)
      ->excludes(output)  // options of a training run: refused rather than ignored
      ->excludes(resume)
      ->excludes(steps)
      ->excludes(init_from);
  app.add_option("--ycb", o.mesh_dir,
                 "the mesh directory of YCB datasets (<dir>/<object>/nontextured.stl), for "
                 "training or --validate-only on mesh piles")
      ->check(CLI::ExistingDirectory);
}

/// The signal that asked training to stop (0: none). Lock-free, so the handler may set it
/// while the training thread reads it.
std::atomic<int> g_stop_signal{0};
static_assert(std::atomic<int>::is_always_lock_free);

extern "C" void onStopSignal(int signal) {
  // The first stop signal is the one the run ends by (a second one ends it at once).
  int none = 0;
  g_stop_signal.compare_exchange_strong(none, signal);
  static const char kSaid[] =
      "\nsimstack_train: stopping after this step, its checkpoint written (Ctrl-C again: at "
      "once)\n";
  const ssize_t written = write(STDERR_FILENO, kSaid, sizeof(kSaid) - 1);
  (void)written;
  // A second Ctrl-C or SIGTERM, whichever came first, ends the process as usual.
  std::signal(SIGINT, SIG_DFL);
  std::signal(SIGTERM, SIG_DFL);
}

/// While it lives, Ctrl-C and SIGTERM ask training to stop after its step (the step's
/// checkpoint written) instead of ending it, and a step's work is not lost.
class StopOnSignal {
 public:
  StopOnSignal()
      : int_(std::signal(SIGINT, onStopSignal)), term_(std::signal(SIGTERM, onStopSignal)) {}
  ~StopOnSignal() {
    std::signal(SIGINT, int_);
    std::signal(SIGTERM, term_);
  }
  StopOnSignal(const StopOnSignal&) = delete;
  StopOnSignal& operator=(const StopOnSignal&) = delete;

 private:
  void (*int_)(int);
  void (*term_)(int);
};

/// Trains with a progress bar, Ctrl-C stopping at a checkpoint; prints the figures and stamps
/// the model's card. The exit status.
int trainAndStamp(CvaeTrainer& trainer, const std::string& architecture,
                  const TrainConfig& training, const Options& o) {
  std::unique_ptr<ProgressBar> bar;
  bool validated = false;  // in this process: until then there is no IoU to show
  StopOnSignal stop_on_signal;
  const auto progress = [&](const TrainingProgress& p) {
    if (!bar)
      bar = std::make_unique<ProgressBar>("training " + architecture, p.steps, p.first_step,
                                          p.seconds);
    validated = validated || p.step % training.validate_every == 0 || p.step == p.steps;
    char iou[16] = " -";
    if (validated) std::snprintf(iou, sizeof(iou), " %.3f", p.validation_iou);
    char suffix[160];
    std::snprintf(suffix, sizeof(suffix),
                  " loss %.0f (tsdf %.0f votes %.0f mmd %.2g) val IoU%s  %.1f samples/s", p.loss,
                  p.tsdf, p.votes, p.mmd, iou, p.samples_per_second);
    bar->update(p.step, suffix);
  };
  TrainingReport r;
  try {
    r = trainer.run(o.resume, progress, [] { return g_stop_signal.load() != 0; });
  } catch (const TrainingStopped& e) {
    if (bar) bar->finish();
    std::cerr << "simstack_train: " << e.what() << "\n";
    return 128 + g_stop_signal.load();
  }
  if (bar) bar->finish();
  const std::string model_file = (std::filesystem::path(o.output) / "model.pt").string();
  if (r.steps_trained == 0 && readModelIntegrity(model_file)) {
    // The run's stamped model is checked against its card, not stamped again: a file replaced
    // since would otherwise be recorded as the run's.
    std::printf("nothing to train: the run had reached step %lld; its model stays as written\n",
                static_cast<long long>(r.steps));
    printTrained(architecture, o.output, r);
    const ModelSelfTest t = checkModel(model_file);
    std::printf("checked against its card: %d object(s), %d occupied voxels on a rendered box\n",
                t.objects, t.occupied_voxels);
    return 0;
  }
  printTrained(architecture, o.output, r);
  // The card records what the file is, so that every later load can tell it was not damaged.
  const ModelIntegrity m = stampModel(model_file);
  std::printf("self-test on a rendered box: %d object(s), %d occupied voxels (card: %s)\n",
              m.self_test_objects, m.self_test_occupied_voxels, modelCardPath(model_file).c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  CLI::App app{
      "Train the depth-conditioned VAE of SIMstack (or its FC ablation) on a generated dataset. "
      "Views and "
      "partial TSDFs are rendered on the fly; checkpoints in OUTPUT resume with --resume."};
  addOptions(app, o);
  readIntegersInDecimal(app);
  CLI11_PARSE(app, argc, argv);
  if (o.output.empty() && o.validate_only.empty()) {
    std::cerr << "simstack_train: error: --output is required (unless --validate-only)\n";
    return 2;
  }

  keepFreedMemoryForReuse();
  try {
    CvaeConfig model;
    TrainConfig training;
    loadTrainingYaml(o.config_path, &model, &training);
    if (o.threads > 0) training.threads = o.threads;
    if (!o.architecture.empty()) model.architecture = o.architecture;
    if (o.steps > 0) training.steps = o.steps;
    if (!o.init_from.empty()) training.init_from = o.init_from;
    if (o.validation_scenes > 0) training.validation_scenes = o.validation_scenes;
    if (o.validation_views > 0) training.validation_views = o.validation_views;
    if (o.validation_samples > 0) training.validation_samples = o.validation_samples;
    if (!o.validate_only.empty()) {
      std::string named;
      for (const std::string& d : o.datasets) named += (named.empty() ? "" : " + ") + d;
      printValidation(
          o.validate_only, named, training,
          CvaeTrainer::validateModel(o.datasets, o.validate_only, training, o.mesh_dir));
      return 0;
    }
    if (!o.allow_held_out) refuseHeldOutDatasets(o.datasets, "train on");
    // A forgotten --resume must not start over in a run's directory (its checkpoint lost).
    if (!o.resume && (std::filesystem::exists(std::filesystem::path(o.output) / "state.yaml") ||
                      std::filesystem::exists(std::filesystem::path(o.output) / "checkpoint.pt")))
      throw std::runtime_error(o.output +
                               " holds a training run: --resume continues it; another --output "
                               "(or removing it) starts afresh");
    // A run writes its files into --output beside whatever is there: the user's files, or the
    // working directory, are not a place for them.
    std::error_code ec;
    if (pathHolds(o.output, std::filesystem::current_path(ec).string()))
      throw std::runtime_error(o.output +
                               " is the working directory or holds it: name a directory inside "
                               "it, e.g. ./run");
    // A run stopped or failed before its first checkpoint leaves its log alone, or with the
    // checkpoint it was writing (checkpoint.pt.tmp, killed before the rename): the directory is
    // that run's, and a new run starts afresh in it.
    const auto only_a_log = [&] {
      for (const auto& e : std::filesystem::directory_iterator(o.output, ec))
        if (e.path().filename() != "train_log.csv" && e.path().filename() != "checkpoint.pt.tmp")
          return false;
      return true;
    };
    if (!o.resume && std::filesystem::is_directory(o.output) && !only_a_log())
      throw std::runtime_error(o.output +
                               " is not empty and holds no training run: choose another "
                               "directory, or empty it");
    std::string command;
    for (int i = 0; i < argc; ++i) command += (i ? " " : "") + std::string(argv[i]);
    CvaeTrainer trainer(o.datasets, model, training, o.output, command, o.mesh_dir);
    if (!trainer.note().empty()) std::printf("note: %s\n", trainer.note().c_str());
    const int status = trainAndStamp(trainer, model.architecture, training, o);
    // Ended by the signal, as a shell expects of a child it interrupted (a loop of runs stops):
    // the step's checkpoint, or the finished model, is written by now.
    if (const int signal = g_stop_signal.load(); signal != 0) {
      std::fflush(stdout);
      std::signal(signal, SIG_DFL);
      std::raise(signal);
    }
    return status;
  } catch (const std::exception& e) {
    std::cerr << "simstack_train: error: " << e.what() << "\n";
    return 1;
  }
}
