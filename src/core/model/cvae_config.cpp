#include "simstack/model/cvae_config.h"

#include <yaml-cpp/yaml.h>

#include <stdexcept>

namespace simstack {
namespace {

template <typename T>
void get(const YAML::Node& n, const char* key, T* value) {
  if (!n[key]) return;
  try {
    *value = n[key].as<T>();
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(std::string("field '") + key + "': " + e.what());
  }
}

void require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument(what);
}

}  // namespace

void CvaeConfig::validate() const {
  require(architecture == "cvae" || architecture == "fc",
          "architecture must be 'cvae' or 'fc', got '" + architecture + "'");
  require(resolution >= 16 && (resolution & (resolution - 1)) == 0,
          "resolution must be a power of two >= 16, got " + std::to_string(resolution));
  require(extent_m > 0.0, "extent_m must be > 0");
  require(truncation_vox > 0.0, "truncation_vox must be > 0");
  require(base_channels >= 1 && max_channels >= base_channels,
          "need 1 <= base_channels <= max_channels");
  require(latent_size >= 1 && condition_size >= 1 && hidden_size >= 1,
          "latent, condition and hidden sizes must be >= 1");
  require(alpha >= 0 && beta >= 0 && gamma >= 0 && delta >= 0, "loss weights must be >= 0");
  require(tsdf_epsilon > 0.0, "tsdf_epsilon must be > 0");
}

std::string CvaeConfig::toYaml() const {
  YAML::Emitter e;
  e << YAML::BeginMap;
  e << YAML::Key << "architecture" << YAML::Value << architecture;
  e << YAML::Key << "resolution" << YAML::Value << resolution;
  e << YAML::Key << "extent_m" << YAML::Value << extent_m;
  e << YAML::Key << "truncation_vox" << YAML::Value << truncation_vox;
  e << YAML::Key << "base_channels" << YAML::Value << base_channels;
  e << YAML::Key << "max_channels" << YAML::Value << max_channels;
  e << YAML::Key << "latent_size" << YAML::Value << latent_size;
  e << YAML::Key << "condition_size" << YAML::Value << condition_size;
  e << YAML::Key << "hidden_size" << YAML::Value << hidden_size;
  e << YAML::Key << "alpha" << YAML::Value << alpha;
  e << YAML::Key << "beta" << YAML::Value << beta;
  e << YAML::Key << "gamma" << YAML::Value << gamma;
  e << YAML::Key << "delta" << YAML::Value << delta;
  e << YAML::Key << "tsdf_epsilon" << YAML::Value << tsdf_epsilon;
  e << YAML::EndMap;
  return e.c_str();
}

CvaeConfig CvaeConfig::fromYaml(const std::string& text) {
  CvaeConfig c;
  YAML::Node n;
  try {
    n = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(std::string("model config is not YAML: ") + e.what());
  }
  get(n, "architecture", &c.architecture);
  get(n, "resolution", &c.resolution);
  get(n, "extent_m", &c.extent_m);
  get(n, "truncation_vox", &c.truncation_vox);
  get(n, "base_channels", &c.base_channels);
  get(n, "max_channels", &c.max_channels);
  get(n, "latent_size", &c.latent_size);
  get(n, "condition_size", &c.condition_size);
  get(n, "hidden_size", &c.hidden_size);
  get(n, "alpha", &c.alpha);
  get(n, "beta", &c.beta);
  get(n, "gamma", &c.gamma);
  get(n, "delta", &c.delta);
  get(n, "tsdf_epsilon", &c.tsdf_epsilon);
  c.validate();
  return c;
}

void TrainConfig::validate() const {
  require(batch_size >= 2, "batch_size must be >= 2 (BatchNorm and MMD need a batch)");
  require(learning_rate > 0.0, "learning_rate must be > 0");
  require(steps >= 1, "steps must be >= 1");
  require(threads >= 1, "threads must be >= 1");
  require(checkpoint_every >= 1 && validate_every >= 1,
          "checkpoint_every and validate_every must be >= 1");
  require(validation_scenes >= 1, "validation_scenes must be >= 1");
  require(image_width >= 16 && image_height >= 16, "image size must be at least 16x16");
}

std::string TrainConfig::toYaml() const {
  YAML::Emitter e;
  e << YAML::BeginMap;
  e << YAML::Key << "batch_size" << YAML::Value << batch_size;
  e << YAML::Key << "learning_rate" << YAML::Value << learning_rate;
  e << YAML::Key << "steps" << YAML::Value << steps;
  e << YAML::Key << "threads" << YAML::Value << threads;
  e << YAML::Key << "seed" << YAML::Value << seed;
  e << YAML::Key << "checkpoint_every" << YAML::Value << checkpoint_every;
  e << YAML::Key << "validate_every" << YAML::Value << validate_every;
  e << YAML::Key << "validation_scenes" << YAML::Value << validation_scenes;
  e << YAML::Key << "image_width" << YAML::Value << image_width;
  e << YAML::Key << "image_height" << YAML::Value << image_height;
  e << YAML::Key << "sensor_noise" << YAML::Value << sensor_noise;
  e << YAML::EndMap;
  return e.c_str();
}

TrainConfig TrainConfig::fromYaml(const std::string& text) {
  TrainConfig c;
  const YAML::Node n = YAML::Load(text);
  get(n, "batch_size", &c.batch_size);
  get(n, "learning_rate", &c.learning_rate);
  get(n, "steps", &c.steps);
  get(n, "threads", &c.threads);
  get(n, "seed", &c.seed);
  get(n, "checkpoint_every", &c.checkpoint_every);
  get(n, "validate_every", &c.validate_every);
  get(n, "validation_scenes", &c.validation_scenes);
  get(n, "image_width", &c.image_width);
  get(n, "image_height", &c.image_height);
  get(n, "sensor_noise", &c.sensor_noise);
  c.validate();
  return c;
}

void loadTrainingYaml(const std::string& path, CvaeConfig* model, TrainConfig* training) {
  try {
    const YAML::Node n = YAML::LoadFile(path);
    YAML::Emitter m, t;
    m << n["model"];
    t << n["training"];
    *model = n["model"] ? CvaeConfig::fromYaml(m.c_str()) : CvaeConfig();
    *training = n["training"] ? TrainConfig::fromYaml(t.c_str()) : TrainConfig();
  } catch (const std::exception& e) {
    throw std::runtime_error("config " + path + ": " + e.what());
  }
}

}  // namespace simstack
