#pragma once
/// @file ros_params.h
/// Every parameter of the perception node, read in one place. The pipeline's settings come
/// from the same file as the tools' (config/perception.yaml, loaded into the node's private
/// namespace by the launch file) and are parsed by the core's loader, so a field has one name,
/// one default and one check; the node's own settings are its `node:` section.

#include <ros/node_handle.h>

#include <string>

#include "simstack/grasping/grasp_ranking.h"
#include "simstack/pipeline/object_tracker.h"
#include "simstack/pipeline/perception_config.h"

namespace simstack {

/// The node's own settings (`node:` in config/perception.yaml).
struct NodeConfig {
  std::string table_frame = "table";  ///< tf frame of the table (z up, plane z = 0); output frame
  bool estimate_table = false;        ///< RANSAC plane per frame instead of tf, broadcast on tf
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
  TrackerConfig tracking;  ///< node/track_max_centre_distance_m, node/track_max_size_ratio
  /// Broadcast each object's superquadric pose on tf as <object_frame_prefix>object_<id>, a
  /// child of table_frame at the frame's stamp.
  bool publish_object_tf = true;
  std::string object_frame_prefix = "simstack_";
  /// Throws std::invalid_argument naming the field.
  void validate() const;
};

/// The pipeline's settings from the parameters under `pnh` (sections perception, segments,
/// fitting, table; a relative model path is taken from `package_dir`); with none of them set,
/// `package_dir`/config/perception.yaml. Throws
/// std::runtime_error naming the parameter when one is misspelt or of the wrong type.
PerceptionConfig perceptionConfigFromParams(const ros::NodeHandle& pnh,
                                            const std::string& package_dir);
/// The node's settings from `pnh`'s `node/` parameters (absent ones keep their defaults).
NodeConfig nodeConfigFromParams(const ros::NodeHandle& pnh);

/// The grasp server's settings (config/grasps.yaml, loaded into its private namespace).
struct GraspServerConfig {
  std::string objects_topic = "perception/objects";  ///< scene of requests without one
  int max_candidates = 64;                           ///< grasps simulated when a request asks for 0
  int max_candidates_limit = 256;                    ///< requests for more are clamped to this
  double max_pull_distance_m = 0.5;                  ///< longer pulls are rejected
  /// A request without a scene is refused when the latest scene's stamp is older than this
  /// (the camera or the perception stopped); 0: any age.
  double max_scene_age_s = 10.0;
  /// Pre-grasp stand-off of requests that ask for 0 (m).
  double pregrasp_distance_m = 0.05;
  GraspRankingConfig ranking;  ///< cup, seal, physics, threads
  /// Throws std::invalid_argument naming the parameter.
  void validate() const;
};
/// The grasp server's settings from `pnh` (absent ones keep their defaults); throws
/// std::runtime_error naming an unknown or mistyped parameter, std::invalid_argument for a bad
/// value.
GraspServerConfig graspServerConfigFromParams(const ros::NodeHandle& pnh);

}  // namespace simstack
