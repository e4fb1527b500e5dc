#pragma once
/// @file evaluated_methods.h
/// The methods the evaluation (eval/evaluator.h) compares: a trained network through
/// ScenePerception (the C-VAE and the FC baselines), and the classical baseline.

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "simstack/offline/eval/classical_baseline.h"
#include "simstack/offline/eval/evaluator.h"
#include "simstack/pipeline/perception_config.h"

namespace simstack {

class ScenePerception;

/// A trained model through ScenePerception with `config`: S hypotheses per view, the first
/// decomposed into superquadrics.
class NetworkMethod : public EvaluatedMethod {
 public:
  /// Loads the model of `config` (ScenePerception's exceptions). Named by its architecture.
  /// With `label_pixels` the estimates carry the instance of every pixel (real scenes).
  explicit NetworkMethod(const PerceptionConfig& config, bool label_pixels = false);
  ~NetworkMethod() override;
  const std::string& name() const override { return name_; }
  void rename(std::string name) { name_ = std::move(name); }
  MethodInfo info() const override;
  MethodEstimate estimate(const DepthView& view, const GridSpec* grid,
                          const Vec2& pile_xy) override;
  /// ScenePerception on all the views (its multi-view settings: condition_views,
  /// refine_iterations).
  MethodEstimate estimateViews(const std::vector<DepthView>& views, const GridSpec* grid,
                               const Vec2& pile_xy) override;
  /// The model's architecture (cvae, fc, fc_plain).
  const std::string& architecture() const;

 private:
  std::unique_ptr<ScenePerception> perception_;
  std::string name_;
  bool label_pixels_;
  uint64_t base_seed_ = 0;  ///< the config's seed
  uint64_t estimates_ = 0;  ///< estimates made so far: the next one's code seed
};

/// The classical baseline (classical_baseline.h) under the protocol. Without a grid from an
/// earlier method it centres one of `resolution`^3 voxels over `extent_m` on the visible pile.
/// A view without pose gets the RANSAC table (table_plane.h). With `label_pixels` it clusters
/// every pixel and the estimates carry the cluster of each (real scenes).
class ClassicalMethod : public EvaluatedMethod {
 public:
  ClassicalMethod(const ClassicalConfig& config, double extent_m, int resolution,
                  bool label_pixels = false);
  const std::string& name() const override { return name_; }
  MethodInfo info() const override { return {}; }
  MethodEstimate estimate(const DepthView& view, const GridSpec* grid,
                          const Vec2& pile_xy) override;

 private:
  ClassicalConfig config_;
  double extent_m_;
  int resolution_;
  bool label_pixels_;
  std::string name_ = "classical";
};

/// TSDF fusion, the paper's multi-view baseline: the views' fused partial TSDF on the grid
/// of an earlier method (else one centred on the true pile), occupied where observed and
/// <= 0; unobserved voxels count as free. It finds no objects.
class FusionMethod : public EvaluatedMethod {
 public:
  FusionMethod(double extent_m, int resolution, double truncation_m);
  const std::string& name() const override { return name_; }
  MethodInfo info() const override { return {}; }
  MethodEstimate estimate(const DepthView& view, const GridSpec* grid,
                          const Vec2& pile_xy) override;
  MethodEstimate estimateViews(const std::vector<DepthView>& views, const GridSpec* grid,
                               const Vec2& pile_xy) override;

 private:
  double extent_m_;
  int resolution_;
  double truncation_m_;
  std::string name_ = "fusion";
};

/// The methods of the multi-view protocol (the paper's section 4.2) for each config's model:
/// conditioned on all views (named by architecture) and on the first alone (`_first`, the
/// single-view figure on the same views); for a model with a latent code and
/// `refine_iterations` > 0 (or the config's refine_starts > 0) also each of them with its codes
/// chosen and optimised against every view (`_opt`, `_first_opt`: the paper's multi-view
/// optimisation; the others draw their codes without refine_starts); then TSDF fusion.
std::vector<std::unique_ptr<EvaluatedMethod>> multiViewMethods(
    const std::vector<PerceptionConfig>& configs, int refine_iterations, double extent_m,
    int resolution, double truncation_m);

/// `name`, or, when one of `methods` already has it, `name` + "_" + the method's index: two
/// models of one architecture make two rows.
std::string distinctName(const std::string& name,
                         const std::vector<std::unique_ptr<EvaluatedMethod>>& methods);

/// The methods of the dataset protocol: one NetworkMethod per config with random latent codes
/// (not the zero code first, as the paper evaluates), named by architecture (a repeated
/// architecture gets the method's index appended), then the classical baseline with the first
/// config's fitter when `classical` is set.
std::vector<std::unique_ptr<EvaluatedMethod>> evaluatedMethods(
    const std::vector<PerceptionConfig>& configs, bool classical, double extent_m, int resolution);

}  // namespace simstack
