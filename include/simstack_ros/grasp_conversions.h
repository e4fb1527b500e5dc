#pragma once
/// @file grasp_conversions.h
/// ROS messages <-> the grasping module's types (free functions, no algorithm). The input
/// conversions throw std::invalid_argument with a message fit for a service response.

#include <simstack/Grasp.h>
#include <simstack/ObjectArray.h>
#include <visualization_msgs/MarkerArray.h>

#include <vector>

#include "simstack/geometry/superquadric.h"
#include "simstack/grasping/grasp_ranking.h"

namespace simstack {

/// The core superquadric of a message; rejects a quaternion that is not finite and of unit
/// norm (within 1e-3), naming `what`. The shape's values are checked by checkScene().
SuperquadricShape superquadricFromMsg(const simstack::Superquadric& msg, const std::string& what);
/// A unit-quaternion pose as a transform; rejects non-finite values and non-unit quaternions.
Transform rigidFromPose(const geometry_msgs::Pose& pose, const std::string& what);

/// The scenes of `msg` to simulate grasps in: its objects first, then up to `hypotheses` - 1 of
/// its further hypotheses.
std::vector<std::vector<SuperquadricShape>> graspScenes(const ObjectArray& msg, int hypotheses);

/// One ranked grasp as a message (contact pose: z axis along the approach).
Grasp graspMsg(const RankedGrasp& grasp);

/// DELETEALL, then each grasp as an arrow pointing at its contact along -approach, coloured
/// from green (best) to red (worst) (namespace "grasps"), and the rank of the best three as
/// text ("grasp_ranks").
visualization_msgs::MarkerArray graspMarkers(const std_msgs::Header& header,
                                             const std::vector<RankedGrasp>& grasps);

}  // namespace simstack
