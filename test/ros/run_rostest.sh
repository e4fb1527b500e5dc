#!/usr/bin/env bash
# Runs one rostest (its own master on a free port) against the devel space of a build.
# Usage: run_rostest.sh BUILD_DIR FILE.test
set -e
build=$1
test_file=$2
# shellcheck disable=SC1091
source "$build/devel/setup.bash"  # (not under set -u: Debian's ROS profile reads unset variables)
set -u
export ROS_HOSTNAME=localhost
export ROS_HOME=${ROS_HOME:-$(mktemp -d)}
exec rostest --text "$test_file"
