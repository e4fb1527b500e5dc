#include "simstack/grasping/grasp_settings.h"

#include <cmath>
#include <stdexcept>
#include <type_traits>

#include "simstack/io/yaml_file.h"

namespace simstack {
namespace {

/// Every setting once, with its field: reading and the check for unknown keys walk the same
/// list. The topple angle is written in degrees (`topple_deg`), kept in radians.
template <class F>
void settingFields(GraspSettings& s, double& topple_deg, F&& f) {
  CandidateConfig& k = s.ranking.candidates;
  PullConfig& p = s.ranking.pull;
  PerturbationConfig& q = s.ranking.perturbation;
  f("threads", s.ranking.threads);
  f("max_candidates", s.policy.max_candidates);
  f("max_candidates_limit", s.policy.max_candidates_limit);
  f("max_pull_distance_m", s.policy.max_pull_distance_m);
  f("max_scene_age_s", s.policy.max_scene_age_s);
  f("pregrasp_distance_m", s.policy.pregrasp_distance_m);
  f("cup_radius_m", k.cup_radius_m);
  f("seal_tolerance_m", k.seal_tolerance_m);
  f("surface_samples", k.surface_samples);
  f("tool_length_m", k.tool_length_m);
  f("max_force_n", p.max_force_n);
  f("cup_stiffness_hz", p.cup_stiffness_hz);
  f("settle_s", p.settle_s);
  f("topple_deg", topple_deg);
  f("density_kgpm3", p.physics.density_kgpm3);
  f("perturbed_copies", q.copies);
  f("perturb_position_m", q.position_m);
  f("perturb_rotation_deg", q.rotation_deg);
  f("perturb_scale_share", q.scale_share);
  f("match_distance_m", s.ranking.match_distance_m);
}

}  // namespace

void GraspSettings::validate() const {
  const auto positive = [](double v, const char* name) {
    if (!(v > 0.0) || !std::isfinite(v))
      throw std::invalid_argument(std::string(name) + " must be a positive number");
  };
  // The ranges simstack_rank_grasps gives the options that override these fields.
  const auto within = [](double v, double low, double high, const char* name) {
    if (!(v >= low && v <= high))
      throw std::invalid_argument(std::string(name) + " must lie in [" + number(low) + ", " +
                                  number(high) + "], not " + number(v));
  };
  policy.validate();
  within(policy.max_candidates, 1, 1024, "max_candidates");
  within(ranking.pull.max_force_n, 0.1, 1000.0, "max_force_n");
  within(ranking.candidates.cup_radius_m, 0.002, 0.1, "cup_radius_m");
  within(ranking.threads, 0, 1024, "threads");
  // Said as the file gives it, in degrees: no turn passes 180.
  within(ranking.pull.topple_rad * 180.0 / M_PI, 0.1, 180.0, "topple_deg");
  positive(ranking.candidates.seal_tolerance_m, "seal_tolerance_m");
  positive(ranking.candidates.tool_length_m, "tool_length_m");
  positive(ranking.match_distance_m, "match_distance_m");
  if (ranking.candidates.surface_samples < 100 || ranking.candidates.surface_samples > 100000)
    throw std::invalid_argument("surface_samples must lie in [100, 100000]");
  ranking.pull.validate();
  ranking.perturbation.validate();
}

namespace {

GraspSettings settingsFromNode(const YAML::Node& root, const std::string& source,
                               const std::set<std::string>& ignored) {
  GraspSettings s;
  double topple_deg = s.ranking.pull.topple_rad * 180.0 / M_PI;
  if (root.IsNull()) return s;
  if (!root.IsMap())
    throw std::invalid_argument(source + ": the grasp settings must be a map of fields");
  std::set<std::string> known = ignored;
  settingFields(s, topple_deg, [&](const char* name, auto&) { known.insert(name); });
  requireKnownKeys(root, known, "the grasp settings", source);
  try {
    settingFields(s, topple_deg, [&](const char* name, auto& value) {
      const YAML::Node node = root[name];
      if (!node) return;
      if constexpr (std::is_integral_v<std::decay_t<decltype(value)>>) {
        // A whole number written as 2.0 (as rosparam may hand it over) is the number 2.
        const double v = readYamlValue<double>(node, name);
        if (v != std::floor(v) || std::abs(v) > 1e9)
          throw std::invalid_argument(std::string(name) + ": " + node.Scalar() +
                                      " is not a whole number");
        value = static_cast<int>(v);
      } else {
        value = readYamlValue<double>(node, name);
      }
    });
    s.ranking.pull.cup_radius_m = s.ranking.candidates.cup_radius_m;
    s.ranking.pull.topple_rad = topple_deg * M_PI / 180.0;
    s.validate();
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(source + ": " + e.what());
  }
  return s;
}

}  // namespace

GraspSettings parseGraspSettingsYaml(const std::string& text, const std::string& source,
                                     const std::set<std::string>& ignored) {
  return settingsFromNode(parseYamlText(text, "grasp settings", source), source, ignored);
}

GraspSettings loadGraspSettingsYaml(const std::string& path, const std::set<std::string>& ignored) {
  return settingsFromNode(loadYamlFile(path, "grasp settings"), path, ignored);
}

}  // namespace simstack
