#include "simstack_ros/perception_server.h"

#include <tf2_msgs/TFMessage.h>

#include <geometry_msgs/TransformStamped.h>
#include <image_transport/camera_common.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/PointCloud2.h>
#include <simstack/ObjectArray.h>
#include <std_msgs/Bool.h>
#include <tf2_eigen/tf2_eigen.h>
#include <visualization_msgs/MarkerArray.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iomanip>
#include <sstream>
#include <stdexcept>
#include <system_error>

#include "simstack/io/octomap_io.h"
#include "simstack/io/staged_output.h"
#include "simstack_ros/conversions.h"

namespace simstack {
namespace {

std::string expandHome(const std::string& path) {
  if (path.rfind("~/", 0) != 0 && path != "~") return path;
  const char* home = std::getenv("HOME");
  return std::string(home ? home : "") + path.substr(1);
}

/// ~output_dir, or $ROS_HOME/simstack when it is empty (ROS_HOME as roslaunch reads it:
/// ~/.ros when unset).
std::string outputDirectory(const std::string& configured) {
  if (!configured.empty()) return expandHome(configured);
  const char* ros_home = std::getenv("ROS_HOME");
  const std::string base = ros_home && *ros_home ? std::string(ros_home) : expandHome("~/.ros");
  return base + "/simstack";
}

/// Each live setting (config/LiveSettings.cfg, config/HoughSettings.cfg) beside the field it
/// sets: the one place they are paired. `f(live_field, field)` is called for each pair.
/// (`occupancy_min`, the node's own, is set apart.)
template <typename F>
void pairLiveSettings(LiveSettingsConfig& live, PerceptionConfig& c, F f) {
  f(live.samples, c.samples);
  f(live.symmetries, c.symmetries);
  f(live.min_instance_points, c.min_instance_points);
  f(live.joint_refinement, c.joint_refinement);
}
template <typename F>
void pairHoughSettings(HoughSettingsConfig& live, HoughConfig& h, F f) {
  f(live.refinement, h.refinement);
  f(live.min_traversals, h.min_traversals);
  f(live.bandwidth_m, h.bandwidth_m);
  f(live.min_instance_voxels, h.min_instance_voxels);
  f(live.min_vote_norm, h.min_vote_norm);
}
const auto kShow = [](auto& live, const auto& field) { live = field; };
const auto kApply = [](const auto& live, auto& field) { field = live; };

LiveSettingsConfig liveSettings(PerceptionConfig c, double occupancy_min) {
  LiveSettingsConfig live;
  pairLiveSettings(live, c, kShow);
  live.occupancy_min = occupancy_min;
  return live;
}

HoughSettingsConfig houghSettings(HoughConfig h) {
  HoughSettingsConfig live;
  pairHoughSettings(live, h, kShow);
  return live;
}

/// Why a file name given to ~save_octomap is refused ("" when it is fine).
std::string badFileName(const std::string& name) {
  if (name.empty()) return "no file name given";
  if (const std::string why = unwritablePath(name); !why.empty())
    return "'" + name.substr(0, 80) + (name.size() > 80 ? "...'" : "'") + ": " + why;
  if (name.find('/') != std::string::npos || name.find('\\') != std::string::npos)
    return "'" + name + "' is not a plain file name (no directories)";
  if (name == "." || name == ".." || name.find("..") != std::string::npos)
    return "'" + name + "' may not contain '..'";
  const std::string ext = std::filesystem::path(name).extension().string();
  if (name[0] == '.') return "'" + name + "' has no name before its extension";
  if (ext != ".ot" && ext != ".bt") return "'" + name + "' must end in .ot or .bt";
  return "";
}

}  // namespace

PerceptionServer::PerceptionServer(ros::NodeHandle nh, ros::NodeHandle pnh,
                                   const std::string& package_dir)
    : nh_(nh),
      pnh_(pnh),
      node_(nodeConfigFromParams(pnh)),
      tf_listener_(tf_buffer_),
      it_(nh),
      // Named after the nodelet, not the manager it is loaded into (two perception nodelets in
      // one manager must not report under one name); ~diagnostic_period is read from pnh.
      diagnostics_(nh, pnh, pnh.getNamespace()),
      rate_since_(ros::SteadyTime::now()),
      tracker_(node_.tracking) {
  // Read by diagnostic_updater (default 1 s, once, at start); checked before anything is
  // advertised, so that a refused node offers no service that could call into it.
  const double period = checkedDiagnosticPeriod(pnh_, diagnostics_.getPeriod());
  const PerceptionConfig config = perceptionConfigFromParams(pnh, package_dir);
  // A setting out of range stops the node, as any refused parameter does; only the model's own
  // faults leave it up and refusing (below).
  validatePerceptionConfig(config);
  views_.setMaxViews(node_.accumulate_views ? node_.max_views : 1);
  ready_pub_ = pnh_.advertise<std_msgs::Bool>("ready", 1, true);
  diagnostics_.setHardwareID("simstack_perception " + pnh_.getNamespace());
  diagnostics_.add("perception", this, &PerceptionServer::diagnose);
  started_ = ros::SteadyTime::now();
  // Timers, services and the settings server are made after everything that may throw, so
  // that no callback reaches an object whose construction failed (a nodelet's callbacks run
  // while it is being constructed).
  const auto startDiagnostics = [this, period] {
    diagnostics_timer_ = nh_.createSteadyTimer(
        ros::WallDuration(period),
        [this](const ros::SteadyTimerEvent&) { diagnostics_.force_update(); });
  };
  if (!loadModel(config)) {
    startDiagnostics();
    return;
  }
  // Latched (~latch): a grasp client, task node or rviz that starts later still gets the
  // last scene, as from octomap_server.
  const bool latch = node_.latch;
  objects_pub_ = pnh_.advertise<ObjectArray>("objects", 1, latch);
  instances_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("instances", 1, latch);
  markers_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("markers", 1, latch);
  occupancy_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("occupancy", 1, latch);
  // image_transport publishes only to transports that have subscribers, so its latched copy
  // would stay an older frame's (or none): latched labels go out raw on a plain publisher.
  if (latch)
    labels_latched_pub_ = pnh_.advertise<sensor_msgs::Image>("labels", 1, true);
  else
    labels_pub_ = image_transport::ImageTransport(pnh_).advertise("labels", 1);
  decompose_samples_ = perception_->config().decompose_samples;
  warmUp();
  // The hints read ~image_transport (image_transport's convention, `_image_transport:=...`)
  // from the node's own namespace: a nodelet's "~" would be its manager's.
  const image_transport::TransportHints hints(node_.image_transport, ros::TransportHints(), pnh_);
  // The image and its camera_info subscribed apart and paired here by exact stamp
  // (StampPairing: a half pair left stamped later than every frame to come, as a looped bag
  // leaves, must not hold back the frames after it).
  image_transport::Subscriber image_sub;
  try {
    image_sub = it_.subscribe("depth/image_rect", 2, &PerceptionServer::onImage, this, hints);
  } catch (const image_transport::TransportLoadException& e) {
    throw std::runtime_error("~image_transport '" + hints.getTransport() +
                             "' cannot be loaded: " + e.what());
  }
  // Beside the image's base name (a compressed transport's subscriber names its own topic).
  ros::Subscriber info_sub =
      nh_.subscribe(image_transport::getCameraInfoTopic(nh_.resolveName("depth/image_rect")), 2,
                    &PerceptionServer::onInfo, this);
  {
    std::lock_guard<std::mutex> lock(mutex_);  // the diagnostics timer already reads them
    image_sub_ = image_sub;
    info_sub_ = info_sub;
  }
  reset_srv_ = pnh_.advertiseService("reset", &PerceptionServer::reset, this);
  save_srv_ = pnh_.advertiseService("save_octomap", &PerceptionServer::saveOctomap, this);
  startLiveSettings();
  if (node_.estimate_table) watchTableBroadcasts();
  // A latched publisher's mask arrives once; a bad one is reported and the previous one kept.
  const std::string mask_topic = pnh_.resolveName("mask");
  mask_sub_ = pnh_.subscribe<sensor_msgs::Image>(
      "mask", 1, [this, mask_topic](const sensor_msgs::ImageConstPtr& msg) {
        try {
          Image<uint8_t> mask = maskFromImage(*msg);
          ROS_INFO("simstack perception: workspace mask %dx%d received on %s", mask.width,
                   mask.height, mask_topic.c_str());
          std::lock_guard<std::mutex> lock(mutex_);
          mask_ = std::move(mask);
        } catch (const std::invalid_argument& e) {
          ROS_ERROR("simstack perception: mask on %s refused, the previous one stays: %s",
                    mask_topic.c_str(), e.what());
        }
      });
  ROS_INFO(
      "simstack perception: model %s (%d samples), table %s '%s', outputs in '%s', listening "
      "on %s",
      perception_->config().model_path.c_str(), perception_->config().samples,
      node_.estimate_table ? "estimated and broadcast as" : "from tf frame",
      node_.table_frame.c_str(), node_.outputFrame().c_str(), image_sub_.getTopic().c_str());
  // Ready once it listens: a launch file or bag player waiting for it loses no frame.
  std_msgs::Bool ready;
  ready.data = true;
  ready_pub_.publish(ready);
  // Both on the monotonic wall clock, so also while a bag is paused: the silence check once a
  // second, /diagnostics once a period.
  silence_timer_ = nh_.createSteadyTimer(
      ros::WallDuration(1.0), [this](const ros::SteadyTimerEvent&) { onSilenceCheck(); });
  startDiagnostics();
  // Last: from here the worker owns the pipeline (settings change between its frames), and
  // onFrame only fills the mailbox.
  try {
    worker_ = std::thread(&PerceptionServer::work, this);
  } catch (const std::system_error& e) {
    // No destructor runs for an object whose constructor throws: the callbacks made above
    // are stopped here, before the members they use go away.
    stopCallbacks();
    throw std::runtime_error(std::string("the worker thread cannot be started: ") + e.what());
  }
}

bool PerceptionServer::loadModel(const PerceptionConfig& config) {
  // A model that cannot be loaded, or that fails its card's checks (SHA-256, format, finite
  // weights, the self-test): the node stays up, says so in diagnostics (ERROR) and on ~ready
  // (false), and perceives nothing, rather than publish scenes a broken network made.
  const auto refuse = [this](const char* why) {
    perception_.reset();
    model_error_ = why;
    ROS_ERROR("simstack perception: model refused, nothing will be perceived: %s", why);
    std_msgs::Bool ready;
    ready.data = false;
    ready_pub_.publish(ready);
    return false;
  };
  try {
    perception_ = std::make_unique<ScenePerception>(config);
  } catch (const std::invalid_argument& e) {
    // A setting the model cannot take (hypotheses to decompose from a model without a latent
    // code): the settings are wrong, not the model, and the node stops.
    throw std::runtime_error(config.model_path + ": " + e.what());
  } catch (const std::exception& e) {  // a runtime_error, or a library's (libtorch, yaml-cpp)
    return refuse(e.what());
  }
  try {
    checkModel(config.model_path);
  } catch (const std::exception& e) {
    return refuse(e.what());
  }
  return true;
}

PerceptionServer::~PerceptionServer() {
  // The worker first: it uses the subscriber and the reconfigure server while it finishes a
  // frame. Callbacks arriving meanwhile only touch the mailbox and settings under the lock.
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  if (worker_.joinable()) worker_.join();
  stopCallbacks();
}

void PerceptionServer::stopCallbacks() {
  // Nothing may call back into this object once its state starts going away (the timer reads
  // the subscriber's topic).
  silence_timer_.stop();
  diagnostics_timer_.stop();
  image_sub_.shutdown();
  info_sub_.shutdown();
  mask_sub_.shutdown();
  tf_watch_.shutdown();
  tf_static_watch_.shutdown();
  reset_srv_.shutdown();
  save_srv_.shutdown();
  hough_reconfigure_.reset();
  reconfigure_.reset();
}

template <class Add>
void PerceptionServer::onInput(InputWatch* watch, const ros::Time& stamp, Add pair) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    watch->saw(stamp);
  }
  std::optional<std::pair<sensor_msgs::ImageConstPtr, sensor_msgs::CameraInfoConstPtr>> frame;
  {
    std::lock_guard<std::mutex> lock(pairing_mutex_);
    frame = pair();
  }
  if (frame) onFrame(frame->first, frame->second);
}

