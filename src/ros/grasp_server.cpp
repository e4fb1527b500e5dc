#include "simstack_ros/grasp_server.h"

#include <tf2_eigen/tf2_eigen.h>
#include <visualization_msgs/MarkerArray.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <optional>
#include <stdexcept>
#include <string>
#include <system_error>

#include "simstack_ros/conversions.h"
#include "simstack_ros/grasp_conversions.h"

namespace simstack {
namespace {

/// How long a tf lookup waits for the transform (wall-clock seconds).
constexpr double kTfWaitS = 0.5;

/// RankGrasps' status constant's name (diagnostics).
std::string statusName(uint8_t status) {
  static const char* const kNames[] = {
      "SUCCEEDED",      "NO_SCENE",    "STALE_SCENE", "EMPTY_SCENE", "UNKNOWN_TARGET",
      "TF_UNAVAILABLE", "BAD_REQUEST", "BAD_SCENE",   "CANCELLED",   "INTERNAL_ERROR"};
  return status < std::size(kNames) ? kNames[status] : "status " + std::to_string(status);
}

}  // namespace

GraspServer::GraspServer(ros::NodeHandle nh, ros::NodeHandle pnh)
    : nh_(nh),
      pnh_(pnh),
      config_(graspServerConfigFromParams(pnh)),
      tf_listener_(tf_buffer_),
      diagnostics_(nh, pnh, pnh.getNamespace()) {
  // ~diagnostic_period is diagnostic_updater's (default 1 s); the timer below keeps the
  // period it had at start.
  const double period = checkedDiagnosticPeriod(pnh_, diagnostics_.getPeriod());
  diagnostics_.setHardwareID("simstack_grasps " + pnh_.getNamespace());
  diagnostics_.add("grasps", this, &GraspServer::diagnose);
  // Scenes on a queue and thread of their own: a request waiting for the ranking in progress
  // holds one of the service's threads, and with the scenes on that queue, the newest scene
  // would wait behind it and the request rank the one from before the ranking it waited for.
  ros::SubscribeOptions scenes = ros::SubscribeOptions::create<ObjectArray>(
      config_.objects_topic, 1, [this](const ObjectArray::ConstPtr& msg) { onObjects(msg); },
      ros::VoidPtr(), &scene_queue_);
  objects_sub_ = nh_.subscribe(scenes);
  scene_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &scene_queue_);
  scene_spinner_->start();
  markers_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("grasps", 1, true);
  rank_srv_ = pnh_.advertiseService("rank_grasps", &GraspServer::rank, this);
  // A plain ActionServer: SimpleActionServer recalls a goal stamped before the last one, and
  // under a looping bag's clock every goal after the first loop would be. Its goals and
  // cancels come on a queue and thread of their own: service requests waiting for the ranking
  // in progress hold the global queue's threads, and a cancel must not wait behind them.
  ros::NodeHandle action_nh(pnh_);
  action_nh.setCallbackQueue(&action_queue_);
  action_ = std::make_unique<actionlib::ActionServer<RankGraspsAction>>(
      action_nh, "rank_grasps_action", [this](GoalHandle goal) { onGoal(goal); },
      [this](GoalHandle goal) { onCancel(goal); }, false);
  action_->start();
  action_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &action_queue_);
  action_spinner_->start();
  // On the wall clock (also while a bag is paused), on the scenes' thread: the service's threads
  // may all wait for a ranking.
  ros::NodeHandle diagnostics_nh(nh_);
  diagnostics_nh.setCallbackQueue(&scene_queue_);
  diagnostics_timer_ = diagnostics_nh.createSteadyTimer(
      ros::WallDuration(period),
      [this](const ros::SteadyTimerEvent&) { diagnostics_.force_update(); });
  ROS_INFO("simstack grasp_server: scenes from %s, ~rank_grasps ready (%d candidates, %d threads)",
           nh_.resolveName(config_.objects_topic).c_str(), config_.policy.max_candidates,
           config_.ranking.threads);
}

GraspServer::~GraspServer() {
  diagnostics_timer_.stop();
  action_spinner_->stop();  // no goal starts, and no cancel comes, past this line
  {
    std::lock_guard<std::mutex> lock(goals_mutex_);
    for (auto& [id, cancelled] : cancelled_) *cancelled = true;
  }
  for (GoalThread& t : goal_threads_) t.thread.join();  // each stops within a pull
  action_.reset();
  scene_spinner_->stop();  // joins its thread: no scene callback runs past this line
  objects_sub_.shutdown();
}

