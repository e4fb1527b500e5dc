#pragma once
/// @file cvae_trainer.h
/// Trains a C-VAE or the FC baseline on a generated dataset: random views are rendered and
/// their partial TSDFs built on the fly (paper section 3.1.1), Adam, checkpoints that resume,
/// a CSV log, validation on the last scenes of the dataset. Deterministic for a seed and the
/// steps at which it was resumed (a resumed run reseeds torch from the seed and its step).

#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "simstack/model/cvae_config.h"
#include "simstack/offline/training/train_config.h"

namespace simstack {

struct TrainingReport {
  int64_t steps = 0;
  /// Steps trained by this run (0: a resumed run that had reached its steps).
  int64_t steps_trained = 0;
  /// Mean of the last 50 steps; occupancy and iou are reported also when their weight is 0.
  double total = 0, tsdf = 0, partial = 0, votes = 0, mmd = 0, occupancy = 0, iou = 0;
  /// IoU and BCE of the expected occupancy of `validation_samples` prior codes (the mean of the
  /// hypotheses, as the evaluation scores them).
  double validation_iou = 0, validation_bce = 0;
  /// Standard error of validation_iou: the spread of the scenes' mean IoU over sqrt(scenes).
  double validation_iou_se = 0;
  /// Mean IoU of one hypothesis, and of the hypothesis nearest the truth (best of S: an
  /// oracle that shows whether the right completion is among the hypotheses).
  double validation_single_iou = 0, validation_best_iou = 0;
  /// Over all validation views, the share of the voxels occupied in some hypothesis that are
  /// not occupied in all: near 0 means the samples are copies of one scene. Also among the
  /// voxels the view observed (partial TSDF weight > 0) and those it did not, and the share of
  /// all disagreeing voxels that lie in the unobserved ones (hidden parts are where they belong).
  double validation_disagreement = 0;
  double validation_disagreement_seen = 0, validation_disagreement_unseen = 0;
  double validation_unseen_share = 0;
  /// Validation IoU of one hypothesis decoded from the encoder's posterior mean, the encoder
  /// seeing the ground truth: above validation_iou only if the code carries the hidden parts
  /// (it is what training optimises; prior codes are what inference has). NaN for FC.
  double validation_posterior_iou = std::numeric_limits<double>::quiet_NaN();
  /// The encoder's posterior N(mu, sigma^2) on the last 50 training batches: RMS of mu and mean
  /// sigma. mu ~ 0 with sigma ~ 1 for every scene: the code says nothing about it; an
  /// informative code has means spread like the prior and small sigmas. NaN when this run
  /// trained no C-VAE step (FC baseline, or a resumed run that had reached its steps).
  double posterior_mu_rms = std::numeric_limits<double>::quiet_NaN();
  double posterior_sigma = std::numeric_limits<double>::quiet_NaN();
  double samples_per_second = 0;
};

/// What the trainer reports after every step (for a progress display).
struct TrainingProgress {
  int64_t step = 0;        ///< steps done
  int64_t steps = 0;       ///< steps of the whole run
  int64_t first_step = 0;  ///< the step this run started from (> 0 when resumed)
  double loss = 0, tsdf = 0, votes = 0, mmd = 0;  ///< this step's losses
  double validation_iou = 0;                      ///< the latest validation (0 before the first)
  double samples_per_second = 0;
  double seconds = 0;  ///< since this run began training (its first batch included)
};
using TrainingProgressCallback = std::function<void(const TrainingProgress&)>;

/// Thrown by CvaeTrainer::run when asked to stop: the checkpoint holds the step it names.
struct TrainingStopped : std::runtime_error {
  TrainingStopped(const std::string& what, int64_t at) : std::runtime_error(what), step(at) {}
  int64_t step;  ///< the step the checkpoint holds
};

/// Adam's step size at optimiser step `step`: a cosine from learning_rate at 0 down to
/// final_learning_rate at training.steps.
double learningRate(const TrainConfig& training, int64_t step);

class CvaeTrainer {
 public:
  /// Trains on one dataset or on several read as one (DatasetMix: interleaved in proportion
  /// to their sizes, so the validation scenes come from every file). `mesh_dir` holds the
  /// meshes of datasets of mesh piles (YCB: <dir>/<name>/nontextured.stl; "" when every file
  /// is of superquadric or household piles). Throws std::runtime_error naming the dataset or
  /// output directory when they are unusable or a dataset does not match the model config,
  /// std::invalid_argument for no dataset.
  CvaeTrainer(const std::vector<std::string>& dataset_paths, const CvaeConfig& model,
              const TrainConfig& training, const std::string& output_dir,
              const std::string& command_line, const std::string& mesh_dir = "");
  CvaeTrainer(const std::string& dataset_path, const CvaeConfig& model, const TrainConfig& training,
              const std::string& output_dir, const std::string& command_line)
      : CvaeTrainer(std::vector<std::string>{dataset_path}, model, training, output_dir,
                    command_line) {}
  ~CvaeTrainer();
  /// What the trainer chose for the user ("" when nothing): a dataset that holds no more scenes
  /// than training.validation_scenes is validated on its last quarter instead.
  const std::string& note() const;
  /// Trains to training.steps (from the last checkpoint when `resume`) and writes
  /// <output>/model.pt and its card <output>/model.yaml. `progress`, when given, is called
  /// after every step from the calling thread. `stop`, when given, is asked after every step:
  /// true writes a checkpoint at that step and throws TrainingStopped. A resumed run that had
  /// reached its steps and written its model leaves model.pt and its card as they are and
  /// reports the card's figures. The run holds its directory (flock): a second run in it
  /// meanwhile throws std::runtime_error saying so.
  TrainingReport run(bool resume, const TrainingProgressCallback& progress = {},
                     const std::function<bool()>& stop = {});

  /// The validation of a run (the last `training.validation_scenes` scenes of the dataset, each
  /// from `training.validation_views` viewpoints) for a trained model file, without training:
  /// the validation_* fields of the report. `mesh_dir` holds the meshes of a dataset of mesh
  /// piles (YCB; "" for superquadric piles). Throws std::runtime_error naming the file that is
  /// unusable or does not match the other.
  static TrainingReport validateModel(const std::vector<std::string>& dataset_paths,
                                      const std::string& model_path, const TrainConfig& training,
                                      const std::string& mesh_dir = "");
  static TrainingReport validateModel(const std::string& dataset_path,
                                      const std::string& model_path, const TrainConfig& training,
                                      const std::string& mesh_dir = "") {
    return validateModel(std::vector<std::string>{dataset_path}, model_path, training, mesh_dir);
  }

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace simstack