void PerceptionServer::onImage(const sensor_msgs::ImageConstPtr& image) {
  onInput(&image_watch_, image->header.stamp,
          [&] { return pairing_.addFirst(image->header.stamp.toNSec(), image); });
}

void PerceptionServer::onInfo(const sensor_msgs::CameraInfoConstPtr& info) {
  onInput(&info_watch_, info->header.stamp,
          [&] { return pairing_.addSecond(info->header.stamp.toNSec(), info); });
}

void PerceptionServer::onFrame(const sensor_msgs::ImageConstPtr& image,
                               const sensor_msgs::CameraInfoConstPtr& info) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++received_;
    last_arrival_ = ros::SteadyTime::now();
    info_watch_.since_frame = image_watch_.since_frame = 0;
    if (mailbox_) ++dropped_;
    mailbox_ = Frame{image, info};
  }
  wake_.notify_one();
}

void PerceptionServer::work() {
  for (;;) {
    Frame frame;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [&] { return stop_ || mailbox_.has_value(); });
      if (stop_) return;
      frame = std::move(*mailbox_);
      mailbox_.reset();
    }
    try {
      process(frame);
    } catch (const std::exception& e) {  // nothing may escape the worker
      skip(frame, e.what());
    }
  }
}

void PerceptionServer::skip(const Frame& frame, const std::string& why) {
  bool warn = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++skipped_;
    // One warning per kind of problem (the reason up to its first ':', without the details
    // that change from frame to frame), then at most one every 5 s while it lasts.
    const std::string kind = why.substr(0, why.find(':'));
    const ros::SteadyTime now = ros::SteadyTime::now();
    warn = kind != last_kind_ || (now - last_warning_).toSec() > 5.0;
    if (warn) last_warning_ = now;
    last_kind_ = kind;
    last_error_ = why;
    failing_ = true;
  }
  if (warn)  // by stamp: header.seq is the publisher's count, which the node's counts are not
    ROS_WARN("simstack perception: the frame stamped %u.%09u on %s skipped: %s",
             frame.image->header.stamp.sec, frame.image->header.stamp.nsec,
             image_sub_.getTopic().c_str(), why.c_str());
}

