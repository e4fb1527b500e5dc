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
  /// a grid of the model's resolution and extent (std::invalid_argument otherwise). Codes are
  /// drawn from N(0, I) with `seed`; with `zero_code_first` the first is the mean scene
  /// (z = 0). The FC baseline returns the same prediction for every sample.
  std::vector<CvaePrediction> predict(const Grid3<float>& partial_tsdf_m,
                                      const Grid3<float>& weight, int samples, uint64_t seed = 0,
                                      bool zero_code_first = false) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace simstack
