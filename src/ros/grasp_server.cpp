#include "simstack_ros/grasp_server.h"

#include <visualization_msgs/MarkerArray.h>

#include <chrono>
#include <cmath>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>

#include "simstack_ros/conversions.h"
#include "simstack_ros/grasp_conversions.h"

namespace simstack {
namespace {

bool positiveFinite(double v) { return std::isfinite(v) && v > 0.0; }

/// A number as a person writes it: 0.1, 2, nan (std::to_string gives 0.100000 and -nan).
std::string number(double v) {
  if (std::isnan(v)) return "nan";
  std::ostringstream out;
  out << v;
  return out.str();
}

/// Why a scene's objects cannot be told apart by id or placed ("" when they can).
std::string badIds(const ObjectArray& scene) {
  if (scene.header.frame_id.empty())
    return "the scene has no header.frame_id: its poses are in no known frame";
  std::set<uint32_t> seen;
  for (const Object& o : scene.objects)
    if (!seen.insert(o.id).second)
      return "object id " + std::to_string(o.id) +
             " appears twice in the scene: ids must be unique";
  return "";
}

/// How far a scene's lowest surface may be from z = 0, where the simulation puts the table,
/// for the scene to be taken as resting on it (metres).
constexpr double kTableGapM = 0.05;

/// A scene's lowest surface against the simulation's table at z = 0: below it by more than
/// kTableGapM is refused (`*refuse`), as a scene in another frame than the table's; above it
/// is said, as its objects fall before any pull. Empty when the scene rests on the table.
std::string tableNote(const std::vector<SuperquadricShape>& scene, const std::string& frame,
                      bool* refuse) {
  const double bottom = sceneBottom(scene);
  *refuse = bottom < -kTableGapM;
  if (std::abs(bottom) <= kTableGapM) return {};
  return "the scene's lowest surface is at z = " + number(bottom) + " m in '" + frame +
         "', where the simulation's table is at z = 0: " +
         (*refuse ? std::string("its objects would stand in the table")
                  : std::string("its objects fall before any pull")) +
         " (a scene is in the table frame: z up, the table at z = 0)";
}

}  // namespace

GraspServer::GraspServer(ros::NodeHandle nh, ros::NodeHandle pnh)
    : nh_(nh), pnh_(pnh), config_(graspServerConfigFromParams(pnh)) {
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
  ROS_INFO("simstack grasp_server: scenes from %s, ~rank_grasps ready (%d candidates, %d threads)",
           nh_.resolveName(config_.objects_topic).c_str(), config_.max_candidates,
           config_.ranking.threads);
}

GraspServer::~GraspServer() {
  scene_spinner_->stop();  // joins its thread: no scene callback runs past this line
  objects_sub_.shutdown();
}

void GraspServer::onObjects(const ObjectArray::ConstPtr& msg) {
  std::lock_guard<std::mutex> lock(latest_mutex_);
  latest_ = msg;
}

bool GraspServer::prepare(const RankGrasps::Request& req, RankGrasps::Response& res,
                          std::vector<std::vector<SuperquadricShape>>* scenes, int* target,
                          GraspRankingConfig* config, std::vector<Vec3>* cameras) {
  ObjectArray::ConstPtr scene;
  if (!req.scene.objects.empty()) {
    scene = boost::make_shared<ObjectArray>(req.scene);
  } else {
    std::lock_guard<std::mutex> lock(latest_mutex_);
    scene = latest_;
  }
  const std::string topic = nh_.resolveName(config_.objects_topic);
  if (!scene) {
    res.message = "the request has no objects and no scene has arrived on " + topic +
                  " yet (is the perception running? its log says why not)";
    return false;
  }
  if (req.scene.objects.empty() && config_.max_scene_age_s > 0.0 && !scene->header.stamp.isZero()) {
    // Under simulated time a replayed bag may loop: a stamp ahead of now is not stale.
    const double age = (ros::Time::now() - scene->header.stamp).toSec();
    if (age > config_.max_scene_age_s) {
      res.message = "the latest scene on " + topic + " is " + number(age) +
                    " s old (max_scene_age_s " + number(config_.max_scene_age_s) + "): " +
                    (age > 86400.0 ? "a day or more apart: is one of this node and the scene's "
                                     "publisher on simulated time (/use_sim_time) and the other "
                                     "not? "
                                   : "is the perception still running? ") +
                    "Send the scene in the request, or raise ~max_scene_age_s (0: any age)";
      return false;
    }
  }
  if (scene->objects.empty()) {
    res.message = "the request has no objects and the latest scene on " + topic + " (stamp " +
                  number(scene->header.stamp.toSec()) + " s) has none either";
    return false;
  }
  if (const std::string why = badIds(*scene); !why.empty()) {
    res.message = (req.scene.objects.empty() ? "the latest scene on " + topic + ": "
                                             : std::string("the request's scene: ")) +
                  why;
    return false;
  }
  res.header = scene->header;
  res.header.frame_id = tf2Frame(res.header.frame_id);  // markers in rviz
  *target = -1;
  std::string ids;
  for (size_t k = 0; k < scene->objects.size(); ++k) {
    if (scene->objects[k].id == req.target_id) *target = static_cast<int>(k);
    ids += (k ? ", " : "") + std::to_string(scene->objects[k].id);
  }
  if (*target < 0) {
    res.message =
        "unknown target id " + std::to_string(req.target_id) + " (the scene's ids: " + ids + ")";
    return false;
  }
  if (!positiveFinite(req.pull_distance_m) || req.pull_distance_m > config_.max_pull_distance_m) {
    res.message = "pull_distance_m must lie in (0, " + number(config_.max_pull_distance_m) +
                  "] m, not " + number(req.pull_distance_m) + " (e.g. 0.1)";
    return false;
  }
  if (!positiveFinite(req.pull_speed_mps) || req.pull_speed_mps > 2.0) {
    res.message =
        "pull_speed_mps must lie in (0, 2] m/s, not " + number(req.pull_speed_mps) + " (e.g. 0.2)";
    return false;
  }
  // 0: every hypothesis the scene carries (what the perception was launched to publish).
  const int wanted = static_cast<int>(std::min<size_t>(
      req.hypotheses == 0 ? 1 + scene->hypotheses.size() : size_t{req.hypotheses}, 64));
  *scenes = graspScenes(*scene, wanted);  // throws for a bad pose (caught by rank())
  for (size_t h = 0; h < scenes->size(); ++h)
    if (const std::string why = checkScene((*scenes)[h]); !why.empty()) {
      // checkScene counts objects in the message's order, from 0.
      res.message =
          (h == 0 ? std::string("the scene's ")
                  : "hypothesis " + std::to_string(h) + " (of the scene's hypotheses), ") +
          why;
      return false;
    }
  bool below = false;
  std::string notes = tableNote((*scenes)[0], res.header.frame_id, &below);
  if (below) {
    res.message = notes;
    return false;
  }
  if (!notes.empty()) notes += "; ";
  if (req.hypotheses == 0 && scene->hypotheses.empty())
    notes +=
        "ranked in the objects alone: the scene carries no hypotheses (the perception "
        "publishes them with a model that has a latent code and decompose_samples above 1, as "
        "grasps.launch does by default); ";
  if (static_cast<int>(scenes->size()) < wanted)
    notes += std::to_string(wanted) + " hypotheses asked for, the scene has " +
             std::to_string(scenes->size()) + "; ";
  *config = config_.ranking;
  int count = req.candidates == 0 ? config_.max_candidates
                                  : static_cast<int>(std::min<uint32_t>(req.candidates, 1u << 20));
  if (count > config_.max_candidates_limit) {
    notes += std::to_string(count) + " candidates asked for, clamped to max_candidates_limit " +
             std::to_string(config_.max_candidates_limit) + "; ";
    count = config_.max_candidates_limit;
  }
  config->candidates.max_candidates = count;
  config->pull.pull_distance_m = req.pull_distance_m;
  config->pull.pull_speed_mps = req.pull_speed_mps;
  cameras->clear();
  if (req.use_camera_pose) {  // its position only: candidates are what is in sight from it
    const geometry_msgs::Point& p = req.camera_pose.position;
    const Vec3 eye(p.x, p.y, p.z);
    if (!eye.allFinite()) {
      res.message = "camera_pose.position is not finite";
      return false;
    }
    cameras->push_back(eye);
  }
  res.message = notes;
  return true;
}

bool GraspServer::rank(RankGrasps::Request& req, RankGrasps::Response& res) {
  std::lock_guard<std::mutex> lock(rank_mutex_);
  const auto start = std::chrono::steady_clock::now();
  res.success = false;
  try {
    std::vector<std::vector<SuperquadricShape>> scenes;
    int target = -1;
    GraspRankingConfig config;
    std::vector<Vec3> cameras;
    if (!prepare(req, res, &scenes, &target, &config, &cameras)) {
      ROS_WARN("simstack grasp_server: %s", res.message.c_str());
      return true;
    }
    const GraspRanking ranking = rankGrasps(scenes, target, cameras, config);
    for (const RankedGrasp& g : ranking.grasps) res.grasps.push_back(graspMsg(g));
    for (const SceneDrift& d : ranking.baseline)
      res.baseline_displacement_m.push_back(static_cast<float>(d.max_displacement_m));
    res.candidates_seen = static_cast<uint32_t>(ranking.candidates.visible);
    res.candidates_sealable = static_cast<uint32_t>(ranking.candidates.sealable);
    res.hypotheses_used = static_cast<uint32_t>(ranking.hypotheses.size());
    res.pulls = static_cast<uint32_t>(ranking.pulls);
    res.message += std::to_string(ranking.grasps.size()) + " grasps ranked" +
                   (ranking.message.empty() ? "" : "; " + ranking.message);
    res.success = true;
    markers_pub_.publish(graspMarkers(res.header, ranking.grasps));
    ROS_INFO("simstack grasp_server: object %u: %zu grasps ranked, %d pulls in %zu hypotheses",
             req.target_id, ranking.grasps.size(), ranking.pulls, ranking.hypotheses.size());
  } catch (const std::invalid_argument& e) {
    res.message = e.what();
    ROS_WARN("simstack grasp_server: %s", e.what());
  } catch (const std::exception& e) {
    res.message = std::string("ranking failed: ") + e.what();
    ROS_ERROR("simstack grasp_server: %s", res.message.c_str());
  }
  res.time_s = std::chrono::duration<float>(std::chrono::steady_clock::now() - start).count();
  return true;
}

}  // namespace simstack
