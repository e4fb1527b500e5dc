#pragma once
/// @file grasp_settings.h
/// The grasp ranking's settings as config/grasps.yaml names them, read in one place: the grasp
/// server reads its parameters through it and simstack_rank_grasps the file itself, so that
/// both rank with the same cup, seal, physics and perturbed copies.

#include <set>
#include <string>

#include "simstack/grasping/grasp_ranking.h"
#include "simstack/grasping/grasp_request.h"

namespace simstack {

struct GraspSettings {
  GraspPolicy policy;          ///< what a request may ask
  GraspRankingConfig ranking;  ///< cup, seal, physics, perturbed copies, threads
  GraspSettings() { ranking.threads = 2; }
  /// Throws std::invalid_argument naming the setting as config/grasps.yaml writes it.
  void validate() const;
};

/// The grasp server's own parameters, which a grasps file may hold beside the settings: its
/// scene topic, its diagnostics period, its action's namespace and actionlib's status rate.
inline const std::set<std::string> kGraspServerKeys = {
    "objects_topic", "diagnostic_period", "rank_grasps_action", "actionlib_status_frequency"};

/// The settings in YAML `text` (a map of config/grasps.yaml's fields; absent ones keep their
/// defaults), checked. Keys in `ignored` are skipped (a caller's own, such as the server's
/// objects_topic). Throws, naming the key and `source`: std::runtime_error for text that does
/// not parse or a key no setting has, std::invalid_argument for a value of the wrong type or
/// out of range.
GraspSettings parseGraspSettingsYaml(const std::string& text, const std::string& source,
                                     const std::set<std::string>& ignored = {});

/// parseGraspSettingsYaml of the file at `path` (std::runtime_error also when it cannot be read).
GraspSettings loadGraspSettingsYaml(const std::string& path,
                                    const std::set<std::string>& ignored = {});

}  // namespace simstack