bool PerceptionServer::toView(const Frame& frame, DepthView* view, std::string* why) {
  const sensor_msgs::CameraInfo& info = *frame.info;
  const sensor_msgs::RegionOfInterest& roi = info.roi;
  const bool reduced = roi.x_offset != 0 || roi.y_offset != 0 || roi.width != 0 ||
                       roi.height != 0 || info.binning_x > 1 || info.binning_y > 1;
  const auto other_size = [&](int width, int height) {
    *why = "the depth image is " + std::to_string(view->depth.width) + "x" +
           std::to_string(view->depth.height) + " but its camera_info " + std::to_string(width) +
           "x" + std::to_string(height) +
           (reduced ? " (" + std::to_string(info.width) + "x" + std::to_string(info.height) +
                          " with its ROI and binning " + std::to_string(info.binning_x) + "x" +
                          std::to_string(info.binning_y) + ")"
                    : std::string());
    return false;
  };
  try {
    view->depth = depthFromImage(*frame.image);
    // A whole image of another size: named as such, before its intrinsics are judged.
    if (!reduced &&
        (uint32_t(view->depth.width) != info.width || uint32_t(view->depth.height) != info.height))
      return other_size(int(info.width), int(info.height));
    view->camera = cameraFromInfo(info);
  } catch (const std::invalid_argument& e) {
    *why = e.what();
    return false;
  }
  if (view->depth.width != view->camera.width || view->depth.height != view->camera.height)
    return other_size(view->camera.width, view->camera.height);
  size_t valid = 0;
  for (float d : view->depth.pixels) valid += validDepth(d);
  if (valid == 0) {
    *why = "the depth image holds no valid depth (all zero, negative or NaN)";
    return false;
  }
  const std::string camera_frame = tf2Frame(frame.image->header.frame_id);
  if (camera_frame.empty()) {
    *why = "the depth image's header has no frame_id (the camera's optical frame)";
    return false;
  }
  // Stamp 0 is no time: tf would place the camera where it is now, and the scene published
  // under it would never be stale to the grasp service.
  if (frame.image->header.stamp.isZero()) {
    *why = "the depth image's header stamp is 0 (no capture time): stamp the images";
    return false;
  }
  // Another camera's intrinsics of the same size (a colour camera_info remapped in its place)
  // would place every point wrongly: said once for each pair of frames, the image's kept.
  const std::string info_frame = tf2Frame(info.header.frame_id);
  if (!info_frame.empty() && info_frame != camera_frame &&
      other_info_frames_.insert(info_frame + " " + camera_frame).second) {
    ROS_WARN(
        "simstack perception: the depth image is in frame '%s' but its camera_info in '%s': "
        "are they one camera's? The image's frame and the camera_info's intrinsics are used",
        camera_frame.c_str(), info_frame.c_str());
  }
  if (node_.estimate_table) return true;  // the pipeline fits the plane
  view->T_table_camera = Transform::Identity();
  return lookup(node_.table_frame, camera_frame, frame.image->header.stamp, &*view->T_table_camera,
                why);
}

