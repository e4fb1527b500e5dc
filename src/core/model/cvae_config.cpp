#include "simstack/model/cvae_config.h"

#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <set>
#include <stdexcept>

#include "simstack/io/yaml_file.h"
#include "simstack/render/depth_renderer.h"

namespace simstack {
namespace {

/// `prefix` ("model.experimental.") names the field in errors.
template <typename T>
void get(const YAML::Node& n, const char* key, T* value, const std::string& prefix = "") {
  if (n[key]) *value = readYamlValue<T>(n[key], "field '" + prefix + key + "'");
}

YAML::Node parse(const std::string& text, const std::string& section) {
  try {
    return YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(section + " config is not YAML: " + e.what());
  }
}

// Every field once, with its YAML name: serialisation and parsing both walk these lists.
template <class C, class F>
void cvaeFields(C& c, F&& f) {
  f("architecture", c.architecture);
  f("resolution", c.resolution);
  f("extent_m", c.extent_m);
  f("truncation_vox", c.truncation_vox);
  f("base_channels", c.base_channels);
  f("max_channels", c.max_channels);
  f("latent_size", c.latent_size);
  f("condition_size", c.condition_size);
  f("hidden_size", c.hidden_size);
  f("latent_injection", c.latent_injection);
  f("alpha", c.alpha);
  f("beta", c.beta);
  f("gamma", c.gamma);
  f("delta", c.delta);
  f("mmd_prior_samples", c.mmd_prior_samples);
  f("tsdf_epsilon", c.tsdf_epsilon);
  f("occupancy_weight", c.occupancy_weight);
  f("occupancy_sharpness", c.occupancy_sharpness);
  f("iou_weight", c.iou_weight);
  f("vote_loss", c.vote_loss);
  f("vote_boundary_weight", c.vote_boundary_weight);
  f("best_of", c.best_of);
}
// `model.experimental` in a training file: variants measured and not kept (docs/experiments.md,
// "Hypotheses (C-VAE codes)"); the defaults are the paper's and every shipped model's.
template <class C, class F>
void cvaeExperimentalFields(C& c, F&& f) {
  f("norm", c.norm);
  f("hidden_condition", c.hidden_condition);
  f("mmd_kernel_widths", c.mmd_kernel_widths);
  f("condition_dropout", c.condition_dropout);
  f("posterior", c.posterior);
  f("prior", c.prior);
  f("kl_weight", c.kl_weight);
  f("kl_free_nats", c.kl_free_nats);
}
// Every field: the flat form a model file stores its network in.
template <class C, class F>
void cvaeAllFields(C& c, F&& f) {
  cvaeFields(c, f);
  cvaeExperimentalFields(c, f);
}

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

void require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument(what);
}

}  // namespace

