// perception_node: PerceptionServer in a process of its own (`rosrun simstack perception_node` in a
// catkin workspace; rosrun skips a build directory inside the package, as scripts/ make it).
#include <ros/package.h>
#include <ros/ros.h>

#include <unistd.h>

#include <cstdlib>

#include "simstack_ros/perception_server.h"

int main(int argc, char** argv) {
  // OpenMP workers that spin would fight the camera driver and the planner for the cores. The
  // OpenMP runtime reads its wait policy when it is loaded, before main: so the process starts
  // itself again with the policy set, unless the environment already chose one.
  if (!std::getenv("OMP_WAIT_POLICY")) {
    setenv("OMP_WAIT_POLICY", "passive", 1);
    execv("/proc/self/exe", argv);  // returns only on failure: then run as we are
  }
  ros::init(argc, argv, "perception");  // topics under <namespace>/perception/, as launched
  ros::NodeHandle nh, pnh("~");
  std::unique_ptr<simstack::PerceptionServer> server;
  try {
    server =
        std::make_unique<simstack::PerceptionServer>(nh, pnh, ros::package::getPath("simstack"));
  } catch (const std::exception& e) {
    ROS_FATAL("simstack perception: %s", e.what());
    return 1;
  }
  ros::AsyncSpinner spinner(2);  // frames and service calls in parallel with the worker
  spinner.start();
  ros::waitForShutdown();
  return 0;
}
