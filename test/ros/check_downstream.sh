#!/usr/bin/env bash
# A user's package that depends on simstack (test/downstream: task code using the perception,
# the grasp ranking, the messages and the ROS conversions, and every public header) is built
# with catkin_make in a throwaway workspace on top of this build's devel space, and its task
# code run on the shipped config. Fails when a public header needs an include directory or a
# library that catkin does not pass on.
# Usage: check_downstream.sh BUILD_DIR SOURCE_DIR [DEVEL_DIR=BUILD_DIR/devel]
set -e
build=$(cd "$1" && pwd)
source_dir=$(cd "$2" && pwd)
devel=$(cd "${3:-$build/devel}" && pwd)
ws=$(mktemp -d)
trap 'rm -rf "$ws"' EXIT
mkdir -p "$ws/src/simstack_downstream_check"
cp "$source_dir"/test/downstream/{package.xml,CMakeLists.txt,task_code.cpp,service_client.cpp} \
  "$ws/src/simstack_downstream_check/"
(cd "$source_dir/include" && find simstack simstack_ros -name '*.h' | sort |
  sed 's|.*|#include <&>|') >"$ws/src/simstack_downstream_check/all_headers.cpp"
# shellcheck disable=SC1091
source "$devel/setup.bash"
cd "$ws"
# The system interpreter: Debian's ROS Python modules are not in a pyenv one on PATH.
# libtorch where this build found it (a system path here; elsewhere on other machines).
torch_dir=$(sed -n 's/^Torch_DIR:PATH=//p' "$build/CMakeCache.txt")
if ! catkin_make -DCMAKE_BUILD_TYPE=Release -DPYTHON_EXECUTABLE=/usr/bin/python3 \
  -DPython3_EXECUTABLE=/usr/bin/python3 ${torch_dir:+-DTorch_DIR="$torch_dir"} \
  >"$ws/build.log" 2>&1; then
  tail -40 "$ws/build.log"
  echo "FAILED: a package depending on simstack does not build"
  exit 1
fi
"$ws/devel/lib/simstack_downstream_check/task_code" "$source_dir/config/perception.yaml" \
  "$source_dir"
