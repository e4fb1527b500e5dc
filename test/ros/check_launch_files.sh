#!/usr/bin/env bash
# roslaunch-check on every launch file of the package (and the rostests): arguments,
# substitutions, packages and node types resolve.
set -e
build=$1
source_dir=$2
# shellcheck disable=SC1091
source "$build/devel/setup.bash"
ROS_HOME=$(mktemp -d)
export ROS_HOME
trap 'rm -rf "$ROS_HOME"' EXIT
status=0
for f in "$source_dir"/launch/*.launch "$source_dir"/test/ros/*.test; do
  if out=$(/usr/bin/python3 /usr/share/roslaunch/scripts/roslaunch-check "$f" 2>&1); then
    echo "ok: $f"
  else
    echo "FAILED: $f"; echo "$out"; status=1
  fi
done
exit $status
