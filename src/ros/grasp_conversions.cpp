#include "simstack_ros/grasp_conversions.h"

#include <sensor_msgs/point_cloud2_iterator.h>
#include <tf2_eigen/tf2_eigen.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "simstack_ros/conversions.h"

namespace simstack {

Transform rigidFromPose(const geometry_msgs::Pose& p, const std::string& what) {
  const Quat q(p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z);
  const Vec3 t(p.position.x, p.position.y, p.position.z);
  if (!t.allFinite() || !q.coeffs().allFinite())
    throw std::invalid_argument(what + ": pose is not finite");
  if (std::abs(q.norm() - 1.0) > 1e-3)
    throw std::invalid_argument(what + ": orientation quaternion has norm " +
                                std::to_string(q.norm()) + ", not 1");
  // Normalised: a quaternion typed to four places (0.7071) is a rotation to 1e-5 only, and the
  // scene's checks hold rotations to 1e-6.
  Transform T = Transform::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = t;
  return T;
}

double asWritten(float value) {
  char text[64];
  const std::to_chars_result r = std::to_chars(text, text + sizeof(text) - 1, value);
  *r.ptr = '\0';
  return std::strtod(text, nullptr);
}

SuperquadricShape superquadricFromMsg(const simstack::Superquadric& m, const std::string& what) {
  SuperquadricShape sq;
  sq.scale_m = Vec3(m.semi_axes.x, m.semi_axes.y, m.semi_axes.z);
  sq.exponents = Vec3(m.exponents.x, m.exponents.y, m.exponents.z);
  sq.T_table_object = rigidFromPose(m.pose, what);
  return sq;
}

Transform tableInFrame(const ObjectArray& msg) {
  const geometry_msgs::Pose& p = msg.table_in_frame;
  const bool unset = p.position.x == 0.0 && p.position.y == 0.0 && p.position.z == 0.0 &&
                     p.orientation.x == 0.0 && p.orientation.y == 0.0 && p.orientation.z == 0.0 &&
                     p.orientation.w == 0.0;
  return unset ? Transform::Identity() : rigidFromPose(p, "the scene's table_in_frame");
}

std::vector<std::vector<SuperquadricShape>> graspScenes(const ObjectArray& msg, int hypotheses) {
  const Transform T_table_frame = tableInFrame(msg).inverse();
  const auto inTable = [&](SuperquadricShape sq) {
    sq.T_table_object = T_table_frame * sq.T_table_object;
    return sq;
  };
  std::vector<std::vector<SuperquadricShape>> scenes(1);
  for (const Object& o : msg.objects)
    scenes[0].push_back(
        inTable(superquadricFromMsg(o.superquadric, "object " + std::to_string(o.id))));
  for (size_t h = 0; h < msg.hypotheses.size() && static_cast<int>(scenes.size()) < hypotheses;
       ++h) {
    std::vector<SuperquadricShape> scene;
    for (size_t k = 0; k < msg.hypotheses[h].superquadrics.size(); ++k)
      scene.push_back(inTable(superquadricFromMsg(
          msg.hypotheses[h].superquadrics[k],
          "hypothesis " + std::to_string(h + 1) + " object " + std::to_string(k))));
    scenes.push_back(std::move(scene));
  }
  return scenes;
}

std::optional<Vec3> measuringCamera(const ObjectArray& msg) {
  if (msg.views != 1) return std::nullopt;
  const geometry_msgs::Pose& p = msg.table_pose;
  const geometry_msgs::Pose by_hand;  // a message filled by hand leaves it all zero
  if (p == by_hand) return std::nullopt;
  // T_camera_table: the camera in the table; a malformed pose is refused, not passed over.
  return rigidFromPose(p, "table_pose").inverse().translation();
}

Points3 measuredSurface(const Object& object, const Transform& T_table_frame) {
  const sensor_msgs::PointCloud2& cloud = object.surface;
  const size_t n = static_cast<size_t>(cloud.width) * cloud.height;
  if (object.measured_points == 0) return {};
  const std::string what = "object " + std::to_string(object.id) + ": surface cloud";
  // Divided, not multiplied: width x height x point_step can pass 2^64 and wrap to a small size.
  if (cloud.point_step == 0) throw std::invalid_argument(what + " has point_step 0");
  const size_t held = cloud.data.size() / cloud.point_step;
  if (n > held)
    throw std::invalid_argument(what + ": width x height is " + std::to_string(n) +
                                " points, its data holds " + std::to_string(held) + " (" +
                                std::to_string(cloud.data.size()) + " bytes of point_step " +
                                std::to_string(cloud.point_step) + ")");
  if (object.measured_points > n)
    throw std::invalid_argument(what + " holds " + std::to_string(n) + " points, fewer than the " +
                                std::to_string(object.measured_points) + " measured_points says");
  // The iterators read raw bytes at each field's offset: the layout is checked first, so that
  // a malformed cloud is refused rather than read out of bounds.
  for (const char* name : {"x", "y", "z"}) {
    const auto field =
        std::find_if(cloud.fields.begin(), cloud.fields.end(),
                     [&](const sensor_msgs::PointField& f) { return f.name == name; });
    if (field == cloud.fields.end())
      throw std::invalid_argument(what + " has no field \"" + name + "\"");
    if (field->datatype != sensor_msgs::PointField::FLOAT32 || field->count < 1 ||
        static_cast<size_t>(field->offset) + sizeof(float) > cloud.point_step)
      throw std::invalid_argument(what + ": field \"" + name +
                                  "\" is not a FLOAT32 inside point_step " +
                                  std::to_string(cloud.point_step));
  }
  Points3 out;
  sensor_msgs::PointCloud2ConstIterator<float> x(cloud, "x"), y(cloud, "y"), z(cloud, "z");
  for (size_t i = 0; i < object.measured_points; ++i, ++x, ++y, ++z) {
    const Vec3 p(*x, *y, *z);
    if (p.allFinite()) out.push_back(T_table_frame * p);
  }
  return out;
}

Grasp graspMsg(const RankedGrasp& g, const std_msgs::Header& pose_header,
               const Transform& T_pose_table, double pregrasp_distance_m) {
  Grasp m;
  // In the poses' frame, as the tool pose: one grasp's fields are read together.
  const Vec3 z = T_pose_table.linear() * g.candidate.approach_table.normalized();
  const Transform tool = T_pose_table * toolPose(g.candidate);
  m.tool_pose.header = m.pregrasp_pose.header = pose_header;
  m.tool_pose.pose = tf2::toMsg(tool);
  m.pregrasp_pose.pose = tf2::toMsg(pregraspPose(tool, pregrasp_distance_m));
  m.held = g.held();
  m.freed = g.freed();
  m.approach.x = z.x(), m.approach.y = z.y(), m.approach.z = z.z();
  m.seal_measured = g.candidate.measured;
  m.seal_score = static_cast<float>(g.candidate.seal_score);
  m.mean_displacement_m = static_cast<float>(g.mean_displacement_m);
  m.worst_displacement_m = static_cast<float>(g.worst_displacement_m);
  m.max_displacement_m = static_cast<float>(g.max_displacement_m);
  m.toppled = static_cast<float>(g.mean_toppled);
  m.freed_share = static_cast<float>(g.freed_share);
  m.failed_share = static_cast<float>(g.failed_share);
  m.score_m = static_cast<float>(g.score_m);
  m.perturbed_held_share = static_cast<float>(g.copies_held_share);
  m.com_offset_m = static_cast<float>(g.com_offset_m);
  m.peak_load = static_cast<float>(g.peak_load);
  for (const PullOutcome& o : g.outcomes)
    m.hypothesis_displacement_m.push_back(static_cast<float>(o.mean_displacement_m));
  return m;
}

visualization_msgs::MarkerArray graspMarkers(const std_msgs::Header& header,
                                             const std::vector<RankedGrasp>& grasps,
                                             const Transform& T_frame_table) {
  visualization_msgs::MarkerArray out;
  visualization_msgs::Marker clear;
  clear.header = header;
  clear.action = visualization_msgs::Marker::DELETEALL;
  out.markers.push_back(clear);
  const double length_m = 0.06;
  for (size_t i = 0; i < grasps.size(); ++i) {
    const Vec3 tip = T_frame_table * grasps[i].candidate.contact_table;
    const Vec3 tail =
        tip + length_m * (T_frame_table.linear() * grasps[i].candidate.approach_table.normalized());
    visualization_msgs::Marker arrow;
    arrow.header = header;
    arrow.ns = "grasps";
    arrow.id = static_cast<int>(i);
    arrow.type = visualization_msgs::Marker::ARROW;
    arrow.action = visualization_msgs::Marker::ADD;
    arrow.pose.orientation.w = 1.0;
    for (const Vec3& p : {tail, tip}) {
      geometry_msgs::Point q;
      q.x = p.x(), q.y = p.y(), q.z = p.z();
      arrow.points.push_back(q);
    }
    arrow.scale.x = 0.004;  // shaft diameter
    arrow.scale.y = 0.008;  // head diameter
    arrow.scale.z = 0.012;  // head length
    const Vec3 colour = outcomeColour(graspOutcome(grasps[i]));
    arrow.color.r = static_cast<float>(colour.x());
    arrow.color.g = static_cast<float>(colour.y());
    arrow.color.b = static_cast<float>(colour.z()), arrow.color.a = 1.0f;
    out.markers.push_back(arrow);
    if (i >= 3) continue;
    visualization_msgs::Marker text = arrow;
    text.ns = "grasp_ranks";
    text.type = visualization_msgs::Marker::TEXT_VIEW_FACING;
    text.points.clear();
    text.pose.position.x = tail.x(), text.pose.position.y = tail.y();
    text.pose.position.z = tail.z() + 0.01;
    text.scale.x = text.scale.y = 0.0, text.scale.z = 0.02;
    text.color.r = text.color.g = text.color.b = 1.0f;
    text.text = std::to_string(i + 1);
    out.markers.push_back(text);
  }
  return out;
}

}  // namespace simstack