void GraspServer::onObjects(const ObjectArray::ConstPtr& msg) {
  {
    std::lock_guard<std::mutex> lock(latest_mutex_);
    latest_ = msg;
  }
  std::lock_guard<std::mutex> lock(answers_mutex_);
  ++answers_.scenes;
}

void GraspServer::record(const RankGrasps::Response& res) {
  std::lock_guard<std::mutex> lock(answers_mutex_);
  ++answers_.by_status[res.status];
  ++answers_.total;
  answers_.last_status = res.status;
  answers_.last_message = res.message;
  answers_.last_time_s = res.time_s;
}

void GraspServer::diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
  ObjectArray::ConstPtr latest;
  {
    std::lock_guard<std::mutex> lock(latest_mutex_);
    latest = latest_;
  }
  Answers a;
  {
    std::lock_guard<std::mutex> lock(answers_mutex_);
    a = answers_;
  }
  const std::string topic = nh_.resolveName(config_.objects_topic);
  double age = 0.0;
  std::string stale;
  if (latest && !latest->header.stamp.isZero()) {
    age = (ros::Time::now() - latest->header.stamp).toSec();
    stale = staleScene(age, config_.policy.max_scene_age_s);
  }
  // A ranking holds rank_mutex_ for as long as it runs.
  const bool ranking = !rank_mutex_.try_lock();
  if (!ranking) rank_mutex_.unlock();
  using diagnostic_msgs::DiagnosticStatus;
  if (a.total > 0 && a.last_status == RankGrasps::Response::INTERNAL_ERROR)
    status.summary(DiagnosticStatus::ERROR, "the last ranking failed: " + a.last_message);
  else if (!latest)
    status.summary(DiagnosticStatus::OK,
                   "no scene on " + topic + " yet: requests that carry their scene are served");
  else if (!stale.empty())
    status.summary(DiagnosticStatus::WARN, "the latest scene on " + topic + " is " + stale +
                                               ": requests without a scene are refused");
  else
    status.summary(DiagnosticStatus::OK, ranking ? "ranking" : "serving");
  status.add("objects topic", topic);
  status.add("scenes received", a.scenes);
  status.add("latest scene: objects", latest ? static_cast<int>(latest->objects.size()) : 0);
  status.add("latest scene: age (s)", age);
  status.add("ranking in progress", std::string(ranking ? "true" : "false"));
  status.add("requests answered", a.total);
  for (const auto& [code, count] : a.by_status) status.add("answered " + statusName(code), count);
  status.add("last answer",
             a.total > 0 ? statusName(a.last_status) + ": " + a.last_message : std::string("none"));
  status.add("last answer's time (s)", a.last_time_s);
}

bool GraspServer::lookup(const std::string& target, const std::string& source,
                         const ros::Time& stamp, Transform* T_target_source, std::string* why) {
  // Waited for on the wall clock: under a paused bag's clock tf2's own timeout never ends.
  const ros::SteadyTime deadline = ros::SteadyTime::now() + ros::WallDuration(kTfWaitS);
  std::string error;
  while (!tf_buffer_.canTransform(target, source, stamp, &error)) {
    if (ros::SteadyTime::now() >= deadline) break;
    ros::WallDuration(0.01).sleep();
  }
  try {
    *T_target_source = rigidFromTf(tf_buffer_.lookupTransform(target, source, stamp));
    return true;
  } catch (const tf2::TransformException& e) {
    char seconds[32];
    std::snprintf(seconds, sizeof(seconds), "%.3f", stamp.toSec());
    *why = "no transform '" + target + "' <- '" + source + "' at the scene's stamp " + seconds +
           " s: " + e.what();
    // A frame tf never heard of: with no frame at all, this node has had no tf (started after
    // a bag ended); else the name may be misspelt, and the frames it knows are named.
    std::vector<std::string> known;
    tf_buffer_._getFrameStrings(known);
    for (const std::string& frame : {target, source}) {
      if (tf_buffer_._frameExists(frame)) continue;
      if (known.empty()) {
        *why +=
            " (this grasp server's tf has received no transform at all: was tf published "
            "while it ran? a bag that ended before it started left it none)";
      } else {
        std::string some;
        for (size_t k = 0; k < known.size() && k < 8; ++k) some += (k ? ", " : "") + known[k];
        *why += " (its tf knows no frame '" + frame + "'; it knows " + some +
                (known.size() > 8 ? ", ..." : "") + ")";
      }
      break;
    }
    return false;
  }
}

