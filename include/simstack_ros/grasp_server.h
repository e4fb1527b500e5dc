#pragma once
/// @file grasp_server.h
/// The ROS face of the grasping module: service ~rank_grasps (simstack/RankGrasps) ranks
/// suction grasps on one object of a scene (the request's, or the latest ObjectArray on
/// ~objects_topic) and publishes them on ~grasps (MarkerArray, latched). Parameters:
/// ros_params.h, config/grasps.yaml. Every bad request is answered with success = false and a
/// message; the server keeps serving.

#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <ros/spinner.h>
#include <simstack/ObjectArray.h>
#include <simstack/RankGrasps.h>

#include <memory>
#include <mutex>
#include <string>

#include "simstack_ros/ros_params.h"

namespace simstack {

class GraspServer {
 public:
  /// Reads the parameters (throws naming a bad one), subscribes and advertises.
  GraspServer(ros::NodeHandle nh, ros::NodeHandle pnh);
  ~GraspServer();

  /// The service's work, callable without ROS transport (tests): fills `res` and returns true
  /// for every request; res.success says whether grasps were ranked.
  bool rank(RankGrasps::Request& req, RankGrasps::Response& res);

 private:
  void onObjects(const ObjectArray::ConstPtr& msg);
  /// The request checked and turned into scenes; false with res.message set when it is bad.
  bool prepare(const RankGrasps::Request& req, RankGrasps::Response& res,
               std::vector<std::vector<SuperquadricShape>>* scenes, int* target,
               GraspRankingConfig* config, std::vector<Vec3>* cameras);

  ros::NodeHandle nh_, pnh_;
  GraspServerConfig config_;
  ros::CallbackQueue scene_queue_;  ///< objects_topic only, served by scene_spinner_
  ros::Subscriber objects_sub_;
  ros::Publisher markers_pub_;
  ros::ServiceServer rank_srv_;
  std::mutex latest_mutex_;
  ObjectArray::ConstPtr latest_;  ///< the newest scene on objects_topic
  std::mutex rank_mutex_;         ///< one ranking at a time (each uses the configured threads)
  std::unique_ptr<ros::AsyncSpinner> scene_spinner_;
};

}  // namespace simstack
