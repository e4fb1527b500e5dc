#pragma once
/// @file cvae_inference.h
/// Running a trained model: a partial TSDF and S latent codes give S full TSDFs and vote
/// fields in one batched forward pass. No torch in this header.

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "simstack/geometry/voxel_grid.h"
#include "simstack/model/cvae_config.h"

namespace simstack {

/// One generated scene hypothesis on the input's grid.
struct CvaePrediction {
  Grid3<float> tsdf_m;  ///< full TSDF in metres (+-truncation)
  Grid3<Vec3f> votes;   ///< centre-vote field
};

/// A further view's own partial TSDF (metres) and weights on the prediction's grid: what the
/// latent optimisation matches (refine()).
struct ViewEvidence {
  Grid3<float> tsdf_m, weight;
};

struct RefineOptions {
  int iterations = 10;         ///< Adam steps on the codes
  double learning_rate = 0.3;  ///< Adam step size (codes are standard normal draws)
  int symmetries = 1;          ///< the kept codes decoded as predict() does with this many
  /// Weight of the prior's negative log-density, |z|^2 / 2, added to each code's evidence
  /// loss: it keeps the codes where the decoder was trained (0 = the evidence alone).
  double prior_weight = 0.0;
  /// Prior draws scored against the evidence before the fitting; the S with the lowest loss
  /// are fitted, best first (with zero_code_first, z = 0 is the first draw and competes with
  /// the others). At most `samples` (the default 0 too): the S draws of predict(), in order.
  int starts = 0;
  /// What a view's evidence scores: "tsdf", |tsdf - view tsdf| (both in tau, clamped to +-1),
  /// or "sign", max(0, -tsdf * view tsdf): only where the decoded scene calls occupied what
  /// the view saw free, or the reverse (a projective TSDF's distances are not the scene's).
  std::string evidence = "sign";
  /// Codes scored and fitted on the average of the `symmetries` passes, as they are decoded
  /// (each step then costs that many decoder passes); false: on the plain pass alone, which
  /// is faster, but a code so fitted means another scene in the turned passes.
  bool fit_on_passes = true;
};

/// What refine() did: the depth-evidence loss of the kept code at each iteration (index 0:
/// before the first step), and the time.
struct RefineReport {
  std::vector<double> loss;
  std::vector<double> code_loss;   ///< per hypothesis: its code's loss at its best step
  std::vector<double> start_loss;  ///< with RefineOptions::starts: each prior draw's loss
  double ms = 0;
};

/// std::invalid_argument unless `symmetries` is 1, 2, 4 or 8 (CvaeInference::predict).
void validateSymmetries(int symmetries);

/// std::invalid_argument naming the bad field of `options` (CvaeInference::refine).
void validateRefineOptions(const RefineOptions& options);

/// The TSDF truncation (m) the network `model` reads and writes on `grid`: its truncation_vox
/// voxels of that grid.
inline double truncationIn(const CvaeConfig& model, const GridSpec& grid) {
  return model.truncation_vox * grid.voxel_size_m;
}

/// Loads once; predict() is const but not thread-safe (torch state): use one per thread.
class CvaeInference {
 public:
  /// Throws std::runtime_error naming the file and the problem (missing, corrupt, config).
  explicit CvaeInference(const std::string& model_path, int threads = 2);
  ~CvaeInference();
  const CvaeConfig& config() const;
  /// Training provenance stored in the file (YAML text, may be empty).
  const std::string& metadata() const;
  /// S = `samples` hypotheses for the partial TSDF (metres) and its weights, which must lie on
  /// a grid of the model's resolution (std::invalid_argument otherwise), of any side: the
  /// network works in voxels, and the truncation is the model's truncation_vox voxels of that
  /// grid (truncationIn). Codes are
  /// drawn from N(0, I) with `seed`; with `zero_code_first` the first is the mean scene
  /// (z = 0). The FC baseline returns the same prediction for every sample.
  /// `symmetries` (1, 2, 4 or 8, else std::invalid_argument): the network also runs on the
  /// input turned about the vertical (2: by a half turn, 4: by every quarter turn) and mirrored
  /// (8), with the same codes, and each hypothesis is the average of the outputs turned back.
  /// The prediction of an input so turned (or mirrored) is then the turned prediction. Costs a
  /// forward pass each.
  std::vector<CvaePrediction> predict(const Grid3<float>& partial_tsdf_m,
                                      const Grid3<float>& weight, int samples, uint64_t seed = 0,
                                      bool zero_code_first = false, int symmetries = 1) const;

  /// The paper's section 4.2: the S codes of predict() (same seed) optimised, the network
  /// fixed, so that the decoded TSDF agrees with every view's own partial TSDF where that view
  /// observed the scene (weight > 0): the mean over views of the sum over the view's observed
  /// voxels of `options.evidence`'s term, plus `options.prior_weight` times |z|^2 / 2. With
  /// `options.starts` > S the codes start from the best S of that many prior draws (same seed),
  /// best first. Hypothesis k is code k at its best step (the report has each code's loss);
  /// the FC baseline, having no code, returns predict()'s. The codes are fitted on the average
  /// of `options.symmetries` passes, as decoded (or, without `options.fit_on_passes`, on the
  /// plain pass). `views` must lie on the partial TSDF's grid (std::invalid_argument).
  std::vector<CvaePrediction> refine(const Grid3<float>& partial_tsdf_m, const Grid3<float>& weight,
                                     const std::vector<ViewEvidence>& views, int samples,
                                     uint64_t seed, bool zero_code_first,
                                     const RefineOptions& options,
                                     RefineReport* report = nullptr) const;

 private:
  /// std::invalid_argument for a grid the model does not take; sets the torch threads.
  void checkInput(const Grid3<float>& partial_tsdf_m, const Grid3<float>& weight,
                  int samples) const;
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace simstack