bool PerceptionServer::lookup(const std::string& target, const std::string& source,
                              const ros::Time& stamp, Transform* T_target_source,
                              std::string* why) {
  bool found = waitForTransform(target, source, stamp, why);
  if (found) {
    try {
      *T_target_source = rigidFromTf(tf_buffer_.lookupTransform(target, source, stamp));
    } catch (const tf2::TransformException& e) {
      *why = "no transform " + target + " <- '" + source + "': " + e.what();
      found = false;
    }
  }
  if (found)
    tf_ahead_frames_ = 0;
  else
    checkClockJump(target, source, stamp);
  return found;
}

void PerceptionServer::checkClockJump(const std::string& target, const std::string& source,
                                      const ros::Time& stamp) {
  // tf drops a transform older than its newest by more than its cache (10 s): after a clock
  // that ran ahead is set right, it keeps only the poses from ahead and refuses the new ones.
  constexpr double kAheadS = 10.0;
  ros::Time latest;
  try {
    latest = tf_buffer_.lookupTransform(target, source, ros::Time(0)).header.stamp;
  } catch (const tf2::TransformException&) {
    tf_ahead_frames_ = 0;  // no transform at all: not a clock's doing
    return;
  }
  if (latest.isZero() || (latest - stamp).toSec() <= kAheadS) {
    tf_ahead_frames_ = 0;
    return;
  }
  if (++tf_ahead_frames_ < 3) return;
  ROS_WARN(
      "simstack perception: tf holds %s <- '%s' only %.0f s ahead of the frames, three frames "
      "in a row (a clock that was set wrong and then corrected?): the tf buffer is cleared and "
      "refilled from now on",
      target.c_str(), source.c_str(), (latest - stamp).toSec());
  tf_buffer_.clear();
  tf_ahead_frames_ = 0;
}

bool PerceptionServer::waitForTransform(const std::string& target, const std::string& source,
                                        const ros::Time& stamp, std::string* why) {
  // tf2's own timeout counts ros::Time alone: under a paused bag's clock it never ended, and
  // the worker (and a nodelet's unload, which joins it) waited for the bag to play on.
  const double timeout = node_.tf_timeout_s;
  const ros::SteadyTime begun = ros::SteadyTime::now();
  const ros::SteadyTime wall_deadline = begun + ros::WallDuration(timeout);
  const ros::Time start = ros::Time::now();
  ros::Time last = start;
  ros::SteadyTime last_moved = begun;
  for (;;) {
    std::string error;  // tf2 appends to it: one attempt's reason only
    if (tf_buffer_.canTransform(target, source, stamp, &error)) return true;
    const ros::SteadyTime wall = ros::SteadyTime::now();
    const ros::Time now = ros::Time::now();
    if (now != last) {
      last = now;
      last_moved = wall;
    }
    const bool waited = wall >= wall_deadline && (now < start || (now - start).toSec() >= timeout ||
                                                  (wall - last_moved).toSec() >= timeout);
    if (waited || stopRequested()) {
      std::ostringstream out;
      out << "no transform " << target << " <- '" << source << "' ";
      if (waited)
        out << "within " << timeout << " s";
      else
        out << "(the node stopped while waiting)";
      out << ": " << (error.empty() ? "tf holds nothing between them at that time" : error);
      if (waited && target == node_.table_frame && !node_.estimate_table)
        out << " (the table frame comes from tf: a bag needs its /tf_static or /tf recorded, or "
               "set ~estimate_table to find the table in the depth)";
      *why = out.str();
      return false;
    }
    ros::WallDuration(0.005).sleep();
  }
}

bool PerceptionServer::stopRequested() {
  std::lock_guard<std::mutex> lock(mutex_);
  return stop_;
}