bool GraspServer::nearestToPoint(const geometry_msgs::PointStamped& point, const ObjectArray& scene,
                                 int* target, uint8_t* status, std::string* why) {
  Vec3 p(point.point.x, point.point.y, point.point.z);
  if (!p.allFinite()) {
    *status = RankGrasps::Response::BAD_REQUEST;
    *why = "target_point is not finite";
    return false;
  }
  const std::string frame = tf2Frame(point.header.frame_id);
  const std::string scene_frame = tf2Frame(scene.header.frame_id);
  if (frame != scene_frame) {
    Transform T_scene_point;
    if (!lookup(scene_frame, frame, scene.header.stamp, &T_scene_point, why)) {
      *status = RankGrasps::Response::TF_UNAVAILABLE;
      *why = "target_point: " + *why;
      return false;
    }
    p = T_scene_point * p;
  }
  std::vector<SuperquadricShape> shapes;
  for (const Object& o : scene.objects)
    shapes.push_back(superquadricFromMsg(o.superquadric, "object " + std::to_string(o.id)));
  double distance = INFINITY;
  *target = objectAtPoint(shapes, p, &distance);
  if (*target < 0) {
    *status = RankGrasps::Response::UNKNOWN_TARGET;
    *why = "no object's surface lies within " + number(kMaxTargetPointM) + " m of target_point (" +
           number(p.x()) + ", " + number(p.y()) + ", " + number(p.z()) + ") in '" + scene_frame +
           "': the nearest is " + number(distance) + " m away";
    return false;
  }
  return true;
}

bool GraspServer::placeRequest(const RankGrasps::Request& req, const ObjectArray& scene,
                               RankGrasps::Response& res, PreparedRequest* out) {
  int* target = &out->target;
  *target = -1;
  std::string ids;
  for (size_t k = 0; k < scene.objects.size(); ++k) {
    if (scene.objects[k].id == req.target_id) *target = static_cast<int>(k);
    ids += (k ? ", " : "") + std::to_string(scene.objects[k].id);
  }
  // A frame given as "/" alone (tf1's root prefix) names no frame: a malformed field, not a
  // transform tf lacks.
  for (const std::string* frame : {&req.target_frame, &req.target_point.header.frame_id})
    if (!frame->empty() && tf2Frame(*frame).empty()) {
      res.status = RankGrasps::Response::BAD_REQUEST;
      res.message =
          std::string(frame == &req.target_frame ? "target_frame" : "target_point's frame_id") +
          " '" + *frame + "' names no frame";
      return false;
    }
  const geometry_msgs::Point& q = req.target_point.point;
  if (req.target_point.header.frame_id.empty() && (q.x != 0.0 || q.y != 0.0 || q.z != 0.0)) {
    // Without a frame the point means nothing; ranking target_id instead would pick an object
    // the caller did not name.
    res.status = RankGrasps::Response::BAD_REQUEST;
    res.message =
        "target_point has no header.frame_id: give the point's frame, or leave the point at 0 to "
        "choose the target by target_id";
    return false;
  }
  if (!req.target_point.header.frame_id.empty()) {
    if (!nearestToPoint(req.target_point, scene, target, &res.status, &res.message)) return false;
  } else if (*target < 0) {
    res.status = RankGrasps::Response::UNKNOWN_TARGET;
    res.message =
        "unknown target id " + std::to_string(req.target_id) + " (the scene's ids: " + ids + ")";
    return false;
  }
  res.target_id = scene.objects[*target].id;
  out->pose_header = res.header;
  out->T_pose_table = out->T_scene_table;
  if (!req.target_frame.empty() && tf2Frame(req.target_frame) != res.header.frame_id) {
    out->pose_header.frame_id = tf2Frame(req.target_frame);
    Transform T_pose_scene;
    if (!lookup(out->pose_header.frame_id, res.header.frame_id, res.header.stamp, &T_pose_scene,
                &res.message)) {
      res.status = RankGrasps::Response::TF_UNAVAILABLE;
      return false;
    }
    out->T_pose_table = T_pose_scene * out->T_scene_table;
  }
  return true;
}

