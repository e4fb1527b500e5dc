#pragma once
/// @file grasp_server.h
/// The ROS face of the grasping module: service ~rank_grasps (simstack/RankGrasps), and the
/// same as action ~rank_grasps_action (simstack/RankGraspsAction, with feedback and cancel), rank
/// suction grasps on one object of a scene (the request's, or the latest ObjectArray on
/// ~objects_topic) and publishes them on ~grasps (MarkerArray, latched), its state on
/// /diagnostics. Parameters: ros_params.h, config/grasps.yaml. Every bad request is answered
/// with success = false and a message; the server keeps serving.

#include <actionlib/server/action_server.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <ros/spinner.h>
#include <simstack/ObjectArray.h>
#include <simstack/RankGrasps.h>
#include <simstack/RankGraspsAction.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <atomic>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

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
  /// Called after each pull with the pulls done, their total and the best finished grasp so
  /// far (nullptr before one); false stops the ranking.
  using GraspFeedback = std::function<bool(int done, int total, const Grasp* best)>;
  /// One ranking at a time, for the service and the action alike; a goal `cancelled` while it
  /// waited for the ranking before it is not started.
  void serve(const RankGrasps::Request& req, RankGrasps::Response& res,
             const GraspFeedback& feedback, const std::atomic<bool>* cancelled = nullptr);
  using GoalHandle = actionlib::ActionServer<RankGraspsAction>::GoalHandle;
  /// The action's goal: accepted, then ranked on a thread of its own (one ranking at a time,
  /// with the service's), with feedback; a cancel stops the pulls.
  /// Takes the last ranking's arrows off ~grasps (a refused request has none).
  void clearMarkers();
  void onGoal(GoalHandle goal);
  void onCancel(GoalHandle goal);
  void runGoal(GoalHandle goal, const std::atomic<bool>& cancelled);
  /// A request made ready for the ranking.
  struct PreparedRequest {
    PreparedGrasps grasps;         ///< the ranking's input (scenes, config, cameras, pre-grasp)
    int target = -1;               ///< index in the scene's objects
    std_msgs::Header pose_header;  ///< frame of the tool and pre-grasp poses
    Transform T_pose_table = Transform::Identity();   ///< the table frame in pose_header's
    Transform T_scene_table = Transform::Identity();  ///< and in the scene's
    Points3 measured_target;            ///< depth points measured on the target, table frame
    std::optional<Vec3> measured_from;  ///< the camera that measured them, table frame
  };
  void onObjects(const ObjectArray::ConstPtr& msg);
  /// Counts an answer (service or action) for /diagnostics.
  void record(const RankGrasps::Response& res);
  /// The server's state: the latest scene and its age, the answers by status, the last one.
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);
  /// The request checked and turned into scenes; false with res.message set when it is bad.
  bool prepare(const RankGrasps::Request& req, RankGrasps::Response& res, PreparedRequest* out);
  /// The request's target (by id or point), pre-grasp distance and pose frame; false with
  /// res.message set when one is bad.
  bool placeRequest(const RankGrasps::Request& req, const ObjectArray& scene,
                    RankGrasps::Response& res, PreparedRequest* out);
  /// T_target_source at `stamp` from tf (waiting up to half a second of wall time); false with
  /// the reason when there is none.
  bool lookup(const std::string& target, const std::string& source, const ros::Time& stamp,
              Transform* T_target_source, std::string* why);
  /// The index of the object whose superquadric surface is nearest `point`; false with the
  /// reason and its RankGrasps status when the point cannot be placed or lies far from every
  /// object.
  bool nearestToPoint(const geometry_msgs::PointStamped& point, const ObjectArray& scene,
                      int* target, uint8_t* status, std::string* why);

  ros::NodeHandle nh_, pnh_;
  GraspServerConfig config_;
  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  ros::CallbackQueue scene_queue_;   ///< objects_topic only, served by scene_spinner_
  ros::CallbackQueue action_queue_;  ///< the action's goals and cancels, by action_spinner_
  ros::Subscriber objects_sub_;
  ros::Publisher markers_pub_;
  std::string markers_frame_;  ///< of the arrows ~grasps shows; empty: none
  ros::ServiceServer rank_srv_;
  std::unique_ptr<actionlib::ActionServer<RankGraspsAction>> action_;
  std::mutex goals_mutex_;                                               ///< guards the two below
  std::map<std::string, std::shared_ptr<std::atomic<bool>>> cancelled_;  ///< by goal id
  struct GoalThread {
    std::thread thread;
    std::shared_ptr<std::atomic<bool>> finished;
  };
  std::vector<GoalThread> goal_threads_;  ///< joined once finished, or when the server goes
  std::mutex latest_mutex_;
  ObjectArray::ConstPtr latest_;  ///< the newest scene on objects_topic
  std::mutex rank_mutex_;         ///< one ranking at a time (each uses the configured threads)
  struct Answers {
    long scenes = 0;  ///< received on objects_topic
    std::map<uint8_t, long> by_status;
    long total = 0;
    uint8_t last_status = 0;
    std::string last_message;
    double last_time_s = 0.0;
  };
  std::mutex answers_mutex_;  ///< guards answers_
  Answers answers_;
  diagnostic_updater::Updater diagnostics_;
  ros::SteadyTimer diagnostics_timer_;  ///< on scene_queue_: a ranking does not hold it up
  std::unique_ptr<ros::AsyncSpinner> scene_spinner_, action_spinner_;
};

}  // namespace simstack
