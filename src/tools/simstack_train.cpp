// simstack_train: trains the C-VAE (or the FC baseline) on a dataset from simstack_generate.
#include <CLI/CLI.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>

#include "cli_checks.h"
#include "progress.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/model/cvae_trainer.h"

using namespace simstack;

namespace {

/// What --validate-only prints: the validation's measures of one model file.
void printValidation(const std::string& model, const std::string& dataset,
                     const TrainConfig& training, const TrainingReport& r) {
  std::printf(
      "validation of %s: the last %d scenes of %s x %d views, %d codes each\n"
      "  IoU of the codes' mean occupancy %.4f +- %.4f (standard error over scenes), "
      "BCE %.4f\n  IoU of one code %.4f, of the best of %d (oracle) %.4f",
      model.c_str(), training.validation_scenes, dataset.c_str(), training.validation_views,
      training.validation_samples, r.validation_iou, r.validation_iou_se, r.validation_bce,
      r.validation_single_iou, training.validation_samples, r.validation_best_iou);
  if (std::isfinite(r.validation_posterior_iou))
    std::printf(", of the posterior mean (encoder seeing the truth) %.4f",
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
  std::cout << "trained " << architecture << " for " << r.steps << " steps ("
            << r.samples_per_second << " samples/s)\n  final losses: total " << r.total << ", tsdf "
            << r.tsdf << ", partial " << r.partial << ", votes " << r.votes << ", mmd " << r.mmd
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

}  // namespace

int main(int argc, char** argv) {
  std::string dataset, config_path, output;
  bool resume = false;
  int threads = 0;
  std::string architecture;
  int64_t steps = 0;
  int validation_scenes = 0, validation_views = 0, validation_samples = 0;
  std::string init_from, validate_only;
  CLI::App app{
      "Train the depth-conditioned VAE of SIMstack (or its FC ablation) on a generated dataset. "
      "Views and "
      "partial TSDFs are rendered on the fly; checkpoints in OUTPUT resume with --resume."};
  app.add_option("--dataset", dataset, "HDF5 dataset from simstack_generate")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--config", config_path,
                 "YAML with `model:` and `training:` sections (see config/train_r32.yaml)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--output", output,
                 "output directory (model.pt, model.yaml, checkpoints, train_log.csv); required "
                 "unless --validate-only");
  app.add_flag("--resume", resume, "continue from OUTPUT/checkpoint.pt");
  app.add_option("--threads", threads, "torch threads (overrides training.threads)")
      ->check(CLI::Range(1, 256));
  app.add_option("--architecture", architecture,
                 "cvae, fc or fc_plain (overrides model.architecture)")
      ->check(CLI::IsMember({"cvae", "fc", "fc_plain"}));
  app.add_option("--steps", steps, "optimiser steps (overrides training.steps)")
      ->check(FinitePositive);
  app.add_option("--init-from", init_from,
                 "warm start from this model file: its tensors of the same name and shape "
                 "(overrides training.init_from; not read with --resume from a checkpoint)")
      ->check(CLI::ExistingFile);
  app.add_option("--validation-scenes", validation_scenes,
                 "held-out scenes at the end of the dataset (overrides training.validation_scenes)")
      ->check(FinitePositive);
  app.add_option("--validation-views", validation_views,
                 "viewpoints per validation scene (overrides training.validation_views)")
      ->check(FinitePositive);
  app.add_option("--validation-samples", validation_samples,
                 "latent codes per validation view (overrides training.validation_samples)")
      ->check(CLI::Range(2, 256));
  app.add_option("--validate-only", validate_only,
                 "score this model file on the dataset's validation scenes as a run's validation "
                 "does (training.validation_scenes x validation_views) and exit; no training")
      ->check(CLI::ExistingFile);
  CLI11_PARSE(app, argc, argv);
  if (output.empty() && validate_only.empty()) {
    std::cerr << "simstack_train: error: --output is required (unless --validate-only)\n";
    return 2;
  }

  keepFreedMemoryForReuse();
  try {
    CvaeConfig model;
    TrainConfig training;
    loadTrainingYaml(config_path, &model, &training);
    if (threads > 0) training.threads = threads;
    if (!architecture.empty()) model.architecture = architecture;
    if (steps > 0) training.steps = steps;
    if (!init_from.empty()) training.init_from = init_from;
    if (validation_scenes > 0) training.validation_scenes = validation_scenes;
    if (validation_views > 0) training.validation_views = validation_views;
    if (validation_samples > 0) training.validation_samples = validation_samples;
    if (!validate_only.empty()) {
      printValidation(validate_only, dataset, training,
                      CvaeTrainer::validateModel(dataset, validate_only, training));
      return 0;
    }
    // A forgotten --resume must not start over in a run's directory (its checkpoint lost).
    if (!resume && (std::filesystem::exists(std::filesystem::path(output) / "state.yaml") ||
                    std::filesystem::exists(std::filesystem::path(output) / "checkpoint.pt")))
      throw std::runtime_error(output +
                               " holds a training run: --resume continues it; another --output "
                               "(or removing it) starts afresh");
    std::string command;
    for (int i = 0; i < argc; ++i) command += (i ? " " : "") + std::string(argv[i]);
    CvaeTrainer trainer(dataset, model, training, output, command);
    std::unique_ptr<ProgressBar> bar;
    const TrainingReport r = trainer.run(resume, [&](const TrainingProgress& p) {
      if (!bar)
        bar =
            std::make_unique<ProgressBar>("training " + model.architecture, p.steps, p.first_step);
      char suffix[160];
      std::snprintf(suffix, sizeof(suffix),
                    " loss %.0f (tsdf %.0f votes %.0f mmd %.2g) val IoU %.3f  %.1f samples/s",
                    p.loss, p.tsdf, p.votes, p.mmd, p.validation_iou, p.samples_per_second);
      bar->update(p.step, suffix);
    });
    if (bar) bar->finish();
    printTrained(model.architecture, output, r);
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_train: error: " << e.what() << "\n";
    return 1;
  }
}
