#pragma once
/// @file ros_params.h
/// Every parameter of the perception node and of the grasp server, read in one place. Each setting
/// is one parameter in the node's private namespace: the pipeline's (config/perception.yaml:
/// ~model, ~symmetries, ~hough/bandwidth_m, ...) are parsed by the core's loader, laid over the
/// package's config/perception.yaml, so a field has one name, one default and one check; the node's
/// own (config/perception_node.yaml: ~table_frame, ~latch, ...) are read here.

#include <ros/node_handle.h>

#include <string>

#include "simstack/grasping/grasp_settings.h"
#include "simstack/pipeline/object_tracker.h"
#include "simstack/pipeline/perception_config.h"

namespace simstack {

/// The node's own settings (config/perception_node.yaml).
struct NodeConfig {
  std::string table_frame = "table";  ///< tf frame of the table (z up, plane z = 0)
  /// Frame of every output (objects, markers, clouds, object tf frames); "" = table_frame.
  std::string output_frame;
  bool estimate_table = false;   ///< RANSAC plane per frame instead of tf, broadcast on tf
  double tf_timeout_s = 0.2;     ///< wait for table_frame <- camera (stamp's clock and wall clock)
  double input_timeout_s = 5.0;  ///< no frame for this long (wall time): warn, diagnostics WARN
  std::string image_transport = "raw";
  double occupancy_min = 0.5;     ///< voxels at least this probably occupied go to ~occupancy
  bool accumulate_views = false;  ///< fuse every frame (pose from tf) until ~reset
  int max_views = 6;              ///< at most this many views fused (the newest kept)
  /// Where ~save_octomap writes; "" = $ROS_HOME/simstack ($ROS_HOME defaults to ~/.ros).
  std::string output_dir;
  /// Objects, markers, instances, occupancy and labels latched: a late subscriber gets the last.
  bool latch = true;
  TrackerConfig tracking;  ///< ~track_max_centre_distance_m, ~track_max_size_ratio,
                           ///< ~track_min_overlap_share, ~track_max_missed_frames
  /// Broadcast each object's superquadric pose on tf as <object_frame_prefix>object_<id>, a
  /// child of the output frame at the frame's stamp.
  bool publish_object_tf = true;
  std::string object_frame_prefix = "simstack_";
  /// The frame outputs are in: output_frame, or table_frame when it is empty.
  const std::string& outputFrame() const {
    return output_frame.empty() ? table_frame : output_frame;
  }
  /// Throws std::invalid_argument naming the field.
  void validate() const;
};

/// The pipeline's settings: `package_dir`/config/perception.yaml with the pipeline's parameters
/// under `pnh` laid over it (~model, ~symmetries, ~hough/..., ~segments/...; a relative model
/// path is taken from `package_dir`). Throws std::runtime_error naming the parameter when one
/// is unknown (misspelt) or of the wrong type.
PerceptionConfig perceptionConfigFromParams(const ros::NodeHandle& pnh,
                                            const std::string& package_dir);
/// The node's settings from `pnh`'s parameters (absent ones keep their defaults).
NodeConfig nodeConfigFromParams(const ros::NodeHandle& pnh);

/// The grasp server's settings: config/grasps.yaml's (core GraspSettings, loaded into its private
/// namespace) and the topic of the scenes it ranks on.
struct GraspServerConfig : GraspSettings {
  std::string objects_topic = "perception/objects";  ///< scene of requests without one
  /// Throws std::invalid_argument naming the parameter.
  void validate() const;
};
/// The grasp server's settings from `pnh` (absent ones keep their defaults); throws
/// std::runtime_error naming an unknown parameter (or a mistyped ~objects_topic),
/// std::invalid_argument for a mistyped or bad grasp setting.
GraspServerConfig graspServerConfigFromParams(const ros::NodeHandle& pnh);

/// `period`, the diagnostics period diagnostic_updater read from `pnh`'s ~diagnostic_period,
/// checked: the parameter, when set, must be a number (diagnostic_updater itself would take its
/// 1 s default in silence) and the period lie in [0.01, 3600] s. Throws std::runtime_error
/// naming the parameter.
double checkedDiagnosticPeriod(const ros::NodeHandle& pnh, double period);

}  // namespace simstack
