#!/usr/bin/env bash
# `rosrun simstack <node>` from a shell that sourced the devel space of the README's build
# finds the package's nodes and tools (rosrun skips <package>/build/ itself; the build links
# them from <package>/.rosrun), `rosrun simstack perception_node` starts and says ready, and when
# it stops it takes the live settings it wrote back off the parameter server again (they would
# override the config at the next start) while keeping what was set before it.
# Usage: check_rosrun.sh DEVEL_DIR   (the devel space, or a build holding devel/)
set -e
root=$(cd "$(dirname "$0")/../.." && pwd)
export ROS_HOME
ROS_HOME=$(mktemp -d)
export ROS_SESSION_REMOVE_HOME=1
# shellcheck disable=SC1091
source "$root/scripts/ros_session.bash" "$1"
set -u
for node in perception_node grasp_server simstack_reconstruct; do
  found=$(rosrun --prefix echo simstack "$node")
  [ -x "$found" ] || { echo "rosrun simstack $node found no executable ('$found')"; exit 1; }
  echo "rosrun simstack $node -> $found"
done
rosrun simstack simstack_generate --help > /dev/null
echo "rosrun simstack simstack_generate --help: exit 0"
# A Python script is found once (else rosrun asks which, on stdin).
# In <package>/build the build hides its own copy (.rosrun) and rosrun finds the source's; in a
# catkin workspace or another build directory it takes the devel space's relay.
found=$(rosrun --prefix echo simstack rank_grasps.py < /dev/null 2>&1)
[ "$found" = "$root/scripts/rank_grasps.py" ] || [ "$found" = "$ROS_SESSION_DEVEL/lib/simstack/rank_grasps.py" ] ||
  { echo "rosrun simstack rank_grasps.py found not just one rank_grasps.py: $found"; exit 1; }
echo "rosrun simstack rank_grasps.py -> $found"
ros_session_start
rosparam set /camera/perception/tf_timeout_s 0.5  # set before the start: kept
ros_session_spawn "$ROS_HOME/node.log" rosrun simstack perception_node __ns:=camera
if ! timeout 120 rostopic echo -n 1 /camera/perception/ready 2> /dev/null | grep -q "data: True"; then
  echo "rosrun simstack perception_node did not say ready within 120 s; its log:"
  tail -20 "$ROS_HOME/node.log"
  exit 1
fi
echo "rosrun simstack perception_node: ready"
# A parameter set before the start and not on the command line is named: an earlier launch's
# leftovers would otherwise change the model or settings without a word.
grep -q "1 parameter(s) under /camera/perception were set before this node started and not on its command line (tf_timeout_s)" "$ROS_HOME/node.log" ||
  { echo "the node did not name the parameter set before it started; its log:"; tail -20 "$ROS_HOME/node.log"; exit 1; }
node_pid=${ROS_SESSION_PIDS[-1]}
rosparam get /camera/perception/samples > /dev/null ||
  { echo "the node wrote no ~samples back (dynamic_reconfigure)"; exit 1; }
ros_session_kill "$node_pid"
left=$(rosparam list /camera/perception)
if [ "$left" != "/camera/perception/tf_timeout_s" ]; then
  echo "after the node stopped, the parameter server holds under ~:"; echo "$left"
  tail -20 "$ROS_HOME/node.log"
  exit 1
fi
echo "rosrun simstack perception_node: stopped, its written-back settings removed, the user's kept"