void PerceptionServer::startLiveSettings() {
  // Two servers, so that every live setting keeps its parameter's name: ~samples, ~symmetries,
  // ... on ~, the Hough voting's on ~hough (~hough/bandwidth_m). Each shows the node's
  // parameters, not the .cfg's defaults.
  reconfigure_ =
      std::make_unique<dynamic_reconfigure::Server<LiveSettingsConfig>>(reconfigure_mutex_, pnh_);
  reconfigure_->updateConfig(liveSettings(perception_->config(), node_.occupancy_min));
  requested_ = perception_->config();
  requested_occupancy_min_ = node_.occupancy_min;
  // A change is judged at once and answered with what will be in effect: a refused value is
  // reported and shown back as the one that stays, before any frame comes.
  reconfigure_->setCallback([this](LiveSettingsConfig& settings, uint32_t) {
    std::lock_guard<std::mutex> lock(mutex_);
    PerceptionConfig c = requested_;
    pairLiveSettings(settings, c, kApply);
    c.decompose_samples = decompose_samples_;  // the core lowers it to samples
    // dynamic_reconfigure's range clamp lets NaN through: an occupancy cloud of nothing.
    if (!(settings.occupancy_min > 0.0 && settings.occupancy_min <= 1.0))
      ROS_ERROR(
          "simstack perception: live setting refused, the previous ones stay: "
          "occupancy_min must lie in (0, 1], not %g",
          settings.occupancy_min);
    else if (request(c))
      requested_occupancy_min_ = settings.occupancy_min;
    settings = liveSettings(requested_, requested_occupancy_min_);
  });
  hough_reconfigure_ = std::make_unique<dynamic_reconfigure::Server<HoughSettingsConfig>>(
      reconfigure_mutex_, ros::NodeHandle(pnh_, "hough"));
  hough_reconfigure_->updateConfig(houghSettings(perception_->config().hough));
  hough_reconfigure_->setCallback([this](HoughSettingsConfig& settings, uint32_t) {
    std::lock_guard<std::mutex> lock(mutex_);
    PerceptionConfig c = requested_;
    pairHoughSettings(settings, c.hough, kApply);
    request(c);
    settings = houghSettings(requested_.hough);
  });
}

bool PerceptionServer::request(const PerceptionConfig& config) {
  try {
    requested_ = perception_->settingsInEffect(config);
    settings_changed_ = true;
    return true;
  } catch (const std::invalid_argument& e) {
    ROS_ERROR("simstack perception: live setting refused, the previous ones stay: %s", e.what());
    return false;
  }
}

void PerceptionServer::applySettings() {
  PerceptionConfig c;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!settings_changed_) return;
    settings_changed_ = false;
    c = requested_;
    node_.occupancy_min = requested_occupancy_min_;
  }
  try {
    perception_->updateSettings(c);  // judged when requested already; this is a guard
  } catch (const std::invalid_argument& e) {
    ROS_ERROR("simstack perception: new settings refused, the previous ones stay: %s", e.what());
  }
}

void PerceptionServer::process(const Frame& frame) {
  applySettings();
  DepthView view;
  std::string why;
  if (!toView(frame, &view, &why)) return skip(frame, why);
  // The output frame's pose, looked up before the pipeline runs: a frame that cannot be placed
  // in it costs nothing.
  std::optional<Transform> T_output_camera;
  if (node_.outputFrame() != node_.table_frame) {
    T_output_camera = Transform::Identity();
    if (!lookup(node_.outputFrame(), tf2Frame(frame.image->header.frame_id),
                frame.image->header.stamp, &*T_output_camera, &why))
      return skip(frame, "~output_frame: " + why);
  }
  std::vector<DepthView> views;
  uint64_t resets = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const ViewHistory::Arrival arrival = views_.arrive(frame.image->header.stamp.toNSec());
    if (arrival.cleared > 0)
      ROS_WARN(
          "simstack perception: frame stamped %.3f s is %.3f s older than the last one on "
          "%s (a bag restarted?): the accumulated views are cleared",
          frame.image->header.stamp.toSec(), arrival.back_s, image_sub_.getTopic().c_str());
    // A bag that loops shows the same pile again: the tracker keeps the ids of objects found
    // where they were (its gates tell another pile's objects apart).
    if (reset_requested_) {
      views_.clear();
      tracker_.reset();
    }
    reset_requested_ = false;
    resets = resets_;
    view.mask = mask_;  // a mask of another size makes perceive() refuse the frame
    views = views_.viewsWith(view);
  }
  SceneEstimate estimate;
  try {
    estimate = perception_->perceive(views);
  } catch (const std::exception& e) {
    return skip(frame, e.what());  // not kept: a refused view would spoil every later frame
  }
  const Transform T_output_table =
      T_output_camera ? Transform(*T_output_camera * estimate.T_table_camera.inverse())
                      : Transform::Identity();
  // A frame ~reset overtook holds the views and ids the caller asked to forget: the next frame
  // is the first after the reset.
  std::lock_guard<std::mutex> publishing(publish_mutex_);
  if (!publish(frame, view, estimate, static_cast<int>(views.size()), T_output_table, resets)) {
    ROS_INFO("simstack perception: the frame stamped %.3f s began before ~reset: not published",
             frame.image->header.stamp.toSec());
    std::lock_guard<std::mutex> lock(mutex_);
    ++overtaken_;
    return;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  views_.keep(std::move(view));
  ++processed_;
  failing_ = false;
  last_timings_ = estimate.timings;
  last_scene_ = std::make_shared<const SceneEstimate>(std::move(estimate));
  last_scene_stamp_ = frame.image->header.stamp;
}