void CvaeConfig::validate() const {
  require(architecture == "cvae" || architecture == "fc" || architecture == "fc_plain",
          "architecture must be 'cvae', 'fc' or 'fc_plain', got '" + architecture + "'");
  require(resolution >= 16 && (resolution & (resolution - 1)) == 0,
          "resolution must be a power of two >= 16, got " + std::to_string(resolution));
  require(extent_m > 0.0, "extent_m must be > 0");
  require(truncation_vox > 0.0, "truncation_vox must be > 0");
  require(base_channels >= 1 && max_channels >= base_channels,
          "need 1 <= base_channels <= max_channels");
  require(latent_size >= 1 && condition_size >= 1 && hidden_size >= 1,
          "latent, condition and hidden sizes must be >= 1");
  require(alpha >= 0 && beta >= 0 && gamma >= 0 && delta >= 0, "loss weights must be >= 0");
  require(norm == "batch" || norm == "group",
          "norm must be 'batch' or 'group', got '" + norm + "'");
  require(latent_injection == "bottleneck" || latent_injection == "every_scale" ||
              latent_injection == "condition",
          "latent_injection must be 'bottleneck', 'every_scale' or 'condition', got '" +
              latent_injection + "'");
  require(hidden_condition == "full" || hidden_condition == "coarse",
          "hidden_condition must be 'full' or 'coarse', got '" + hidden_condition + "'");
  require(mmd_prior_samples >= 2, "mmd_prior_samples must be >= 2");
  require(!mmd_kernel_widths.empty(), "mmd_kernel_widths needs at least one width");
  for (double w : mmd_kernel_widths) require(w > 0.0, "mmd_kernel_widths must be > 0");
  require(tsdf_epsilon > 0.0, "tsdf_epsilon must be > 0");
  require(occupancy_weight >= 0.0, "occupancy_weight must be >= 0");
  require(occupancy_sharpness > 0.0, "occupancy_sharpness must be > 0");
  require(iou_weight >= 0.0, "iou_weight must be >= 0");
  require(condition_dropout >= 0.0 && condition_dropout < 1.0,
          "condition_dropout must lie in [0, 1)");
  require(posterior == "gaussian" || posterior == "deterministic",
          "posterior must be 'gaussian' or 'deterministic', got '" + posterior + "'");
  require(prior == "standard" || prior == "learned",
          "prior must be 'standard' or 'learned', got '" + prior + "'");
  require(prior == "standard" || posterior == "gaussian",
          "a learned prior needs posterior 'gaussian' (the KL compares two Gaussians)");
  require(kl_weight >= 0.0, "kl_weight must be >= 0");
  require(kl_free_nats >= 0.0, "kl_free_nats must be >= 0");
  require(best_of >= 1 && best_of <= 16, "best_of must lie in 1-16");
  require(best_of == 1 || (hasLatentCode() && posterior == "gaussian"),
          "best_of > 1 needs the C-VAE's code drawn from a Gaussian posterior");
  require(vote_boundary_weight >= 0.0, "vote_boundary_weight must be >= 0");
  require(vote_loss == "occupied" || vote_loss == "all",
          "vote_loss must be 'occupied' or 'all', got '" + vote_loss + "'");
}

void CvaeConfig::copyLossSettings(const CvaeConfig& o) {
  alpha = o.alpha;
  beta = o.beta;
  gamma = o.gamma;
  delta = o.delta;
  mmd_prior_samples = o.mmd_prior_samples;
  mmd_kernel_widths = o.mmd_kernel_widths;
  tsdf_epsilon = o.tsdf_epsilon;
  occupancy_weight = o.occupancy_weight;
  occupancy_sharpness = o.occupancy_sharpness;
  iou_weight = o.iou_weight;
  vote_loss = o.vote_loss;
  vote_boundary_weight = o.vote_boundary_weight;
  condition_dropout = o.condition_dropout;
  posterior = o.posterior;
  kl_weight = o.kl_weight;
  kl_free_nats = o.kl_free_nats;
  best_of = o.best_of;
}

std::string CvaeConfig::toYaml() const {
  YAML::Emitter e;
  e << YAML::BeginMap;
  cvaeAllFields(*this, [&](const char* key, const auto& value) {
    e << YAML::Key << key << YAML::Value << value;
  });
  e << YAML::EndMap;
  return e.c_str();
}

namespace {
// From the nodes themselves, not from text emitted again: a bad value's line is the file's.
// `x` holds the experimental fields: the section's `experimental:` map in a training file, the
// section itself in the flat form a model file stores.
CvaeConfig cvaeFromNodes(const YAML::Node& n, const YAML::Node& x, const std::string& prefix,
                         const std::string& x_prefix) {
  CvaeConfig c;
  cvaeFields(c, [&](const char* key, auto& value) { get(n, key, &value, prefix); });
  cvaeExperimentalFields(c, [&](const char* key, auto& value) { get(x, key, &value, x_prefix); });
  c.validate();
  return c;
}
TrainConfig trainFromNodes(const YAML::Node& n, const YAML::Node& x, const std::string& prefix,
                           const std::string& x_prefix) {
  TrainConfig c;
  trainFields(c, [&](const char* key, auto& value) { get(n, key, &value, prefix); });
  trainExperimentalFields(c, [&](const char* key, auto& value) { get(x, key, &value, x_prefix); });
  c.validate();
  return c;
}
}  // namespace

