#pragma once
/// @file perception_options.h
/// The options every tool that runs ScenePerception shares, and the one place that turns them
/// into a PerceptionConfig: the package's config/perception.yaml unless --config names
/// another, the config's model unless --model names one (whose card brings its sample count
/// and Hough setting), then --samples, --seed, --threads, --symmetries and --no-joint over both.

#include <CLI/CLI.hpp>

#include <cmath>
#include <set>
#include <string>
#include <vector>

#include "cli_checks.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/pipeline/perception_config.h"

namespace simstack {

/// The package directory: the source tree, or where `make install` put config/ and models/.
std::string packageDir();
/// A file shipped with the package (e.g. "config/perception.yaml"): from the source tree, or
/// where `make install` put it.
std::string packageFile(const std::string& relative);

/// --intrinsics "fx,fy,cx,cy" (pixels) for an image of width x height, or
/// "fx,fy,cx,cy,width,height" naming that size; std::invalid_argument naming the option for
/// anything else, another size, or intrinsics PinholeCamera::validate refuses.
PinholeCamera parseIntrinsics(const std::string& text, int width, int height);
/// As parseIntrinsics, for the size the text gives, else for the image whose centre is the
/// principal point (width 2 cx + 1, height 2 cy + 1): the camera of a depth file that does not
/// give its size (an unorganized cloud).
PinholeCamera parseCentredIntrinsics(const std::string& text);

class PerceptionOptions {
 public:
  struct Which {
    bool several_models = false;  ///< --model may be repeated (simstack_evaluate)
    bool seed = true;             ///< --seed is the latent-code seed
    bool joint = true;            ///< --no-joint
  };
  /// Adds the options to `app`.
  PerceptionOptions(CLI::App& app, Which which);
  PerceptionOptions(CLI::App& app) : PerceptionOptions(app, Which()) {}

  /// One config per --model given (in order), or the config's own model when none is. Each
  /// model is checked once per process (checkModel: its card's SHA-256 and format, finite
  /// weights, the self-test). Throws std::runtime_error naming the file when a config, card or
  /// model is unusable.
  std::vector<PerceptionConfig> configs() const;
  /// The first of configs().
  PerceptionConfig config() const { return configs().front(); }
  /// The files named by --config and --model, or without --model the config's own model, with
  /// the models' cards: for outputs to be checked against.
  std::vector<std::string> inputFiles() const;
  /// The perception config file (--config, or the package's).
  const std::string& configPath() const { return config_path_; }

 private:
  std::string config_path_ = packageFile("config/perception.yaml");
  std::vector<std::string> models_;
  int samples_ = 3, threads_ = 2, symmetries_ = 4;
  uint64_t seed_ = 0;
  bool no_joint_ = false;
  mutable std::set<std::string> checked_models_;
  CLI::Option *samples_opt_ = nullptr, *seed_opt_ = nullptr, *threads_opt_ = nullptr,
              *symmetries_opt_ = nullptr;
};

}  // namespace simstack
