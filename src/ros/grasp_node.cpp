// grasp_server: GraspServer in a process of its own (launch/grasps.launch).
#include <ros/ros.h>

#include <memory>

#include "simstack_ros/grasp_server.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "grasps");
  ros::NodeHandle nh, pnh("~");
  std::unique_ptr<simstack::GraspServer> server;
  try {
    server = std::make_unique<simstack::GraspServer>(nh, pnh);
  } catch (const std::exception& e) {
    ROS_FATAL("simstack grasp_server: %s", e.what());
    return 1;
  }
  // The service's: a second request waits for the ranking in progress, not behind it in the
  // queue. Scenes come on a thread of the server's own.
  ros::AsyncSpinner spinner(2);
  spinner.start();
  ros::waitForShutdown();
  return 0;
}