CvaeConfig CvaeConfig::fromYaml(const std::string& text) {
  const YAML::Node n = parse(text, "model");
  return cvaeFromNodes(n, n, "", "");
}

void TrainConfig::validate() const {
  require(batch_size >= 2, "batch_size must be >= 2 (BatchNorm and MMD need a batch)");
  require(learning_rate > 0.0, "learning_rate must be > 0");
  require(final_learning_rate > 0.0 && final_learning_rate <= learning_rate,
          "final_learning_rate must be > 0 and <= learning_rate");
  require(steps >= 1, "steps must be >= 1");
  require(threads >= 1 && threads <= 256, "threads must lie in [1, 256]");
  require(checkpoint_every >= 1 && validate_every >= 1,
          "checkpoint_every and validate_every must be >= 1");
  require(validation_scenes >= 1, "validation_scenes must be >= 1");
  require(validation_views >= 1, "validation_views must be >= 1");
  require(validation_samples >= 2 && validation_samples <= 256,
          "validation_samples must lie in [2, 256]");
  require(image_width >= 16 && image_height >= 16, "image size must be at least 16x16");
  require(overhead_share >= 0.0 && overhead_share <= 1.0, "overhead_share must lie in [0, 1]");
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
  const YAML::Node n = parse(text, "training");
  return trainFromNodes(n, n, "", "");
}

std::string modelCardPath(const std::string& model_path) {
  return std::filesystem::path(model_path).replace_extension(".yaml").string();
}

namespace {
// A misspelt field in a file the user writes must not fall back to its default unnoticed
// (configs stored inside older model files are parsed leniently instead).
template <class C, class Fields>
void rejectUnknownFields(const YAML::Node& section, const std::string& name, Fields fields,
                         bool with_experimental) {
  if (!section.IsMap()) throw std::invalid_argument("'" + name + "' must be a map");
  C defaults;
  std::set<std::string> known;
  fields(defaults, [&](const char* key, const auto&) { known.insert(key); });
  if (with_experimental) known.insert("experimental");
  for (const auto& kv : section) {
    const std::string key = kv.first.as<std::string>();
    if (!known.count(key)) throw std::invalid_argument("unknown field " + name + "." + key);
  }
}

/// The `experimental:` map of the section `name` of a training file, its fields checked (an
/// empty map when there is none). A dropped variant's setting written outside it is refused
/// with the place it belongs.
template <class C, class Main, class Experimental>
YAML::Node experimentalOf(const YAML::Node& section, const std::string& name, Main main,
                          Experimental experimental) {
  if (!section.IsMap()) throw std::invalid_argument("'" + name + "' must be a map");
  C defaults;
  experimental(defaults, [&](const char* key, const auto&) {
    if (section[key])
      throw std::invalid_argument(name + "." + key + " is a dropped variant's setting: write it " +
                                  "under " + name + ".experimental");
  });
  rejectUnknownFields<C>(section, name, main, true);
  const YAML::Node x = section["experimental"];
  if (!x || x.IsNull()) return YAML::Node(YAML::NodeType::Map);
  rejectUnknownFields<C>(x, name + ".experimental", experimental, false);
  return x;
}
}  // namespace

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
    if (m && !m.IsNull())
      *model = cvaeFromNodes(m,
                             experimentalOf<CvaeConfig>(
                                 m, "model", [](auto& c, auto&& f) { cvaeFields(c, f); },
                                 [](auto& c, auto&& f) { cvaeExperimentalFields(c, f); }),
                             "model.", "model.experimental.");
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
