/// The C++ client of docs/reference.md ("Grasp service"), compiled here so that the snippet
/// there stays true to the messages (check_downstream.sh builds it; nothing runs it).

#include <ros/ros.h>
#include <simstack/ObjectArray.h>
#include <simstack/RankGrasps.h>

bool firstHeldGrasp(ros::NodeHandle& nh, const simstack::ObjectArray& scene, uint32_t target,
                    simstack::Grasp* grasp) {
  ros::ServiceClient client = nh.serviceClient<simstack::RankGrasps>("/camera/grasps/rank_grasps");
  simstack::RankGrasps srv;
  srv.request.scene = scene;  // the simstack::ObjectArray the target was chosen from
  srv.request.target_id = target;
  srv.request.pull_distance_m = 0.10;
  srv.request.pull_speed_mps = 0.20;
  srv.request.target_frame = "base_link";  // poses in the robot's frame
  if (client.waitForExistence(ros::Duration(30.0)) && client.call(srv) && srv.response.success)
    for (const simstack::Grasp& g : srv.response.grasps)
      if (g.held) {
        *grasp = g;  // g.tool_pose and g.pregrasp_pose: PoseStamped in base_link, z into the object
        return true;
      }
  return false;
}
