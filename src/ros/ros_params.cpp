#include "simstack_ros/ros_params.h"

#include <ros/console.h>
#include <ros/param.h>
#include <xmlrpcpp/XmlRpcValue.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <set>
#include <stdexcept>

#include "simstack_ros/conversions.h"

namespace simstack {
namespace {

/// XmlRpc (what rosparam loaded from the YAML file) as YAML again, for the core's loaders.
YAML::Node yamlOf(XmlRpc::XmlRpcValue& v) {
  switch (v.getType()) {
    case XmlRpc::XmlRpcValue::TypeStruct: {
      YAML::Node map(YAML::NodeType::Map);
      for (auto& kv : v) map[kv.first] = yamlOf(kv.second);
      return map;
    }
    case XmlRpc::XmlRpcValue::TypeArray: {
      YAML::Node list(YAML::NodeType::Sequence);
      for (int i = 0; i < v.size(); ++i) list.push_back(yamlOf(v[i]));
      return list;
    }
    case XmlRpc::XmlRpcValue::TypeBoolean:
      return YAML::Node(static_cast<bool>(v));
    case XmlRpc::XmlRpcValue::TypeInt:
      return YAML::Node(static_cast<int>(v));
    case XmlRpc::XmlRpcValue::TypeDouble:
      return YAML::Node(static_cast<double>(v));
    case XmlRpc::XmlRpcValue::TypeString:
      return YAML::Node(static_cast<std::string>(v));
    default:
      throw std::runtime_error("parameter of an unsupported type");
  }
}

/// The parameters of `all` that `keep` accepts, as the text of one YAML map ("" for none).
template <class Keep>
std::string yamlText(XmlRpc::XmlRpcValue& all, Keep keep) {
  YAML::Node map(YAML::NodeType::Map);
  if (all.getType() == XmlRpc::XmlRpcValue::TypeStruct)
    for (auto& kv : all)
      if (keep(kv.first)) map[kv.first] = yamlOf(kv.second);
  return map.size() == 0 ? std::string() : YAML::Dump(map);
}

template <class T>
void read(const ros::NodeHandle& pnh, const std::string& name, T* value) {
  if (pnh.hasParam(name) && !pnh.getParam(name, *value))
    throw std::runtime_error(pnh.resolveName(name) + " has the wrong type");
}

/// Every parameter of the node's own (config/perception_node.yaml) once, with its field: reading
/// and the check for unknown names walk the same list.
template <class C, class F>
void nodeFields(C& c, F&& f) {
  f("table_frame", c.table_frame);
  f("output_frame", c.output_frame);
  f("estimate_table", c.estimate_table);
  f("tf_timeout_s", c.tf_timeout_s);
  f("input_timeout_s", c.input_timeout_s);
  f("image_transport", c.image_transport);
  f("occupancy_min", c.occupancy_min);
  f("accumulate_views", c.accumulate_views);
  f("max_views", c.max_views);
  f("output_dir", c.output_dir);
  f("latch", c.latch);
  f("publish_object_tf", c.publish_object_tf);
  f("object_frame_prefix", c.object_frame_prefix);
  f("track_max_centre_distance_m", c.tracking.max_centre_distance_m);
  f("track_max_size_ratio", c.tracking.max_size_ratio);
  f("track_min_overlap_share", c.tracking.min_overlap_share);
  f("track_max_missed_frames", c.tracking.max_missed_frames);
}

const std::set<std::string>& nodeParameters() {
  static const std::set<std::string> names = [] {
    std::set<std::string> out;
    NodeConfig c;
    nodeFields(c, [&](const char* name, auto&) { out.insert(name); });
    return out;
  }();
  return names;
}

bool isPipelineParameter(const std::string& name) {
  const std::vector<std::string>& f = perceptionConfigFields();
  const std::vector<std::string>& s = perceptionConfigSections();
  return std::find(f.begin(), f.end(), name) != f.end() ||
         std::find(s.begin(), s.end(), name) != s.end();
}

/// Every parameter in the node's private namespace must be one it reads, so that a misspelt
/// one stops the node rather than being ignored. Besides the pipeline's and the node's own:
/// diagnostic_updater's ~diagnostic_period, and the maps image_transport's publisher plugins
/// (compressed, theora) keep under the ~labels topic, which outlive the node.
void checkPrivateNamespace(const ros::NodeHandle& pnh, XmlRpc::XmlRpcValue& all) {
  for (auto& kv : all) {
    const std::string& name = kv.first;
    if (isPipelineParameter(name) || nodeParameters().count(name) || name == "diagnostic_period" ||
        (name == "labels" && kv.second.getType() == XmlRpc::XmlRpcValue::TypeStruct))
      continue;
    throw std::runtime_error(
        "unknown parameter " + pnh.resolveName(name) +
        " (the node reads the pipeline's settings of config/perception.yaml and its own of "
        "config/perception_node.yaml, each under its own name; docs/reference.md)");
  }
}

/// The node's private parameters (an empty map when there are none).
XmlRpc::XmlRpcValue privateParameters(const ros::NodeHandle& pnh) {
  XmlRpc::XmlRpcValue all;
  if (!ros::param::get(pnh.getNamespace(), all) || all.getType() != XmlRpc::XmlRpcValue::TypeStruct)
    return XmlRpc::XmlRpcValue();
  return all;
}

}  // namespace

void NodeConfig::validate() const {
  if (table_frame.empty()) throw std::invalid_argument("~table_frame is empty");
  if (!(tf_timeout_s >= 0.0 && tf_timeout_s <= 10.0))
    throw std::invalid_argument("~tf_timeout_s must lie in [0, 10] s");
  if (!(input_timeout_s >= 0.5 && input_timeout_s <= 3600.0))
    throw std::invalid_argument("~input_timeout_s must lie in [0.5, 3600] s");
  if (!(occupancy_min > 0.0 && occupancy_min <= 1.0))
    throw std::invalid_argument("~occupancy_min must lie in (0, 1]");
  if (max_views < 1 || max_views > 64)
    throw std::invalid_argument("~max_views must lie in [1, 64]");
  try {
    tracking.validate();
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("~track_") + e.what());  // the parameter's name
  }
}

