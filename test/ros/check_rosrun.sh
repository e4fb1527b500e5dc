#!/usr/bin/env bash
# `rosrun simstack <node>` from a shell that sourced the devel space of the README's build
# finds the package's nodes and tools (rosrun skips <package>/build/ itself; the build links
# them from <package>/.rosrun), and `rosrun simstack perception_node` starts and says ready.
# Usage: check_rosrun.sh BUILD_DIR
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
ros_session_start
ros_session_spawn "$ROS_HOME/node.log" rosrun simstack perception_node __ns:=camera
if ! timeout 120 rostopic echo -n 1 /camera/perception/ready 2> /dev/null | grep -q "data: True"; then
  echo "rosrun simstack perception_node did not say ready within 120 s; its log:"
  tail -20 "$ROS_HOME/node.log"
  exit 1
fi
echo "rosrun simstack perception_node: ready"