void PerceptionServer::watchTableBroadcasts() {
  // Another node's transform to table_frame (a URDF's table, say) would give the frame a second
  // parent beside the camera this node broadcasts it under, and tf's lookups would jump
  // between the two. Kept here (a static one for good, a dynamic one while it keeps coming)
  // and said by publish(), which broadcasts the table. Another nodelet of the same manager is
  // this process and shares its publisher name: it is not seen.
  const std::string me = ros::this_node::getName(), table = node_.table_frame;
  using Event = ros::MessageEvent<tf2_msgs::TFMessage const>;
  const auto watcher = [this, me, table](bool is_static) {
    return boost::function<void(const Event&)>([this, me, table, is_static](const Event& event) {
      if (event.getPublisherName() == me) return;
      for (const geometry_msgs::TransformStamped& t : event.getMessage()->transforms)
        if (tf2Frame(t.child_frame_id) == table) {
          std::lock_guard<std::mutex> lock(other_table_mutex_);
          other_table_ = event.getPublisherName() + " broadcasts '" + table + "' under '" +
                         tf2Frame(t.header.frame_id) + "'" + (is_static ? " on /tf_static" : "");
          other_table_static_ = is_static;
          other_table_seen_ = ros::SteadyTime::now();
          return;
        }
    });
  };
  tf_watch_ = nh_.subscribe<const Event&>("/tf", 100, watcher(false));
  tf_static_watch_ = nh_.subscribe<const Event&>("/tf_static", 100, watcher(true));
}

void PerceptionServer::warnAboutOtherTable() {
  std::lock_guard<std::mutex> lock(other_table_mutex_);
  const ros::SteadyTime now = ros::SteadyTime::now();
  const bool current = other_table_static_ || (now - other_table_seen_).toSec() < 10.0;
  if (other_table_.empty() || !current) return;
  // Once every 10 s, and at once for another broadcaster than the last one said.
  if (other_table_ == other_table_said_ && (now - other_table_said_at_).toSec() < 10.0) return;
  ROS_WARN(
      "simstack perception: %s too, while estimate_table broadcasts it under the camera: tf has "
      "two parents for it; give ~table_frame another name (replay.launch's estimated_frame)",
      other_table_.c_str());
  other_table_said_ = other_table_;
  other_table_said_at_ = now;
}

bool PerceptionServer::publish(const Frame& frame, const DepthView& view,
                               const SceneEstimate& estimate, int views,
                               const Transform& T_output_table, uint64_t resets) {
  std_msgs::Header header;
  header.stamp = frame.image->header.stamp;
  header.frame_id = node_.outputFrame();
  std_msgs::Header camera_header = frame.image->header;  // of the labels image and the table's tf
  camera_header.frame_id = tf2Frame(camera_header.frame_id);
  std::vector<SuperquadricShape> shapes;
  for (const InstanceEstimate& e : estimate.instances()) shapes.push_back(e.superquadric);
  // The tracker matches objects in a frame that stays put: the table's, or, where the table is
  // the plane estimated in each image (its origin and x axis follow the camera), the output
  // frame when that is another (a fixed frame of the workcell).
  std::vector<SuperquadricShape> tracked = shapes;
  if (estimate.table_estimated && node_.outputFrame() != node_.table_frame)
    for (SuperquadricShape& sq : tracked) sq.T_table_object = T_output_table * sq.T_table_object;
  ObjectIds ids;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (resets != resets_) return false;
    ids = tracker_.assign(tracked);
  }
  if (estimate.table_estimated) {
    warnAboutOtherTable();
    geometry_msgs::TransformStamped t = tf2::eigenToTransform(estimate.T_table_camera.inverse());
    t.header.stamp = header.stamp;
    t.header.frame_id = camera_header.frame_id;
    t.child_frame_id = node_.table_frame;
    tf_broadcaster_.sendTransform(t);
  }
  if (node_.publish_object_tf) {
    std::vector<geometry_msgs::TransformStamped> frames;
    for (size_t k = 0; k < shapes.size(); ++k) {
      geometry_msgs::TransformStamped t =
          tf2::eigenToTransform(Transform(T_output_table * shapes[k].T_table_object));
      t.header = header;
      t.child_frame_id = node_.object_frame_prefix + "object_" + std::to_string(ids[k]);
      frames.push_back(std::move(t));
    }
    if (!frames.empty()) tf_broadcaster_.sendTransform(frames);
  }
  objects_pub_.publish(objectArrayMsg(header, estimate, views,
                                      static_cast<int>(estimate.hypotheses.size()),
                                      perception_->config().symmetries, ids, T_output_table));
  instances_pub_.publish(instancesCloud(header, estimate, ids, T_output_table));
  markers_pub_.publish(objectMarkers(header, estimate, ids, T_output_table));
  double occupancy_min;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    occupancy_min = node_.occupancy_min;
  }
  occupancy_pub_.publish(
      occupancyCloud(header, estimate.occupancy_probability, occupancy_min, T_output_table));
  // Latched, it is made for every frame (a later subscriber gets the last); else only when
  // someone listens.
  if (node_.latch || labels_pub_.getNumSubscribers() > 0) {
    const sensor_msgs::Image labels =
        labelImage(camera_header,
                   pixelInstances(view, estimate, 0, labelMinHeight(perception_->config())), ids);
    if (node_.latch)
      labels_latched_pub_.publish(labels);
    else
      labels_pub_.publish(labels);
  }
  return true;
}