bool GraspServer::prepare(const RankGrasps::Request& req, RankGrasps::Response& res,
                          PreparedRequest* out) {
  ObjectArray::ConstPtr scene;
  if (!req.scene.objects.empty()) {
    scene = boost::make_shared<ObjectArray>(req.scene);
  } else {
    std::lock_guard<std::mutex> lock(latest_mutex_);
    scene = latest_;
  }
  const std::string topic = nh_.resolveName(config_.objects_topic);
  if (!scene) {
    res.status = RankGrasps::Response::NO_SCENE;
    res.message = "the request has no objects and no scene has arrived on " + topic +
                  " yet (is the perception running? its log says why not)";
    return false;
  }
  // The scene's frame and stamp from here on, a stale one's too (its age is the task's to see).
  res.header = scene->header;
  res.header.frame_id = tf2Frame(res.header.frame_id);  // markers in rviz
  if (req.scene.objects.empty() && !scene->header.stamp.isZero()) {
    const double age = (ros::Time::now() - scene->header.stamp).toSec();
    if (const std::string why = staleScene(age, config_.policy.max_scene_age_s); !why.empty()) {
      res.status = RankGrasps::Response::STALE_SCENE;
      res.message = "the latest scene on " + topic + " is " + why;
      return false;
    }
  }
  if (scene->objects.empty()) {
    res.status = RankGrasps::Response::EMPTY_SCENE;
    char stamp[32];
    std::snprintf(stamp, sizeof(stamp), "%u.%09u", scene->header.stamp.sec,
                  scene->header.stamp.nsec);
    res.message = "the request has no objects and the latest scene on " + topic + " (stamp " +
                  stamp + " s) has none either";
    return false;
  }
  res.status = RankGrasps::Response::BAD_SCENE;  // what an invalid_argument from here is about
  std::vector<uint32_t> ids;
  for (const Object& o : scene->objects) ids.push_back(o.id);
  // Before any work: a target chosen by id, or a tf wait, would answer another fault.
  std::string why = checkIds(ids);
  if (tf2Frame(scene->header.frame_id).empty())
    why =
        "its header.frame_id is '" + scene->header.frame_id + "': its poses are in no known frame";
  if (!why.empty()) {
    res.message = (req.scene.objects.empty() ? "the latest scene on " + topic + ": "
                                             : std::string("the request's scene: ")) +
                  why;
    return false;
  }
  GraspRequest request;
  request.pull_distance_m = asWritten(req.pull_distance_m);
  request.pull_speed_mps = asWritten(req.pull_speed_mps);
  request.candidates = req.candidates;
  request.hypotheses = req.hypotheses;
  request.pregrasp_m = asWritten(req.pregrasp_distance_m);
  checkGraspBounds(request, config_.policy);  // before any work (throws; caught by serve())
  out->T_scene_table = tableInFrame(*scene);  // throws for a bad pose (caught by serve())
  // The scenes asked for only (table frame; throws for a bad pose). The scene is checked before
  // a target is looked for in it: a malformed one is BAD_SCENE, not an unknown target.
  request.scenes = graspScenes(*scene, GraspPolicy::hypothesesFor(req.hypotheses));
  if (why = checkScene(request.scenes[0], ids); !why.empty())
    throw std::invalid_argument("the scene's " + why);
  out->measured_from = measuringCamera(*scene);  // throws for a malformed table_pose
  if (!placeRequest(req, *scene, res, out)) return false;
  request.target = out->target;
  request.ids = ids;
  if (req.use_camera_pose) {  // its position only: candidates are what is in sight from it
    const geometry_msgs::Point& p = req.camera_pose.position;
    request.camera_table = out->T_scene_table.inverse() * Vec3(p.x, p.y, p.z);
  }
  // Throws std::invalid_argument saying what is out of bounds (caught by serve()).
  out->grasps = prepareGrasps(request, config_.ranking, config_.policy);
  out->measured_target = measuredSurface(scene->objects[out->target], out->T_scene_table.inverse());
  std::string notes = out->grasps.notes;
  // A cloud that is not the target's (a scene built by hand) would judge the seals on a surface
  // the cup never meets: its points are set aside and the ranking says so.
  const SuperquadricShape& target = request.scenes[0][static_cast<size_t>(out->target)];
  if (const std::string why = measuredOffTarget(out->measured_target, target); !why.empty()) {
    addNote(&notes,
            "seals judged on the superquadric alone: of the target's surface cloud, " + why);
    out->measured_target.clear();
  }
  if (req.hypotheses == 0 && scene->hypotheses.empty())
    addNote(&notes,
            "ranked in the objects alone: the scene carries no hypotheses (the perception "
            "publishes them with a model that has a latent code and decompose_samples above 1, "
            "as grasps.launch does by default)");
  res.message = notes.empty() ? notes : notes + "; ";
  return true;
}

