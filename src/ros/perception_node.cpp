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
/// Says which parameters under `ns` were there before the node started and were not given on
/// its command line (`_name:=value`): outside roslaunch (which passes __log:= and sets its
/// parameters just before), they are an earlier run's, left on the master, and silently lay
/// another model or setting over the package config.
void warnLeftOverParameters(const std::string& ns, const std::set<std::string>& before,
                            const std::vector<std::string>& args) {
  std::set<std::string> given;
  for (const std::string& a : args) {
    if (a.rfind("__log:=", 0) == 0) return;  // started by roslaunch
    if (a.size() > 1 && a[0] == '_' && a[1] != '_' && a.find(":=") != std::string::npos)
      given.insert(ns + "/" + a.substr(1, a.find(":=") - 1));
  }
  std::string left;
  int count = 0;
  for (const std::string& name : before)
    if (!given.count(name)) {
      if (count < 5) left += (count ? ", " : "") + name.substr(ns.size() + 1);
      ++count;
    }
  if (count > 0)
    ROS_WARN(
        "simstack perception: %d parameter(s) under %s were set before this node started and not "
        "on its command line (%s%s): they are laid over the package config. Left by an earlier "
        "launch on this master? `rosparam delete %s` clears them.",
        count, ns.c_str(), left.c_str(), count > 5 ? ", ..." : "", ns.c_str());
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
  const std::vector<std::string> args(argv, argv + argc);  // before ros::init takes its own
  ros::init(argc, argv, "perception", ros::init_options::NoSigintHandler);
  ros::NodeHandle nh, pnh("~");  // topics under <namespace>/perception/, as launched
  const std::set<std::string> before = parametersUnder(pnh.getNamespace());
  warnLeftOverParameters(pnh.getNamespace(), before, args);
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
  // The spinner first: a settings change served after the removal would write them back.
  spinner.stop();
  if (ros::ok()) removeWrittenBack(pnh.getNamespace(), before);
  server.reset();
  ros::shutdown();
  return 0;
}
