#pragma once
/// @file perception_server.h
/// The ROS face of ScenePerception, one class shared by the perception node and nodelet (as
/// octomap_server's OctomapServer is): it subscribes depth/image_rect + depth/camera_info,
/// finds the table (tf, or a RANSAC plane it then broadcasts), runs the pipeline on a worker
/// thread and publishes the objects, their instance cloud, markers, the occupancy and the label
/// image, in ~output_frame; services ~reset and ~save_octomap; live settings through
/// dynamic_reconfigure (config/LiveSettings.cfg on ~, config/HoughSettings.cfg on ~hough);
/// diagnostics. Parameters: ros_params.h. Frames reach the worker
/// through a one-slot mailbox: the newest frame wins, callbacks never block, and the frames
/// replaced before the worker took them are counted as dropped.

#include <diagnostic_updater/diagnostic_updater.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <simstack/HoughSettingsConfig.h>
#include <simstack/LiveSettingsConfig.h>
#include <simstack/SaveOctomap.h>
#include <std_srvs/Empty.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>

#include <condition_variable>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "simstack/pipeline/scene_perception.h"
#include "simstack/pipeline/view_history.h"
#include "simstack_ros/ros_params.h"
#include "simstack_ros/stamp_pairing.h"

namespace simstack {

class PerceptionServer {
 public:
  /// Reads the parameters (throws std::runtime_error naming a bad one), loads the model and
  /// checks it (checkModel). A model that cannot be loaded or fails a check is refused: the
  /// node reports ERROR in diagnostics, latches ~ready false and perceives nothing. Otherwise
  /// it warms the network up, advertises, subscribes and starts the worker.
  PerceptionServer(ros::NodeHandle nh, ros::NodeHandle pnh, const std::string& package_dir);
  /// Stops the worker (the frame it is on is finished first).
  ~PerceptionServer();
  PerceptionServer(const PerceptionServer&) = delete;
  PerceptionServer& operator=(const PerceptionServer&) = delete;

