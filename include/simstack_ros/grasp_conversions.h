#pragma once
/// @file grasp_conversions.h
/// ROS messages <-> the grasping module's types (free functions, no algorithm). The input
/// conversions throw std::invalid_argument with a message fit for a service response.

#include <simstack/Grasp.h>
#include <simstack/ObjectArray.h>
#include <visualization_msgs/MarkerArray.h>

#include <optional>
#include <vector>

#include "simstack/geometry/superquadric.h"
#include "simstack/grasping/grasp_ranking.h"

namespace simstack {

/// The number a float32 request field was written as: its shortest decimal, as a double (0.1f
/// is 0.1, not 0.100000001490116). A pull 1.5 nm longer changes some simulated outcomes, so the
/// service ranks on the numbers the caller gave, as simstack_rank_grasps does.
double asWritten(float value);

/// The core superquadric of a message; rejects a quaternion that is not finite and of unit
/// norm (within 1e-3), naming `what`, and normalises it. The shape's values are checked by
/// checkScene().
SuperquadricShape superquadricFromMsg(const simstack::Superquadric& msg, const std::string& what);
/// A unit-quaternion pose as a transform, the quaternion normalised; rejects non-finite values
/// and quaternions whose norm is not 1 within 1e-3.
Transform rigidFromPose(const geometry_msgs::Pose& pose, const std::string& what);

/// T_frame_table of `msg` (its table_in_frame): the identity when all zero (a message made by
/// hand); throws std::invalid_argument for a pose that is not finite or not a unit quaternion.
Transform tableInFrame(const ObjectArray& msg);

/// The scenes of `msg` to simulate grasps in, in its table frame (z up, table plane z = 0; the
/// simulation's): its objects first, then up to `hypotheses` - 1 of its further hypotheses.
std::vector<std::vector<SuperquadricShape>> graspScenes(const ObjectArray& msg, int hypotheses);

/// The depth points measured on `object` (the first measured_points of its surface cloud, x y
/// z float32), in its table frame: `T_table_frame` maps the message's frame there. Throws
/// std::invalid_argument for a cloud without x y z fields or with fewer points than it claims.
Points3 measuredSurface(const Object& object, const Transform& T_table_frame);

/// The position of the camera that measured every object's depth points, in the table frame:
/// from `msg.table_pose` when the frame fused one view (`views` 1); std::nullopt for points of
/// several views or a pose left all zero (a message made by hand). std::invalid_argument for
/// any other pose that is not a rigid transform (not finite, a quaternion not of norm 1).
std::optional<Vec3> measuringCamera(const ObjectArray& msg);

/// One ranked grasp (ranked in the table frame) as a message: its tool and pre-grasp poses
/// (toolPose(), pregraspPose()) and its approach in `pose_header`'s frame, mapped there by
/// `T_pose_table`.
Grasp graspMsg(const RankedGrasp& grasp, const std_msgs::Header& pose_header,
               const Transform& T_pose_table, double pregrasp_distance_m);

/// DELETEALL, then each grasp as an arrow pointing at its contact along -approach (namespace
/// "grasps"), coloured by outcome: green held and freed, yellow held but not freed, red the
/// seal broke; the rank of the best three as text ("grasp_ranks"); in `header`'s frame, where
/// the table frame is `T_frame_table`.
visualization_msgs::MarkerArray graspMarkers(const std_msgs::Header& header,
                                             const std::vector<RankedGrasp>& grasps,
                                             const Transform& T_frame_table);

}  // namespace simstack
