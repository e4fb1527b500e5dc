#include "simstack/model/cvae_config.h"

#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <set>
#include <stdexcept>
#include <utility>

#include "simstack/io/config_fields.h"
#include "simstack/io/yaml_file.h"
#include "simstack/render/depth_renderer.h"

namespace simstack {
namespace {

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

}  // namespace

void CvaeConfig::validate() const {
  requireConfig(architecture == "cvae" || architecture == "fc" || architecture == "fc_plain",
                "architecture must be 'cvae', 'fc' or 'fc_plain', got '" + architecture + "'");
  // Up to 512: the grids index their voxels with 32-bit ints (R^3 passes 2^31 above 1290), and
  // one float grid at 512 already takes 0.5 GB.
  requireConfig(
      resolution >= 16 && resolution <= 512 && (resolution & (resolution - 1)) == 0,
      "resolution must be a power of two in [16, 512], got " + std::to_string(resolution));
  requireConfig(extent_m > 0.0, "extent_m must be > 0" + gotValue(extent_m));
  requireConfig(truncation_vox > 0.0, "truncation_vox must be > 0" + gotValue(truncation_vox));
  // The upper bounds are far beyond what trains on one machine: past them a size is a typo, and
  // the network's allocation would fail with a message that names no field.
  requireConfig(base_channels >= 1 && max_channels >= base_channels && max_channels <= 1024,
                "need 1 <= base_channels <= max_channels <= 1024, got " +
                    std::to_string(base_channels) + " and " + std::to_string(max_channels));
  requireConfig(latent_size >= 1 && latent_size <= 4096 && condition_size >= 1 &&
                    condition_size <= 4096 && hidden_size >= 1 && hidden_size <= 65536,
                "latent_size and condition_size must lie in [1, 4096] and hidden_size in [1, "
                "65536], got " +
                    std::to_string(latent_size) + ", " + std::to_string(condition_size) + " and " +
                    std::to_string(hidden_size));
  for (const auto& [name, weight] : {std::pair<const char*, double>{"alpha", alpha},
                                     {"beta", beta},
                                     {"gamma", gamma},
                                     {"delta", delta}})
    requireConfig(weight >= 0,
                  std::string(name) + " (a loss weight) must be >= 0" + gotValue(weight));
  requireConfig(norm == "batch" || norm == "group",
                "norm must be 'batch' or 'group', got '" + norm + "'");
  requireConfig(latent_injection == "bottleneck" || latent_injection == "every_scale" ||
                    latent_injection == "condition",
                "latent_injection must be 'bottleneck', 'every_scale' or 'condition', got '" +
                    latent_injection + "'");
  requireConfig(hidden_condition == "full" || hidden_condition == "coarse",
                "hidden_condition must be 'full' or 'coarse', got '" + hidden_condition + "'");
  // The MMD's kernel matrices take N^2 floats per kernel width (4096 draws: 64 MB each).
  requireConfig(mmd_prior_samples >= 2 && mmd_prior_samples <= 4096,
                "mmd_prior_samples must lie in [2, 4096]" + gotValue(mmd_prior_samples));
  requireConfig(!mmd_kernel_widths.empty(), "mmd_kernel_widths needs at least one width");
  for (double w : mmd_kernel_widths)
    requireConfig(w > 0.0, "mmd_kernel_widths must be > 0" + gotValue(w));
  requireConfig(tsdf_epsilon > 0.0, "tsdf_epsilon must be > 0" + gotValue(tsdf_epsilon));
  requireConfig(occupancy_weight >= 0.0,
                "occupancy_weight must be >= 0" + gotValue(occupancy_weight));
  requireConfig(occupancy_sharpness > 0.0,
                "occupancy_sharpness must be > 0" + gotValue(occupancy_sharpness));
  requireConfig(iou_weight >= 0.0, "iou_weight must be >= 0" + gotValue(iou_weight));
  requireConfig(condition_dropout >= 0.0 && condition_dropout < 1.0,
                "condition_dropout must lie in [0, 1)" + gotValue(condition_dropout));
  requireConfig(posterior == "gaussian" || posterior == "deterministic",
                "posterior must be 'gaussian' or 'deterministic', got '" + posterior + "'");
  requireConfig(prior == "standard" || prior == "learned",
                "prior must be 'standard' or 'learned', got '" + prior + "'");
  requireConfig(prior == "standard" || posterior == "gaussian",
                "a learned prior needs posterior 'gaussian' (the KL compares two Gaussians)");
  requireConfig(kl_weight >= 0.0, "kl_weight must be >= 0" + gotValue(kl_weight));
  requireConfig(kl_free_nats >= 0.0, "kl_free_nats must be >= 0" + gotValue(kl_free_nats));
  requireConfig(best_of >= 1 && best_of <= 16, "best_of must lie in 1-16" + gotValue(best_of));
  requireConfig(best_of == 1 || (hasLatentCode() && posterior == "gaussian"),
                "best_of > 1 needs the C-VAE's code drawn from a Gaussian posterior");
  requireConfig(vote_boundary_weight >= 0.0,
                "vote_boundary_weight must be >= 0" + gotValue(vote_boundary_weight));
  requireConfig(vote_loss == "occupied" || vote_loss == "all",
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
  cvaeFields(c, [&](const char* key, auto& value) { readConfigField(n, key, &value, prefix); });
  cvaeExperimentalFields(
      c, [&](const char* key, auto& value) { readConfigField(x, key, &value, x_prefix); });
  c.validate();
  return c;
}
}  // namespace

CvaeConfig CvaeConfig::fromYaml(const std::string& text) {
  const YAML::Node n = parseConfigText(text, "model");
  return cvaeFromNodes(n, n, "", "");
}

std::string modelCardPath(const std::string& model_path) {
  return std::filesystem::path(model_path).replace_extension(".yaml").string();
}

YAML::Node loadModelCard(const std::string& card_path) {
  const YAML::Node root = loadYamlFile(card_path, "model card");
  if (!root.IsMap())
    throw std::runtime_error(card_path + (root.IsNull() ? ": the model card is empty" : "") +
                             ": a model card is a YAML map of sections (model, training, "
                             "provenance, perception, evaluation, integrity)");
  static const std::set<std::string> kSections = {"model",      "training",   "provenance",
                                                  "perception", "evaluation", "integrity"};
  for (const auto& kv : root) {
    if (!kv.first.IsScalar())
      throw std::runtime_error(card_path + ": a section name that is not a word");
    const std::string key = kv.first.as<std::string>();
    if (!kSections.count(key))
      throw std::runtime_error(card_path + ": unknown section '" + key +
                               "' (a model card holds model, training, provenance, perception, "
                               "evaluation and integrity)");
  }
  return root;
}

CvaeConfig cvaeConfigFromSection(const YAML::Node& section) {
  return cvaeFromNodes(section,
                       experimentalOf<CvaeConfig>(
                           section, "model", [](auto& c, auto&& f) { cvaeFields(c, f); },
                           [](auto& c, auto&& f) { cvaeExperimentalFields(c, f); }),
                       "model.", "model.experimental.");
}

}  // namespace simstack