 private:
  struct Frame {
    sensor_msgs::ImageConstPtr image;
    sensor_msgs::CameraInfoConstPtr info;
  };
  /// One input stream watched alone, for silenceCause: what came since the last frame.
  struct InputWatch {
    ros::SteadyTime arrival;  ///< when a message last came
    ros::Time stamp;          ///< and its stamp
    long since_frame = 0;     ///< messages since the last frame
    void saw(const ros::Time& message_stamp) {
      arrival = ros::SteadyTime::now();
      stamp = message_stamp;
      ++since_frame;
    }
    bool recent(const ros::SteadyTime& now, double timeout_s) const {
      return since_frame > 0 && (now - arrival).toSec() < timeout_s;
    }
  };
  void onImage(const sensor_msgs::ImageConstPtr& image);
  void onInfo(const sensor_msgs::CameraInfoConstPtr& info);
  /// A message of either stream: watched, then offered to the pairing (`pair` adds it there);
  /// a pair it completes goes to onFrame.
  template <class Add>
  void onInput(InputWatch* watch, const ros::Time& stamp, Add pair);
  /// An image with the camera_info of its stamp: into the mailbox.
  void onFrame(const sensor_msgs::ImageConstPtr& image,
               const sensor_msgs::CameraInfoConstPtr& info);
  void work();
  void process(const Frame& frame);
  /// The frame as a DepthView with its table pose (std::nullopt pose with estimate_table);
  /// false, with the reason, when the frame must be skipped.
  bool toView(const Frame& frame, DepthView* view, std::string* why);
  /// T_target_source at `stamp` from tf, waited for as waitForTransform does; false, with the
  /// reason, when it did not come.
  bool lookup(const std::string& target, const std::string& source, const ros::Time& stamp,
              Transform* T_target_source, std::string* why);
  /// After a failed lookup: when tf holds target <- source only far ahead of `stamp` (a clock
  /// that ran ahead and was set back) for the third frame in a row, clears the tf buffer (static
  /// transforms stay) and says so.
  void checkClockJump(const std::string& target, const std::string& source, const ros::Time& stamp);
  /// Waits for target <- source at `stamp` for tf_timeout_s of the clock of the
  /// stamps (simulated time under /use_sim_time: a bag played slowly gets as long in its own
  /// time) and at least as long on the wall clock; a simulated clock that stands still that
  /// long (a paused bag, or none started) ends it, as does the node stopping. False, with the
  /// reason, when the transform did not come.
  bool waitForTransform(const std::string& target, const std::string& source,
                        const ros::Time& stamp, std::string* why);
  /// Stops the timers, subscribers, services and reconfigure servers (roscpp waits for a
  /// callback of theirs still running).
  void stopCallbacks();
  /// Whether the destructor has asked the worker to end (takes mutex_).
  bool stopRequested();
  /// The estimate (in the table frame) published in the output frame, `T_output_table`; false,
  /// and nothing published, when ~reset was called since the frame began (`resets`: the count
  /// of resets it began after).
  bool publish(const Frame& frame, const DepthView& view, const SceneEstimate& estimate, int views,
               const Transform& T_output_table, uint64_t resets);
  void skip(const Frame& frame, const std::string& why);
  /// One frame of a rendered box before the first subscription (ScenePerception::warmUp).
  void warmUp();
  /// Loads and checks the model; false (said on the log and ~ready) when it is refused.
  /// Throws std::runtime_error for settings the model cannot take (the node stops).
  bool loadModel(const PerceptionConfig& config);
  bool reset(std_srvs::Empty::Request&, std_srvs::Empty::Response&);
  bool saveOctomap(SaveOctomap::Request& req, SaveOctomap::Response& res);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);
  /// With estimate_table: notes another node's broadcast of table_frame on /tf or /tf_static,
  /// which warnAboutOtherTable() says (each 10 s, while it lasts) when the table is broadcast.
  void watchTableBroadcasts();
  void warnAboutOtherTable();
  /// Once a second (wall time): a warning when no frame has come for ~input_timeout_s.
  void onSilenceCheck();
  /// Seconds since the last frame came (since the start before any), mutex_ held.
  double secondsWithoutFrame(const ros::SteadyTime& now) const;
  /// The same, or 0 while frames come within input_timeout_s (mutex_ held).
  double silenceSeconds(const ros::SteadyTime& now) const;
  /// Why no frame comes, as far as the topics tell (mutex_ held).
  std::string silenceCause(const ros::SteadyTime& now) const;
  /// The dynamic_reconfigure servers of the live settings, showing the settings in effect.
  void startLiveSettings();
  /// Applies settings changed by dynamic_reconfigure (worker thread, between frames).
  void applySettings();
  /// A dynamic_reconfigure change (mutex_ held): `config` becomes requested_ when the pipeline
  /// would take it; else the refusal is logged and false returned.
  bool request(const PerceptionConfig& config);

  ros::NodeHandle nh_, pnh_;
  NodeConfig node_;
  std::unique_ptr<ScenePerception> perception_;
  tf2_ros::Buffer tf_buffer_;
  tf2_ros::TransformListener tf_listener_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;
  image_transport::ImageTransport it_;
  image_transport::Subscriber image_sub_;  ///< depth/image_rect, through ~image_transport
  ros::Subscriber info_sub_;               ///< the camera_info beside it
  ros::Subscriber mask_sub_;               ///< ~mask: the workspace mask, applied to every frame
  ros::Subscriber tf_watch_, tf_static_watch_;  ///< with estimate_table: other table broadcasts
  std::mutex other_table_mutex_;                ///< guards the five below
  std::string other_table_;  ///< who else broadcasts table_frame, under what ("": none)
  bool other_table_static_ = false;
  ros::SteadyTime other_table_seen_, other_table_said_at_;
  std::string other_table_said_;
  std::mutex pairing_mutex_;  ///< taken before mutex_ where both are
  StampPairing<sensor_msgs::ImageConstPtr, sensor_msgs::CameraInfoConstPtr> pairing_{4};
  ros::Publisher objects_pub_, instances_pub_, markers_pub_, occupancy_pub_, ready_pub_;
  image_transport::Publisher labels_pub_;  ///< ~labels unlatched, through any transport
  ros::Publisher labels_latched_pub_;      ///< ~labels latched, raw
  ros::ServiceServer reset_srv_, save_srv_;
  diagnostic_updater::Updater diagnostics_;
  boost::recursive_mutex reconfigure_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<LiveSettingsConfig>> reconfigure_;         ///< on ~
  std::unique_ptr<dynamic_reconfigure::Server<HoughSettingsConfig>> hough_reconfigure_;  ///< ~hough
  /// Wall time: simulated time stops with a bag and jumps back when it loops.
  ros::SteadyTimer silence_timer_, diagnostics_timer_;