void PerceptionServer::warmUp() {
  const ros::SteadyTime begun = ros::SteadyTime::now();
  const SceneEstimate estimate = perception_->warmUp();
  warm_up_s_ = (ros::SteadyTime::now() - begun).toSec();
  warm_up_objects_ = static_cast<int>(estimate.instances().size());
  if (warm_up_objects_ == 1)
    ROS_INFO("simstack perception: network warmed up in %.2f s (the test box found)", warm_up_s_);
  else
    ROS_WARN(
        "simstack perception: warm-up on a rendered box found %d objects, not 1: is the model "
        "the one meant?",
        warm_up_objects_);
}

bool PerceptionServer::reset(std_srvs::Empty::Request&, std_srvs::Empty::Response&) {
  std::lock_guard<std::mutex> publishing(publish_mutex_);  // a frame being published goes out first
  std::lock_guard<std::mutex> lock(mutex_);
  reset_requested_ = true;
  ++resets_;
  ROS_INFO("simstack perception: accumulated views cleared");
  return true;
}

bool PerceptionServer::saveOctomap(SaveOctomap::Request& req, SaveOctomap::Response& res) {
  std::lock_guard<std::mutex> saving(save_mutex_);  // two calls for one name: one after the other
  res.success = false;
  res.message = badFileName(req.file_name);
  if (!res.message.empty()) return true;
  std::shared_ptr<const SceneEstimate> scene;
  double occupancy_min;
  std_msgs::Header header;  // the grid's frame: the table's
  {
    std::lock_guard<std::mutex> lock(mutex_);
    scene = last_scene_;
    occupancy_min = node_.occupancy_min;
    header.frame_id = node_.table_frame;
    header.stamp = last_scene_stamp_;
  }
  if (!scene) {
    res.message = "no scene perceived yet";
    return true;
  }
  namespace fs = std::filesystem;
  try {
    const fs::path dir = outputDirectory(node_.output_dir);
    fs::create_directories(dir);
    const fs::path target = dir / req.file_name;
    if (fs::is_symlink(target)) {
      res.message = "'" + req.file_name + "' in " + dir.string() + " is a symbolic link: refused";
      return true;
    }
    writeOccupancyOctomap(target.string(), scene->occupancy_probability, occupancy_min);
    res.path = fs::absolute(target).string();
    res.header = header;
    res.success = true;
    res.message =
        "wrote " + res.path + " (coordinates in the table frame '" + header.frame_id + "')";
  } catch (const std::exception& e) {
    res.message = e.what();
  }
  return true;
}

double PerceptionServer::secondsWithoutFrame(const ros::SteadyTime& now) const {
  return (now - (received_ > 0 ? last_arrival_ : started_)).toSec();
}

double PerceptionServer::silenceSeconds(const ros::SteadyTime& now) const {
  const double silent = secondsWithoutFrame(now);
  return silent >= node_.input_timeout_s ? silent : 0.0;
}

std::string PerceptionServer::silenceCause(const ros::SteadyTime& now) const {
  // Every message counted here came after the last frame and found no partner of its stamp
  // (a message that completes a pair is uncounted by onFrame).
  const bool recent_info = info_watch_.recent(now, node_.input_timeout_s);
  const bool recent_image = image_watch_.recent(now, node_.input_timeout_s);
  const uint32_t image_publishers = image_sub_.getNumPublishers();
  const uint32_t info_publishers = info_sub_.getNumPublishers();
  std::ostringstream out;
  out << std::fixed << std::setprecision(3);
  if ((recent_image || recent_info) && image_watch_.since_frame > 0 && info_watch_.since_frame > 0)
    out << "depth images and camera_info arrive but their stamps never match ("
        << image_watch_.since_frame << " image(s) and " << info_watch_.since_frame
        << " camera_info since " << (received_ > 0 ? "the last frame" : "the start")
        << ", the last stamped " << image_watch_.stamp.toSec() << " and "
        << info_watch_.stamp.toSec()
        << "): each image is taken with the camera_info of exactly its stamp";
  else if (recent_info)
    out << "camera_info arrives (the last stamped " << info_watch_.stamp.toSec()
        << ") but no depth image"
        << (image_publishers > 0 ? " from its publisher(s)"
                                 : ": nothing publishes " + image_sub_.getTopic());
  else if (recent_image)
    out << "depth images arrive (the last stamped " << image_watch_.stamp.toSec()
        << ") but no camera_info"
        << (info_publishers > 0 ? " from its publisher(s)"
                                : " (nothing publishes " + info_sub_.getTopic() + ")")
        << "; each image is taken with its camera_info";
  else if (image_publishers > 0 && info_publishers == 0)
    out << "nothing publishes " << info_sub_.getTopic() << " while the depth image has "
        << image_publishers << " publisher(s): each image is taken with its camera_info";
  else if (image_publishers > 0)
    out << "both topics have publishers but nothing comes (a paused or ended bag, a stopped "
           "camera?)";
  else if (received_ > 0)
    out << "nothing publishes them any more: the camera stopped, or the bag ended";
  else
    out << "is the camera running, and its namespace the one given?";
  return out.str();
}

