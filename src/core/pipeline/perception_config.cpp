#include "simstack/pipeline/perception_config.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <array>
#include <filesystem>
#include <set>
#include <stdexcept>
#include <type_traits>

#include "simstack/io/config_fields.h"
#include "simstack/io/yaml_file.h"
#include "simstack/model/cvae_inference.h"

namespace simstack {
namespace {

// Every field once, with its YAML name: reading and writing walk the same lists.
template <class C, class F>
void perceptionFields(C& c, F&& f) {
  f("model", c.model_path);
  f("samples", c.samples);
  f("zero_code_first", c.zero_code_first);
  f("seed", c.seed);
  f("decompose_samples", c.decompose_samples);
  f("symmetries", c.symmetries);
  f("points_per_instance", c.points_per_instance);
  f("observed_points", c.observed_points);
  f("min_instance_points", c.min_instance_points);
  f("joint_refinement", c.joint_refinement);
  f("min_pile_height_m", c.min_pile_height_m);
  f("min_depth_m", c.min_depth_m);
  f("max_depth_m", c.max_depth_m);
  f("threads", c.threads);
  f("refine_iterations", c.refine_iterations);
  f("refine_learning_rate", c.refine_learning_rate);
  f("refine_prior_weight", c.refine_prior_weight);
  f("refine_starts", c.refine_starts);
  f("refine_evidence", c.refine_evidence);
  f("refine_on_passes", c.refine_on_passes);
  f("condition_views", c.condition_views);
}
template <class C, class F>
void houghFields(C& c, F&& f) {
  f("refinement", c.refinement);
  f("min_traversals", c.min_traversals);
  f("gamma", c.gamma);
  f("bandwidth_m", c.bandwidth_m);
  f("min_instance_voxels", c.min_instance_voxels);
  f("min_vote_norm", c.min_vote_norm);
  f("outside_tolerance_vox", c.outside_tolerance_vox);
}
template <class C, class F>
void segmentFields(C& c, F&& f) {
  f("enabled", c.enabled);
  f("pixel_stride", c.pixel_stride);
  f("voxel_resolution_m", c.voxel_resolution_m);
  f("seed_resolution_m", c.seed_resolution_m);
  f("concavity_tolerance_deg", c.concavity_tolerance_deg);
  f("min_segment_points", c.min_segment_points);
  f("min_instance_share", c.min_instance_share);
  f("fragment_share", c.fragment_share);
  f("max_unseen_points", c.max_unseen_points);
  f("apart_vote_divergence", c.apart_vote_divergence);
  f("min_boundary_faces", c.min_boundary_faces);
  f("free_space_margin_m", c.free_space_margin_m);
  f("max_free_share", c.max_free_share);
  f("hull_samples", c.hull_samples);
  f("same_centre_m", c.same_centre_m);
  f("depth_jump_ratio", c.depth_jump_ratio);
  f("depth_jump_share", c.depth_jump_share);
  f("crease_angle_deg", c.crease_angle_deg);
  f("crease_window_px", c.crease_window_px);
  f("crease_offset_px", c.crease_offset_px);
}
template <class C, class F>
void surfaceInstanceFields(C& c, F&& f) {
  f("enabled", c.enabled);
  f("min_height_m", c.min_height_m);
  f("max_base_height_m", c.max_base_height_m);
  f("cluster_tolerance_m", c.cluster_tolerance_m);
  f("min_points", c.min_points);
  f("attach_share", c.attach_share);
  f("container_profile_m", c.container_profile_m);
  f("container_min_arc_deg", c.container_min_arc_deg);
  f("container_inside_share", c.container_inside_share);
  f("held_container_profile_m", c.held_container_profile_m);
  f("occluded_plane_m", c.occluded_plane_m);
  f("held_occluded_plane_m", c.held_occluded_plane_m);
  f("occluded_margin_m", c.occluded_margin_m);
  f("occluded_share", c.occluded_share);
  f("occluded_edge_m", c.occluded_edge_m);
  f("fit_overlap_share", c.fit_overlap_share);
}
template <class C, class F>
void crowdedFields(C& c, F&& f) {
  f("min_objects", c.min_objects);
  f("bandwidth_m", c.bandwidth_m);
  f("min_instance_voxels", c.min_instance_voxels);
  f("max_unseen_points", c.max_unseen_points);
}
template <class C, class F>
void gridFields(C& c, F&& f) {
  f("side_m", c.side_m);
  f("object_voxels", c.object_voxels);
  f("smallest_object_voxels", c.smallest_object_voxels);
  f("fine_side_share", c.fine_side_share);
}
template <class C, class F>
void fitFields(C& c, F&& f) {
  f("min_scale_m", c.min_scale_m);
  f("max_scale_m", c.max_scale_m);
  f("min_exponent", c.min_exponent);
  f("max_exponent", c.max_exponent);
  f("initial_exponent", c.initial_exponent);
  f("lambda_dist", c.lambda_dist);
  f("lambda_coll", c.lambda_coll);
  f("lambda_floor", c.lambda_floor);
  f("max_points", c.max_points);
  f("surrounded_share", c.surrounded_share);
  f("one_sided_volume_exponent", c.one_sided_volume_exponent);
  f("one_sided_growth_limit", c.one_sided_growth_limit);
  f("coarse_points", c.coarse_points);
  f("joint_points", c.joint_points);
  f("shape_samples", c.shape_samples);
  f("contact_margin_m", c.contact_margin_m);
  f("joint_rounds", c.joint_rounds);
  f("start_iterations", c.start_iterations);
  f("max_iterations", c.max_iterations);
  f("joint_max_iterations", c.joint_max_iterations);
}
template <class C, class F>
void tableFields(C& c, F&& f) {
  f("inlier_distance_m", c.inlier_distance_m);
  f("max_iterations", c.max_iterations);
  f("pixel_stride", c.pixel_stride);
  f("max_depth_m", c.max_depth_m);
  f("min_inlier_share", c.min_inlier_share);
  f("max_planes", c.max_planes);
  f("max_behind_share", c.max_behind_share);
}
template <class C, class F>
void workspaceFields(C& c, F&& f) {
  f("min_m", c.min_m);
  f("max_m", c.max_m);
  f("max_tiles", c.max_tiles);
  f("tile_overlap_m", c.tile_overlap_m);
}

template <class T>
void emit(YAML::Emitter& e, const T& value) {
  e << value;
}
void emit(YAML::Emitter& e, const std::array<double, 3>& value) {
  e << YAML::Flow << YAML::BeginSeq;
  for (double v : value) e << v;
  e << YAML::EndSeq;
}

/// Reads the fields `fields` names from the map `n` into `c`; `prefix` ("hough.") names them in
/// errors. Keys of `n` that are not fields are left to the caller.
template <class C, class Fields>
void readFields(const YAML::Node& n, const std::string& prefix, C* c, Fields fields,
                const std::string& path) {
  fields(*c, [&](const char* key, auto& value) {
    if (!n[key]) return;
    try {
      value = readYamlValue<std::remove_reference_t<decltype(value)>>(n[key], prefix + key);
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(path + ": " + e.what());
    }
  });
}

/// The section `name` of `root` ("hough"): its fields into `c`, any other key an error; absent
/// or empty (every field left out): the defaults.
template <class C, class Fields>
void readSection(const YAML::Node& root, const char* name, C* c, Fields fields,
                 const std::string& path) {
  const YAML::Node n = root[name];
  if (!n || n.IsNull()) return;
  if (!n.IsMap()) throw std::runtime_error(path + ": '" + name + "' must be a map");
  readFields(n, std::string(name) + ".", c, fields, path);
  std::set<std::string> known;
  fields(*c, [&](const char* key, auto&) { known.insert(key); });
  for (const auto& kv : n) {
    const std::string key = kv.first.as<std::string>();
    if (!known.count(key)) throw std::runtime_error(path + ": unknown field " + name + "." + key);
  }
}

/// The fields `fields` names, as keys and values of the map being written.
template <class C, class Fields>
void writeFields(YAML::Emitter& e, C& c, Fields fields) {
  fields(c, [&](const char* key, const auto& value) {
    e << YAML::Key << key << YAML::Value;
    emit(e, value);
  });
}

template <class C, class Fields>
void writeSection(YAML::Emitter& e, const char* name, C& c, Fields fields) {
  e << YAML::Key << name << YAML::Value << YAML::BeginMap;
  writeFields(e, c, fields);
  e << YAML::EndMap;
}

void readHough(const YAML::Node& root, HoughConfig* h, const std::string& path) {
  readSection(
      root, "hough", h, [](auto& x, auto&& f) { houghFields(x, f); }, path);
}

void writeHough(YAML::Emitter& e, HoughConfig& h) {
  writeSection(e, "hough", h, [](auto& x, auto&& f) { houghFields(x, f); });
}

/// `samples` of the map `n`; `prefix` names it in errors.
void readSamples(const YAML::Node& n, const std::string& prefix, PerceptionConfig* c,
                 const std::string& path) {
  if (!n["samples"]) return;
  try {
    c->samples = n["samples"].as<int>();
  } catch (const YAML::Exception& e) {
    throw std::runtime_error(path + ": " + prefix + "samples: " + e.what());
  }
}

/// Refuses a top-level key that is neither a field nor a section; a `perception:` or `node:`
/// section is told where its settings belong.
void checkTopLevel(const YAML::Node& root, const std::string& path) {
  const std::vector<std::string>& fields = perceptionConfigFields();
  const std::vector<std::string>& sections = perceptionConfigSections();
  for (const auto& kv : root) {
    const std::string key = kv.first.as<std::string>();
    if (key == "perception")
      throw std::runtime_error(path +
                               ": the pipeline's own fields (model, samples, symmetries, ...) "
                               "stand at the top level of the file, not in a 'perception:' "
                               "section");
    if (key == "node")
      throw std::runtime_error(path +
                               ": 'node:' is not part of a perception config: the ROS node's "
                               "own settings are its parameters (config/perception_node.yaml)");
    if (std::find(fields.begin(), fields.end(), key) == fields.end() &&
        std::find(sections.begin(), sections.end(), key) == sections.end())
      throw std::runtime_error(path + ": unknown field '" + key + "'");
  }
}

/// The model path resolved, the model's card read, then what the file says of the card's
/// settings explicitly (normally nothing).
PerceptionConfig finishConfig(PerceptionConfig c, const YAML::Node& root, const std::string& path,
                              const std::string& base_dir, const std::string& model_path) {
  if (!model_path.empty()) c.model_path = model_path;
  if (!c.model_path.empty() && !base_dir.empty() &&
      std::filesystem::path(c.model_path).is_relative())
    c.model_path = (std::filesystem::path(base_dir) / c.model_path).string();
  c.model_card_path = applyModelCard(&c);
  readSamples(root, "", &c, path);
  readHough(root, &c.hough, path);
  return c;
}

PerceptionConfig perceptionFromYaml(const YAML::Node& root, const std::string& path,
                                    const std::string& base_dir, const std::string& model_path) {
  PerceptionConfig c;
  if (!root.IsMap()) throw std::runtime_error(path + ": expected a YAML map");
  checkTopLevel(root, path);
  readFields(
      root, "", &c, [](auto& x, auto&& f) { perceptionFields(x, f); }, path);
  readSection(
      root, "segments", &c.segments, [](auto& x, auto&& f) { segmentFields(x, f); }, path);
  readSection(
      root, "surface_instances", &c.surface_instances,
      [](auto& x, auto&& f) { surfaceInstanceFields(x, f); }, path);
  readSection(
      root, "crowded", &c.crowded, [](auto& x, auto&& f) { crowdedFields(x, f); }, path);
  readSection(
      root, "fitting", &c.fit, [](auto& x, auto&& f) { fitFields(x, f); }, path);
  readSection(
      root, "table", &c.table, [](auto& x, auto&& f) { tableFields(x, f); }, path);
  readSection(
      root, "workspace", &c.workspace, [](auto& x, auto&& f) { workspaceFields(x, f); }, path);
  readSection(
      root, "grid", &c.grid, [](auto& x, auto&& f) { gridFields(x, f); }, path);
  c.source = path;
  return finishConfig(c, root, path, base_dir, model_path);
}

}  // namespace

void GridConfig::validate() const {
  if (!(side_m == 0.0 || (side_m >= 0.01 && side_m <= 10.0)))
    throw std::invalid_argument("grid.side_m must be 0 (the model's) or lie in [0.01, 10] m" +
                                gotValue(side_m));
  if (!(object_voxels >= 0.0 && object_voxels <= 1000.0))
    throw std::invalid_argument("grid.object_voxels must lie in [0, 1000] (0 = off)" +
                                gotValue(object_voxels));
  if (!(smallest_object_voxels >= 0.0 && smallest_object_voxels <= 1000.0))
    throw std::invalid_argument(
        "grid.smallest_object_voxels must lie in [0, 1000] (0 = only the median)" +
        gotValue(smallest_object_voxels));
  if (!(fine_side_share >= 0.25 && fine_side_share < 1.0))
    throw std::invalid_argument("grid.fine_side_share must lie in [0.25, 1)" +
                                gotValue(fine_side_share));
}

RefineOptions refineOptions(const PerceptionConfig& c) {
  return {c.refine_iterations, c.refine_learning_rate, c.symmetries,      c.refine_prior_weight,
          c.refine_starts,     c.refine_evidence,      c.refine_on_passes};
}

namespace {

void checkRanges(const PerceptionConfig& config, bool latent) {
  if (config.samples < 1 || config.samples > kMaxSamples)
    throw std::invalid_argument("samples must lie in [1, " + std::to_string(kMaxSamples) +
                                "], not " + std::to_string(config.samples));
  if (!(config.min_pile_height_m >= 0.0 && config.min_pile_height_m <= 1.0))
    throw std::invalid_argument("min_pile_height_m must lie in [0, 1] m, not " +
                                std::to_string(config.min_pile_height_m));
  if (!(config.min_depth_m > 0.0 && config.min_depth_m < config.max_depth_m &&
        config.max_depth_m <= 100.0))
    throw std::invalid_argument(
        "the sensor range min_depth_m .. max_depth_m must satisfy 0 < min "
        "< max <= 100 m, not " +
        std::to_string(config.min_depth_m) + " .. " + std::to_string(config.max_depth_m));
  const int most_decomposed = latent ? config.samples : kMaxSamples;
  if (config.decompose_samples < 0 || config.decompose_samples > most_decomposed)
    throw std::invalid_argument("decompose_samples must lie in [0, " +
                                std::to_string(most_decomposed) + (latent ? " (samples)" : "") +
                                "], not " + std::to_string(config.decompose_samples));
  // Each instance's points are sampled, fitted and published: a million would hold a frame for
  // minutes and could exhaust the memory.
  if (config.points_per_instance < 10 || config.points_per_instance > 100000)
    throw std::invalid_argument("points_per_instance must lie in [10, 100000], not " +
                                std::to_string(config.points_per_instance));
  if (config.min_instance_points < 0)
    throw std::invalid_argument("min_instance_points must be >= 0, not " +
                                std::to_string(config.min_instance_points));
  if (config.threads < 1) throw std::invalid_argument("threads must be >= 1");
  validateSymmetries(config.symmetries);
  validateRefineOptions(refineOptions(config));
  if (config.condition_views != "all" && config.condition_views != "first")
    throw std::invalid_argument("condition_views must be 'all' or 'first', not '" +
                                config.condition_views + "'");
  config.fit.validate();
  config.workspace.validate();
  config.segments.validate();
  config.surface_instances.validate();
  config.crowded.validate();
  config.hough.validate();
  config.table.validate();
  config.grid.validate();
}

}  // namespace

void validatePerceptionConfig(const PerceptionConfig& config, bool latent) {
  try {
    checkRanges(config, latent);
  } catch (const std::invalid_argument& e) {
    if (config.source.empty()) throw;
    throw std::invalid_argument(config.source +
                                (config.model_card_path.empty()
                                     ? std::string()
                                     : " (with the model card " + config.model_card_path + ")") +
                                ": " + e.what());
  }
}

const std::vector<std::string>& perceptionConfigSections() {
  static const std::vector<std::string> sections{
      "hough", "segments", "surface_instances", "crowded", "fitting", "table", "workspace", "grid"};
  return sections;
}

const std::vector<std::string>& perceptionConfigFields() {
  static const std::vector<std::string> fields = [] {
    std::vector<std::string> out;
    PerceptionConfig c;
    perceptionFields(c, [&](const char* key, auto&) { out.emplace_back(key); });
    return out;
  }();
  return fields;
}

std::string applyModelCard(PerceptionConfig* config) {
  const std::string path = modelCardPath(config->model_path);
  if (config->model_path.empty() || !std::filesystem::exists(path)) return "";
  const YAML::Node root = loadModelCard(path);
  const YAML::Node section = root["perception"];
  if (!section) return "";
  if (!section.IsMap()) throw std::runtime_error(path + ": 'perception' must be a map");
  for (const auto& kv : section) {
    const std::string key = kv.first.as<std::string>();
    if (key != "samples" && key != "hough")
      throw std::runtime_error(path + ": unknown field perception." + key +
                               " (a model card's perception section holds samples and hough)");
  }
  readSamples(section, "perception.", config, path);
  readHough(section, &config->hough, path);
  return path;
}

PerceptionConfig loadPerceptionYaml(const std::string& path, const std::string& base_dir,
                                    const std::string& model_path) {
  return perceptionFromYaml(loadYamlFile(path, "perception config"), path, base_dir, model_path);
}

PerceptionConfig parsePerceptionYaml(const std::string& text, const std::string& source,
                                     const std::string& base_dir, const std::string& model_path) {
  const YAML::Node root = parseYamlText(text, "perception config", source);
  return perceptionFromYaml(root, source, base_dir, model_path);
}

PerceptionConfig overlayPerceptionYaml(const std::string& defaults_path,
                                       const std::string& overrides, const std::string& source,
                                       const std::string& base_dir) {
  YAML::Node merged = YAML::Clone(loadYamlFile(defaults_path, "perception config"));
  if (!merged.IsMap()) throw std::runtime_error(defaults_path + ": expected a YAML map");
  const YAML::Node over = parseYamlText(overrides, "perception config", source);
  if (over.IsNull()) return perceptionFromYaml(merged, defaults_path, base_dir, "");
  if (!over.IsMap()) throw std::runtime_error(source + ": expected a YAML map");
  checkTopLevel(over, source);
  for (const auto& kv : over) {
    const std::string key = kv.first.as<std::string>();
    if (kv.second.IsMap() && merged[key] && merged[key].IsMap()) {
      YAML::Node section = merged[key];
      for (const auto& field : kv.second) section[field.first.as<std::string>()] = field.second;
    } else {
      merged[key] = kv.second;
    }
  }
  return perceptionFromYaml(merged, source + " over " + defaults_path, base_dir, "");
}

std::string modelCardPerceptionYaml(int samples, const HoughConfig& hough) {
  HoughConfig h = hough;
  YAML::Emitter e;
  e.SetDoublePrecision(10);
  e << YAML::BeginMap << YAML::Key << "perception" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "samples" << YAML::Value << samples;
  writeHough(e, h);
  e << YAML::EndMap << YAML::EndMap;
  return e.c_str();
}

std::string perceptionYaml(const PerceptionConfig& config) {
  PerceptionConfig c = config;
  YAML::Emitter e;
  e.SetDoublePrecision(10);  // 0.05, not 0.050000000000000003
  e << YAML::BeginMap;
  writeFields(e, c, [](auto& x, auto&& f) { perceptionFields(x, f); });
  writeHough(e, c.hough);
  writeSection(e, "segments", c.segments, [](auto& x, auto&& f) { segmentFields(x, f); });
  writeSection(e, "surface_instances", c.surface_instances,
               [](auto& x, auto&& f) { surfaceInstanceFields(x, f); });
  writeSection(e, "crowded", c.crowded, [](auto& x, auto&& f) { crowdedFields(x, f); });
  writeSection(e, "fitting", c.fit, [](auto& x, auto&& f) { fitFields(x, f); });
  writeSection(e, "table", c.table, [](auto& x, auto&& f) { tableFields(x, f); });
  writeSection(e, "workspace", c.workspace, [](auto& x, auto&& f) { workspaceFields(x, f); });
  writeSection(e, "grid", c.grid, [](auto& x, auto&& f) { gridFields(x, f); });
  e << YAML::EndMap;
  return e.c_str();
}

}  // namespace simstack