PerceptionConfig perceptionConfigFromParams(const ros::NodeHandle& pnh,
                                            const std::string& package_dir) {
  // The package's config, with the pipeline's parameters found under ~ laid over it.
  XmlRpc::XmlRpcValue all = privateParameters(pnh);
  if (all.getType() == XmlRpc::XmlRpcValue::TypeStruct) checkPrivateNamespace(pnh, all);
  return overlayPerceptionYaml(package_dir + "/config/perception.yaml",
                               yamlText(all, isPipelineParameter),
                               "the parameters under " + pnh.getNamespace(), package_dir);
}

NodeConfig nodeConfigFromParams(const ros::NodeHandle& pnh) {
  XmlRpc::XmlRpcValue all = privateParameters(pnh);
  if (all.getType() == XmlRpc::XmlRpcValue::TypeStruct) checkPrivateNamespace(pnh, all);
  NodeConfig c;
  // A value of the wrong type (1 for true, "0.5" for 0.5) stops the node rather than being
  // replaced by the default unnoticed.
  nodeFields(c, [&](const char* name, auto& value) { read(pnh, name, &value); });
  c.table_frame = tf2Frame(c.table_frame);
  c.output_frame = tf2Frame(c.output_frame);
  c.validate();
  return c;
}

void GraspServerConfig::validate() const {
  if (objects_topic.empty()) throw std::invalid_argument("objects_topic must not be empty");
  GraspSettings::validate();
}

GraspServerConfig graspServerConfigFromParams(const ros::NodeHandle& pnh) {
  // The grasp settings (config/grasps.yaml's fields) go to the core's reader as YAML, as the
  // file would; objects_topic is the node's own, diagnostic_period diagnostic_updater's,
  // rank_grasps_action and actionlib_status_frequency actionlib's (its status list's timeout,
  // its status rate, which actionlib searches for up from the action's namespace).
  XmlRpc::XmlRpcValue all = privateParameters(pnh);
  const std::string yaml =
      yamlText(all, [](const std::string& name) { return kGraspServerKeys.count(name) == 0; });
  GraspServerConfig c;
  static_cast<GraspSettings&>(c) =
      parseGraspSettingsYaml(yaml, "the parameters under " + pnh.getNamespace());
  read(pnh, "objects_topic", &c.objects_topic);
  c.validate();
  return c;
}

double checkedDiagnosticPeriod(const ros::NodeHandle& pnh, double period) {
  const std::string name = pnh.resolveName("diagnostic_period");
  XmlRpc::XmlRpcValue value;
  if (pnh.getParam("diagnostic_period", value) &&
      value.getType() != XmlRpc::XmlRpcValue::TypeDouble &&
      value.getType() != XmlRpc::XmlRpcValue::TypeInt)
    throw std::runtime_error(name + " must be a number of seconds");
  if (!(period >= 0.01 && period <= 3600.0))
    throw std::runtime_error(name + " must lie in [0.01, 3600] s");
  return period;
}

}  // namespace simstack