bool GraspServer::rank(RankGrasps::Request& req, RankGrasps::Response& res) {
  serve(req, res, {});
  record(res);
  return true;
}

void GraspServer::onGoal(GoalHandle goal) {
  const std::string id = goal.getGoalID().id;
  auto cancelled = std::make_shared<std::atomic<bool>>(false);
  std::lock_guard<std::mutex> lock(goals_mutex_);
  cancelled_[id] = cancelled;
  goal.setAccepted();
  // Threads of finished goals are joined here, so that they do not pile up.
  for (auto it = goal_threads_.begin(); it != goal_threads_.end();) {
    if (*it->finished) {
      it->thread.join();
      it = goal_threads_.erase(it);
    } else {
      ++it;
    }
  }
  // Its own thread: the spinner's stay free for cancels and the service.
  auto finished = std::make_shared<std::atomic<bool>>(false);
  try {
    std::thread thread([this, goal, id, cancelled, finished]() mutable {
      runGoal(goal, *cancelled);
      std::lock_guard<std::mutex> done(goals_mutex_);
      cancelled_.erase(id);
      *finished = true;
    });
    goal_threads_.push_back({std::move(thread), finished});
  } catch (const std::system_error& e) {  // no thread to be had: the goal ends, the server stays
    cancelled_.erase(id);
    RankGraspsResult result;
    result.status = RankGraspsResult::INTERNAL_ERROR;
    result.message = std::string("no thread for the ranking: ") + e.what();
    ROS_ERROR("simstack grasp_server: %s", result.message.c_str());
    RankGrasps::Response counted;  // in the diagnostics as every other answer
    counted.status = result.status;
    counted.message = result.message;
    record(counted);
    goal.setAborted(result, result.message);
  }
}

void GraspServer::onCancel(GoalHandle goal) {
  std::lock_guard<std::mutex> lock(goals_mutex_);
  const auto it = cancelled_.find(goal.getGoalID().id);
  if (it != cancelled_.end()) *it->second = true;
}

void GraspServer::runGoal(GoalHandle goal, const std::atomic<bool>& cancelled) {
  const RankGraspsGoal& g = *goal.getGoal();
  RankGrasps::Request req;
  req.scene = g.scene;
  req.target_id = g.target_id;
  req.target_point = g.target_point;
  req.target_frame = g.target_frame;
  req.pregrasp_distance_m = g.pregrasp_distance_m;
  req.candidates = g.candidates;
  req.pull_distance_m = g.pull_distance_m;
  req.pull_speed_mps = g.pull_speed_mps;
  req.use_camera_pose = g.use_camera_pose;
  req.camera_pose = g.camera_pose;
  req.hypotheses = g.hypotheses;
  RankGrasps::Response res;
  serve(
      req, res,
      [&](int done, int total, const Grasp* best) {
        RankGraspsFeedback feedback;
        feedback.pulls_done = static_cast<uint32_t>(done);
        feedback.pulls_total = static_cast<uint32_t>(total);
        feedback.has_best = best != nullptr;
        if (best) feedback.best = *best;
        goal.publishFeedback(feedback);
        return !cancelled && ros::ok();
      },
      &cancelled);
  const bool was_cancelled = cancelled;  // read once: a cancel may still come
  if (was_cancelled) res.status = RankGrasps::Response::CANCELLED;
  record(res);
  RankGraspsResult result;
  result.success = res.success && !was_cancelled;  // cancelled after the last pull: none either
  result.status = res.status;
  result.message = res.message;
  result.header = res.header;
  result.target_id = res.target_id;
  result.grasps = res.grasps;
  result.candidates_seen = res.candidates_seen;
  result.candidates_sealable = res.candidates_sealable;
  result.hypotheses_used = res.hypotheses_used;
  result.baseline_displacement_m = res.baseline_displacement_m;
  result.settle_displacement_m = res.settle_displacement_m;
  result.pulls = res.pulls;
  result.time_s = res.time_s;
  if (was_cancelled)
    goal.setCanceled(result, res.message);
  else if (res.success)
    goal.setSucceeded(result, res.message);
  else
    goal.setAborted(result, res.message);
}

