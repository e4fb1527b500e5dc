#include "simstack/offline/training/train_config.h"

#include <yaml-cpp/yaml.h>

#include <stdexcept>
#include <string>

#include "simstack/io/config_fields.h"
#include "simstack/io/yaml_file.h"
#include "simstack/render/depth_renderer.h"

namespace simstack {
namespace {

template <class C, class F>
void trainFields(C& c, F&& f) {
  f("batch_size", c.batch_size);
  f("learning_rate", c.learning_rate);
  f("final_learning_rate", c.final_learning_rate);
  f("steps", c.steps);
  f("threads", c.threads);
  f("seed", c.seed);
  f("checkpoint_every", c.checkpoint_every);
  f("validate_every", c.validate_every);
  f("validation_scenes", c.validation_scenes);
  f("validation_views", c.validation_views);
  f("validation_samples", c.validation_samples);
  f("image_width", c.image_width);
  f("image_height", c.image_height);
  f("sensor_noise", c.sensor_noise);
  f("sensor_model", c.sensor_model);
  f("init_from", c.init_from);
}
template <class C, class F>
void trainExperimentalFields(C& c, F&& f) {
  f("overhead_share", c.overhead_share);
}
template <class C, class F>
void trainAllFields(C& c, F&& f) {
  trainFields(c, f);
  trainExperimentalFields(c, f);
}

TrainConfig trainFromNodes(const YAML::Node& n, const YAML::Node& x, const std::string& prefix,
                           const std::string& x_prefix) {
  TrainConfig c;
  trainFields(c, [&](const char* key, auto& value) { readConfigField(n, key, &value, prefix); });
  trainExperimentalFields(
      c, [&](const char* key, auto& value) { readConfigField(x, key, &value, x_prefix); });
  c.validate();
  return c;
}

}  // namespace

void TrainConfig::validate() const {
  requireConfig(batch_size >= 2 && batch_size <= 1024,
                "batch_size must lie in [2, 1024] (BatchNorm and MMD need a batch), not " +
                    std::to_string(batch_size));
  requireConfig(learning_rate > 0.0, "learning_rate must be > 0" + gotValue(learning_rate));
  requireConfig(final_learning_rate > 0.0 && final_learning_rate <= learning_rate,
                "final_learning_rate must be > 0 and <= learning_rate (" +
                    configValue(learning_rate) + ")" + gotValue(final_learning_rate));
  requireConfig(steps >= 1, "steps must be >= 1" + gotValue(steps));
  requireConfig(threads >= 1 && threads <= 256, "threads must lie in [1, 256]" + gotValue(threads));
  requireConfig(checkpoint_every >= 1,
                "checkpoint_every must be >= 1" + gotValue(checkpoint_every));
  requireConfig(validate_every >= 1, "validate_every must be >= 1" + gotValue(validate_every));
  requireConfig(validation_scenes >= 1,
                "validation_scenes must be >= 1" + gotValue(validation_scenes));
  requireConfig(validation_views >= 1 && validation_views <= 64,
                "validation_views must lie in [1, 64], not " + std::to_string(validation_views));
  requireConfig(validation_samples >= 2 && validation_samples <= 256,
                "validation_samples must lie in [2, 256]" + gotValue(validation_samples));
  requireConfig(
      image_width >= 16 && image_height >= 16 && image_width <= 4096 && image_height <= 4096,
      "image_width and image_height must lie in [16, 4096], not " + std::to_string(image_width) +
          "x" + std::to_string(image_height));
  requireConfig(overhead_share >= 0.0 && overhead_share <= 1.0,
                "overhead_share must lie in [0, 1]" + gotValue(overhead_share));
  parseSensorModel(sensor_model);  // throws naming the value and the choices
}

std::string TrainConfig::toYaml() const {
  YAML::Emitter e;
  e << YAML::BeginMap;
  trainAllFields(*this, [&](const char* key, const auto& value) {
    e << YAML::Key << key << YAML::Value << value;
  });
  e << YAML::EndMap;
  return e.c_str();
}

TrainConfig TrainConfig::fromYaml(const std::string& text) {
  const YAML::Node n = parseConfigText(text, "training");
  return trainFromNodes(n, n, "", "");
}

void loadTrainingYaml(const std::string& path, CvaeConfig* model, TrainConfig* training) {
  const YAML::Node n = loadYamlFile(path, "training config");
  try {
    if (n.IsNull()) {  // nothing but comments: the defaults
      *model = CvaeConfig();
      *training = TrainConfig();
      return;
    }
    if (!n.IsMap()) throw std::invalid_argument("expected a YAML map");
    for (const auto& kv : n) {
      const std::string section = kv.first.as<std::string>();
      if (section != "model" && section != "training")
        throw std::invalid_argument("unknown section '" + section + "' (model, training)");
    }
    const YAML::Node m = n["model"], t = n["training"];
    *model = CvaeConfig();
    if (m && !m.IsNull()) *model = cvaeConfigFromSection(m);
    *training = TrainConfig();
    if (t && !t.IsNull())
      *training = trainFromNodes(t,
                                 experimentalOf<TrainConfig>(
                                     t, "training", [](auto& c, auto&& f) { trainFields(c, f); },
                                     [](auto& c, auto&& f) { trainExperimentalFields(c, f); }),
                                 "training.", "training.experimental.");
  } catch (const std::exception& e) {
    throw std::runtime_error("config " + path + ": " + e.what());
  }
}

}  // namespace simstack