  std::mutex mutex_;  ///< guards the mailbox, the counters, the last scene and the views
  std::condition_variable wake_;
  std::optional<Frame> mailbox_;
  bool stop_ = false;
  long received_ = 0, dropped_ = 0, processed_ = 0, skipped_ = 0;
  long overtaken_ = 0;  ///< frames perceived when ~reset came: not published
  std::string last_error_, last_kind_;
  bool failing_ = false;  ///< the last frame was skipped
  ros::SteadyTime last_warning_;
  ros::SteadyTime started_, last_arrival_;  ///< when the node started; when the last frame came
  ros::SteadyTime last_silence_warning_;    ///< zero while frames arrive
  std::string last_silence_kind_;           ///< the cause of the last silence warning
  ros::SteadyTime last_change_warning_;     ///< the last warning said for a changed cause
  InputWatch image_watch_, info_watch_;     ///< each stream alone, under mutex_
  long processed_before_ = 0;
  ros::SteadyTime rate_since_;
  ObjectTracker tracker_;  ///< ids kept across frames (~track_*); under mutex_
  double warm_up_s_ = 0.0;
  int warm_up_objects_ = 0;
  int decompose_samples_ = 1;  ///< as configured at start (samples may change live)
  /// Why the model was refused ("" when it was loaded): nothing is perceived then.
  std::string model_error_;
  int tf_ahead_frames_ = 0;  ///< frames in a row whose tf was only far ahead (worker thread)
  /// The pairs of camera_info and image frames warned about as differing (worker thread).
  std::set<std::string> other_info_frames_;
  std::mutex save_mutex_;
  /// Held by the worker from a frame's id check to its last message and by ~reset, taken before
  /// mutex_: once ~reset returns, no frame begun before it is published.
  std::mutex publish_mutex_;
  StageTimings last_timings_;
  std::shared_ptr<const SceneEstimate> last_scene_;
  ros::Time last_scene_stamp_;  ///< its depth image's stamp
  ViewHistory views_;           ///< accumulated views (accumulate_views)
  Image<uint8_t> mask_;         ///< the last ~mask received (empty: none)
  bool reset_requested_ = false;
  uint64_t resets_ = 0;  ///< ~reset calls so far: a frame begun before the last is not published
  /// The settings in effect from the next frame on, as judged when requested (under mutex_);
  /// settings_changed_ until the worker has applied them.
  PerceptionConfig requested_;
  double requested_occupancy_min_ = 0.0;
  bool settings_changed_ = false;
  std::thread worker_;  ///< last: starts after everything it uses
};

/// What a perception nodelet that could not start (a refused setting) leaves in its namespace:
/// ~ready latched false and an ERROR on /diagnostics once a second saying why, so that a launch
/// file or task code waiting for it learns at once; the manager keeps running.
class RefusedPerception {
 public:
  RefusedPerception(const ros::NodeHandle& nh, const ros::NodeHandle& pnh, const std::string& why);

 private:
  ros::Publisher ready_pub_;
  diagnostic_updater::Updater diagnostics_;
  ros::SteadyTimer timer_;
};

}  // namespace simstack