void GraspServer::serve(const RankGrasps::Request& req, RankGrasps::Response& res,
                        const GraspFeedback& feedback, const std::atomic<bool>* cancelled) {
  std::lock_guard<std::mutex> lock(rank_mutex_);
  const auto start = std::chrono::steady_clock::now();
  res.success = false;
  res.status = RankGrasps::Response::INTERNAL_ERROR;
  if (cancelled && *cancelled) {
    res.status = RankGrasps::Response::CANCELLED;
    res.message = "cancelled while it waited for the ranking before it";
    return;
  }
  try {
    PreparedRequest p;
    if (!prepare(req, res, &p)) {
      ROS_WARN("simstack grasp_server: %s", res.message.c_str());
      clearMarkers();
      return;
    }
    // A service call has no feedback, but stops at shutdown too (CANCELLED), instead of holding
    // the node's exit for the rest of its pulls.
    RankingProgress progress = [](int, int, const RankedGrasp*) { return ros::ok(); };
    if (feedback)
      progress = [&](int done, int total, const RankedGrasp* best) {
        std::optional<Grasp> msg;
        if (best) msg = graspMsg(*best, p.pose_header, p.T_pose_table, p.grasps.pregrasp_m);
        return feedback(done, total, msg ? &*msg : nullptr);
      };
    const GraspRanking ranking =
        rankGrasps(p.grasps.scenes, p.target, p.grasps.cameras, p.grasps.config, progress,
                   p.measured_target, p.measured_from);
    for (const RankedGrasp& g : ranking.grasps)
      res.grasps.push_back(graspMsg(g, p.pose_header, p.T_pose_table, p.grasps.pregrasp_m));
    for (const SceneDrift& d : ranking.baseline) {
      res.baseline_displacement_m.push_back(static_cast<float>(d.max_displacement_m));
      res.settle_displacement_m.push_back(static_cast<float>(d.presettle_displacement_m));
    }
    res.candidates_seen = static_cast<uint32_t>(ranking.candidates.visible);
    res.candidates_sealable = static_cast<uint32_t>(ranking.candidates.sealable);
    res.hypotheses_used = static_cast<uint32_t>(ranking.hypotheses.size());
    res.pulls = static_cast<uint32_t>(ranking.pulls);
    res.message += (ranking.stopped ? "cancelled: " + std::to_string(ranking.grasps.size()) +
                                          " grasps with all their pulls done, not a ranking"
                                    : std::to_string(ranking.grasps.size()) + " grasps ranked") +
                   (ranking.message.empty() ? "" : "; " + ranking.message);
    res.success = !ranking.stopped;  // cancelled: the grasps so far, not a ranking
    res.status =
        ranking.stopped ? RankGrasps::Response::CANCELLED : RankGrasps::Response::SUCCEEDED;
    markers_pub_.publish(graspMarkers(res.header, ranking.grasps, p.T_scene_table));
    markers_frame_ = res.header.frame_id;
    ROS_INFO("simstack grasp_server: object %u: %zu grasps ranked, %d pulls in %zu %s",
             res.target_id, ranking.grasps.size(), ranking.pulls, ranking.hypotheses.size(),
             ranking.hypotheses.size() == 1 ? "hypothesis" : "hypotheses");
  } catch (const BadGraspRequest& e) {
    res.status = RankGrasps::Response::BAD_REQUEST;
    res.message = e.what();
    ROS_WARN("simstack grasp_server: %s", e.what());
  } catch (const std::invalid_argument& e) {  // the scene's: prepare() and rankGrasps check it
    res.status = RankGrasps::Response::BAD_SCENE;
    res.message = e.what();
    ROS_WARN("simstack grasp_server: %s", e.what());
  } catch (const std::exception& e) {
    res.status = RankGrasps::Response::INTERNAL_ERROR;
    res.message = std::string("ranking failed: ") + e.what();
    ROS_ERROR("simstack grasp_server: %s", res.message.c_str());
  }
  // A refused request has no grasps: the last ranking's arrows are not its answer.
  if (!res.success && res.status != RankGrasps::Response::CANCELLED) clearMarkers();
  res.time_s = std::chrono::duration<float>(std::chrono::steady_clock::now() - start).count();
}

void GraspServer::clearMarkers() {
  if (markers_frame_.empty()) return;  // none published
  std_msgs::Header header;
  header.frame_id = markers_frame_;
  header.stamp = ros::Time::now();
  markers_pub_.publish(graspMarkers(header, {}, Transform::Identity()));
  markers_frame_.clear();
}

}  // namespace simstack