void PerceptionServer::onSilenceCheck() {
  const ros::SteadyTime now = ros::SteadyTime::now();
  double silent = 0.0;
  bool warn = false, resumed = false;
  std::string cause;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    silent = silenceSeconds(now);
    // The first warning after input_timeout_s, then one every 30 s while it lasts, and one at
    // once when its cause changes (the cause's words before its details in brackets).
    const std::string now_cause = silent > 0.0 ? silenceCause(now) : std::string();
    const std::string kind = now_cause.substr(0, now_cause.find('('));
    // A changed cause is said at once, but at most once a 30 s (a slow stream flips it).
    const bool changed =
        kind != last_silence_kind_ &&
        (last_change_warning_.isZero() || (now - last_change_warning_).toSec() >= 30.0);
    if (silent > 0.0 && (last_silence_warning_.isZero() ||
                         (now - last_silence_warning_).toSec() >= 30.0 || changed)) {
      warn = true;
      if (changed && !last_silence_warning_.isZero()) last_change_warning_ = now;
      last_silence_warning_ = now;
      last_silence_kind_ = kind;
      cause = now_cause;
    } else if (silent == 0.0 && !last_silence_warning_.isZero()) {
      resumed = true;
      last_silence_warning_ = ros::SteadyTime();
    }
  }
  const std::string topics = image_sub_.getTopic() + " and " + info_sub_.getTopic();
  if (warn)
    ROS_WARN("simstack perception: no depth frame on %s for %.0f s: %s", topics.c_str(), silent,
             cause.c_str());
  if (resumed) ROS_INFO("simstack perception: depth frames arrive again on %s", topics.c_str());
}

void PerceptionServer::diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
  long unpaired = 0;
  {
    std::lock_guard<std::mutex> lock(pairing_mutex_);
    unpaired = pairing_.forgotten();
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (!model_error_.empty()) {
    status.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "model refused: " + model_error_);
    status.add("ready (model loaded and warmed up, listening)", std::string("false"));
    return;
  }
  const ros::SteadyTime now = ros::SteadyTime::now();
  const double seconds = std::max(1e-3, (now - rate_since_).toSec());
  const double rate = (processed_ - processed_before_) / seconds;
  rate_since_ = now;
  processed_before_ = processed_;
  const double silent = silenceSeconds(now);
  if (processed_ == 0 && skipped_ > 0)  // stays an error when the frames stop coming
    status.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "no frame processed: " + last_error_);
  else if (silent > 0.0)
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                   "no depth frame for " + std::to_string(static_cast<int>(silent)) + " s on " +
                       image_sub_.getTopic() + ": " + silenceCause(now));
  else if (failing_)
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "frames skipped: " + last_error_);
  else if (received_ == 0)
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "ready, waiting for the first frame");
  else
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "perceiving");
  status.add("ready (model loaded and warmed up, listening)", std::string("true"));
  status.add("warm-up objects found (a 12 x 8 x 6 cm box)", warm_up_objects_);
  status.add("warm-up seconds", warm_up_s_);
  status.add("depth topic", image_sub_.getTopic());
  status.add("seconds since the last frame", secondsWithoutFrame(now));
  status.add("frames received", received_);
  status.add("frames processed", processed_);
  status.add("frames dropped (newer frame came first)", dropped_);
  status.add("frames skipped (bad input)", skipped_);
  status.add("frames overtaken by ~reset (not published)", overtaken_);
  status.add("images or camera_info without a partner of their stamp (forgotten)", unpaired);
  status.add("frames processed per second (since the last report)", rate);
  status.add("last error", last_error_);
  status.add("table ms", last_timings_.table_ms);
  status.add("tsdf ms", last_timings_.tsdf_ms);
  status.add("network ms", last_timings_.network_ms);
  status.add("instances ms", last_timings_.instances_ms);
  status.add("mesh ms", last_timings_.mesh_ms);
  status.add("fitting ms", last_timings_.fitting_ms);
  status.add("total ms", last_timings_.total_ms);
  status.add("tiles (network passes) of the last frame", last_scene_ ? last_scene_->tiles : 0);
  status.add("grid side (m) of the last frame", last_scene_ ? last_scene_->tile_side_m : 0.0);
  status.add("workspace mask",
             mask_.empty() ? std::string("none")
                           : std::to_string(mask_.width) + "x" + std::to_string(mask_.height));
}

RefusedPerception::RefusedPerception(const ros::NodeHandle& nh, const ros::NodeHandle& pnh,
                                     const std::string& why)
    : diagnostics_(nh, pnh, pnh.getNamespace()) {
  ready_pub_ = ros::NodeHandle(pnh).advertise<std_msgs::Bool>("ready", 1, true);
  std_msgs::Bool ready;
  ready.data = false;
  ready_pub_.publish(ready);
  diagnostics_.setHardwareID("simstack_perception " + pnh.getNamespace());
  diagnostics_.add("perception", [why](diagnostic_updater::DiagnosticStatusWrapper& status) {
    status.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "not started: " + why);
    status.add("ready (model loaded and warmed up, listening)", std::string("false"));
  });
  timer_ = ros::NodeHandle(nh).createSteadyTimer(
      ros::WallDuration(1.0),
      [this](const ros::SteadyTimerEvent&) { diagnostics_.force_update(); });
}

}  // namespace simstack
