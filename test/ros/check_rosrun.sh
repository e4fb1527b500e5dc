#!/usr/bin/env bash
# `rosrun simstack <node>` from a shell that sourced the devel space of the README's build
# finds the package's nodes and tools (rosrun skips <package>/build/ itself; the build links
# them from <package>/.rosrun).
# Usage: check_rosrun.sh BUILD_DIR
set -e
# shellcheck disable=SC1091
source "$1/devel/setup.bash"
set -u
export ROS_HOME
ROS_HOME=$(mktemp -d)
trap 'rm -rf "$ROS_HOME"' EXIT
for node in perception_node grasp_server simstack_reconstruct; do
  found=$(rosrun --prefix echo simstack "$node")
  [ -x "$found" ] || { echo "rosrun simstack $node found no executable ('$found')"; exit 1; }
  echo "rosrun simstack $node -> $found"
done
rosrun simstack simstack_generate --help > /dev/null
echo "rosrun simstack simstack_generate --help: exit 0"
