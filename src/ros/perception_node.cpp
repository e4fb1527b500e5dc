// perception_node: PerceptionServer in a process of its own (`rosrun simstack perception_node` in a
// catkin workspace; rosrun skips a build directory inside the package, as scripts/ make it).
#include <ros/package.h>
#include <ros/ros.h>

#include <unistd.h>

#include <csignal>
#include <cstdlib>
#include <set>
#include <string>
#include <vector>

#include "simstack_ros/perception_server.h"

namespace {
volatile std::sig_atomic_t stop_requested = 0;
void requestStop(int) { stop_requested = 1; }

/// Names of the parameters under `ns` on the parameter server.
std::set<std::string> parametersUnder(const std::string& ns) {
  std::vector<std::string> names;
  ros::param::getParamNames(names);
  std::set<std::string> under;
  for (const std::string& name : names)
    if (name.compare(0, ns.size() + 1, ns + "/") == 0) under.insert(name);
  return under;
}

/// dynamic_reconfigure writes every live setting back to the parameter server, where it would
/// outlast the node and override the config at the next `rosrun` (another model's `samples`,
/// say): what this run added goes again; what was set before it started stays.
void removeWrittenBack(const std::string& ns, const std::set<std::string>& before) {
  for (const std::string& name : parametersUnder(ns))
    if (!before.count(name)) ros::param::del(name);
}
}  // namespace

int main(int argc, char** argv) {
  // OpenMP workers that spin would fight the camera driver and the planner for the cores. The
  // OpenMP runtime reads its wait policy when it is loaded, before main: so the process starts
  // itself again with the policy set, unless the environment already chose one.
  if (!std::getenv("OMP_WAIT_POLICY")) {
    setenv("OMP_WAIT_POLICY", "passive", 1);
    execv("/proc/self/exe", argv);  // returns only on failure: then run as we are
  }
  // Our own SIGINT handler, so that the parameters can be cleaned up while the master is
  // still reachable.
  ros::init(argc, argv, "perception", ros::init_options::NoSigintHandler);
  ros::NodeHandle nh, pnh("~");  // topics under <namespace>/perception/, as launched
  const std::set<std::string> before = parametersUnder(pnh.getNamespace());
  std::signal(SIGINT, requestStop);
  std::signal(SIGTERM, requestStop);
  std::unique_ptr<simstack::PerceptionServer> server;
  try {
    server =
        std::make_unique<simstack::PerceptionServer>(nh, pnh, ros::package::getPath("simstack"));
  } catch (const std::exception& e) {
    ROS_FATAL("simstack perception: %s", e.what());
    removeWrittenBack(pnh.getNamespace(), before);
    return 1;
  }
  ros::AsyncSpinner spinner(2);  // frames and service calls in parallel with the worker
  spinner.start();
  while (!stop_requested && ros::ok()) ros::WallDuration(0.1).sleep();
  if (ros::ok()) removeWrittenBack(pnh.getNamespace(), before);
  spinner.stop();
  server.reset();
  ros::shutdown();
  return 0;
}
