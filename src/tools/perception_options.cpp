#include "perception_options.h"

#include <cmath>
#include <filesystem>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "simstack/io/image_io.h"
#include "simstack/model/cvae_config.h"
#include "simstack/pipeline/scene_perception.h"

namespace simstack {

std::string packageDir() {
  for (const char* dir : {SIMSTACK_SOURCE_DIR, SIMSTACK_SHARE_DIR})
    if (std::filesystem::exists(std::filesystem::path(dir) / "config/perception.yaml")) return dir;
  return SIMSTACK_SOURCE_DIR;
}

std::string packageFile(const std::string& relative) {
  return (std::filesystem::path(packageDir()) / relative).string();
}

PerceptionOptions::PerceptionOptions(CLI::App& app, Which which) {
  app.add_option("--config", config_path_,
                 "perception config (its model, pipeline settings); the options below override it")
      ->capture_default_str()
      ->check(CLI::ExistingFile);
  app.add_option("--model", models_,
                 which.several_models
                     ? "model file(s), each with its card (models/<name>.yaml) beside it; "
                       "default: the config's model"
                     : "model file, with its card (models/<name>.yaml) beside it; default: the "
                       "config's model")
      ->check(CLI::ExistingFile)
      ->expected(1, which.several_models ? 1 << 16 : 1);
  samples_opt_ =
      app.add_option("--samples", samples_, "latent samples S (default: the model card's)")
          ->check(FinitePositive)
          ->check(CLI::Range(1, kMaxSamples));
  symmetries_opt_ =
      app.add_option("--symmetries", symmetries_,
                     "network passes averaged: the view as seen, turned by a half (2) or "
                     "every quarter turn (4), and mirrored (8) (default: the config's)")
          ->check(CLI::IsMember({1, 2, 4, 8}));
  if (which.seed)
    seed_opt_ = app.add_option("--seed", seed_, "latent code seed (default: the config's)")
                    ->transform(SeedNumber);
  threads_opt_ = app.add_option("--threads", threads_, "threads (default: the config's)")
                     ->check(FinitePositive);
  if (which.joint) app.add_flag("--no-joint", no_joint_, "skip the joint refinement (eqs. 7-9)");
}

std::vector<std::string> PerceptionOptions::inputFiles() const {
  std::vector<std::string> files{config_path_};
  std::vector<std::string> models = models_;
  if (models.empty()) {  // the config's own model, which an --output could replace as well
    const std::string model = loadPerceptionYaml(config_path_, packageDir(), "").model_path;
    if (!model.empty()) models.push_back(model);
  }
  for (const std::string& m : models) {
    files.push_back(m);
    files.push_back(modelCardPath(m));
  }
  return files;
}

std::vector<PerceptionConfig> PerceptionOptions::configs() const {
  const std::string base = packageDir();
  std::vector<std::string> models = models_;
  if (models.empty()) models.emplace_back();  // the config's own
  std::vector<PerceptionConfig> out;
  for (const std::string& model : models) {
    // Relative model paths in a config are read from the package directory; a --model path
    // is the user's, relative to the working directory.
    PerceptionConfig c = loadPerceptionYaml(
        config_path_, base, model.empty() ? "" : std::filesystem::absolute(model).string());
    if (c.model_path.empty()) throw std::runtime_error(config_path_ + ": no model given");
    if (!std::filesystem::exists(c.model_path))
      throw std::runtime_error(config_path_ + ": model " + c.model_path + " does not exist");
    if (checked_models_.insert(c.model_path).second) checkModel(c.model_path);
    if (samples_opt_->count()) c.samples = samples_;
    if (seed_opt_ && seed_opt_->count()) c.seed = seed_;
    if (threads_opt_->count()) c.threads = threads_;
    if (symmetries_opt_->count()) c.symmetries = symmetries_;
    if (no_joint_) c.joint_refinement = false;
    out.push_back(std::move(c));
  }
  return out;
}

namespace {

/// fx, fy, cx, cy of --intrinsics, and the image's width and height when it gives them.
std::vector<double> intrinsicValues(const std::string& text) {
  if (!text.empty() && text.back() == ',')  // getline would drop the empty last item
    throw std::invalid_argument("--intrinsics: '" + text + "' ends in a comma");
  std::stringstream ss(text);
  std::vector<double> v;
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      size_t used = 0;
      v.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw std::invalid_argument("--intrinsics: '" + item + "' is not a number");
    }
  }
  if (v.size() != 4 && v.size() != 6)
    throw std::invalid_argument(
        "--intrinsics needs fx,fy,cx,cy or fx,fy,cx,cy,width,height (4 or 6 numbers)");
  for (size_t i = 4; i < v.size(); ++i)
    if (!(v[i] >= 1 && v[i] <= kMaxDepthImageSide && v[i] == std::floor(v[i])))
      throw std::invalid_argument("--intrinsics: the image's " +
                                  std::string(i == 4 ? "width " : "height ") +
                                  std::to_string(v[i]) + " is not a whole number in [1, " +
                                  std::to_string(kMaxDepthImageSide) + "]");
  return v;
}

}  // namespace

PinholeCamera parseIntrinsics(const std::string& text, int width, int height) {
  const std::vector<double> v = intrinsicValues(text);
  if (v.size() == 6 && (v[4] != width || v[5] != height))
    throw std::invalid_argument("--intrinsics gives a " + std::to_string(std::lround(v[4])) + "x" +
                                std::to_string(std::lround(v[5])) + " image, but it is " +
                                std::to_string(width) + "x" + std::to_string(height));
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.fx = v[0];
  c.fy = v[1];
  c.cx = v[2];
  c.cy = v[3];
  c.validate();
  return c;
}

PinholeCamera parseCentredIntrinsics(const std::string& text) {
  const std::vector<double> v = intrinsicValues(text);
  if (v.size() == 6) return parseIntrinsics(text, static_cast<int>(v[4]), static_cast<int>(v[5]));
  const auto side = [&](double centre, const char* what) {
    if (!(centre >= 0 && 2 * centre + 1 <= kMaxDepthImageSide))
      throw std::invalid_argument(std::string("--intrinsics: ") + what + " " +
                                  std::to_string(centre) + " is not in [0, " +
                                  std::to_string((kMaxDepthImageSide - 1) / 2) + "]");
    return static_cast<int>(std::lround(2 * centre + 1));
  };
  return parseIntrinsics(text, side(v[2], "cx"), side(v[3], "cy"));
}

}  // namespace simstack
