#!/usr/bin/env bash
# A missing, corrupt or damaged model at start (a file that is not a model; the shipped model
# with one byte flipped, which its card's SHA-256 catches): perception_node stays up, says
# "model refused" naming the file and the check, reports ERROR on /diagnostics, latches ~ready
# false and publishes no ObjectArray; the nodelet does the same inside a manager that keeps
# running. A ~image_transport no plugin provides, a pipeline setting out of range and one the
# model cannot take are configuration errors: the node exits 1 with a ROS_FATAL naming it; the
# nodelet latches ~ready false and reports ERROR on /diagnostics.
# Usage: test_bad_model.sh DEVEL_DIR SOURCE_DIR   (the devel space, or a build holding devel/)
set -e
build=$1
export ROS_HOME=$(mktemp -d)  # before the session script, which would make one of its own
# shellcheck disable=SC1091
source "$2/scripts/ros_session.bash" "$build"
set -u
ROS_SESSION_REMOVE_HOME=1
ros_session_start
node="$ROS_SESSION_DEVEL/lib/simstack/perception_node"
echo "not a model" > "$ROS_HOME/corrupt.pt"
cp "$2/models/simstack_r32_fc.pt" "$ROS_HOME/flipped.pt"
cp "$2/models/simstack_r32_fc.yaml" "$ROS_HOME/flipped.yaml"
/usr/bin/python3 - "$ROS_HOME/flipped.pt" <<'PY'
import sys
path = sys.argv[1]
data = bytearray(open(path, "rb").read())
data[len(data) // 2] ^= 0xFF  # one byte inside the weights
open(path, "wb").write(bytes(data))
PY

# refused NS MODEL CHECK: the node in namespace NS with MODEL says why (CHECK) on its log and in
# /diagnostics, ~ready is false, and it offers no objects topic.
refused() {
  local ns=$1 model=$2 check=$3 log="$ROS_HOME/$1.log"
  ros_session_spawn "$log" "$node" __ns:="$ns" _model:="$model"
  local pid=${ROS_SESSION_PIDS[-1]}
  for _ in $(seq 120); do grep -q "model refused" "$log" && break; sleep 0.5; done
  grep "ERROR.*model refused" "$log" | grep "$(basename "$model")" | grep -q "$check" ||
    { echo "$ns: no ERROR naming $model and '$check':"; cat "$log"; exit 1; }
  timeout 60 rostopic echo -n 1 "/$ns/perception/ready" | grep -q "data: False" ||
    { echo "$ns: ~ready is not false"; exit 1; }
  timeout 60 /usr/bin/python3 - "$ns" "$(basename "$model")" <<'PY' || { echo "$ns: no ERROR on /diagnostics"; exit 1; }
import sys, rospy
from diagnostic_msgs.msg import DiagnosticArray
ns, name = sys.argv[1], sys.argv[2]
rospy.init_node("diagnostics_reader", anonymous=True)
while not rospy.is_shutdown():
    for s in rospy.wait_for_message("/diagnostics", DiagnosticArray, timeout=15).status:
        if s.name.startswith(ns + "/perception") and s.level == 2 and name in s.message:
            sys.exit(0)
PY
  local topics
  topics=$(rostopic list) && [ -n "$topics" ] || { echo "$ns: rostopic list failed"; exit 1; }
  if echo "$topics" | grep -q "^/$ns/perception/objects$"; then
    echo "$ns: a refused model's node offers an objects topic"; exit 1; fi
  kill -0 "$pid" || { echo "$ns: the node exited"; cat "$log"; exit 1; }
  ros_session_kill "$pid"
}
refused missing "$ROS_HOME/missing.pt" "not found"
refused corrupt "$ROS_HOME/corrupt.pt" "not a libtorch archive"
refused flipped "$ROS_HOME/flipped.pt" "SHA-256"

# exits_fatal WHAT PATTERN PROGRAM ARGS...: PROGRAM, started in a namespace of its own (a
# `_name:=value` stays on the parameter server), exits 1 with a FATAL matching PATTERN.
cases=0
exits_fatal() {
  local what=$1 pattern=$2 status
  shift 2
  cases=$((cases + 1))
  set +e
  timeout 120 "$@" __ns:=case$cases > "$ROS_HOME/case$cases.log" 2>&1
  status=$?
  set -e
  [ "$status" -eq 1 ] && grep -q "FATAL.*$pattern" "$ROS_HOME/case$cases.log" ||
    { echo "$(basename "$1") with $what exited with $status:"; cat "$ROS_HOME/case$cases.log"; exit 1; }
}
# image_transport's own parameter, ~image_transport, names a transport that no plugin provides.
exits_fatal "~image_transport nosuch" "~image_transport 'nosuch' cannot be loaded" \
  "$node" _image_transport:=nosuch
# A pipeline setting out of range, one the model cannot take (hypotheses from `fc`, which has no
# latent code) and a diagnostics period that is not a number are configuration errors too.
exits_fatal "~symmetries 3" "symmetries must be 1, 2, 4 or 8" "$node" _symmetries:=3
exits_fatal "~decompose_samples 3 and fc" "simstack_r32_fc.pt: .*decompose_samples" \
  "$node" _model:="$2/models/simstack_r32_fc.pt" _decompose_samples:=3
exits_fatal "~diagnostic_period abc" "diagnostic_period must be a number" \
  "$node" _diagnostic_period:=abc
exits_fatal "~diagnostic_period abc" "diagnostic_period must be a number" \
  "$ROS_SESSION_DEVEL/lib/simstack/grasp_server" _diagnostic_period:=abc
ros_session_spawn "$ROS_HOME/manager.log" rosrun nodelet nodelet manager __name:=manager
timeout 60 bash -c 'until rosnode list 2>/dev/null | grep -q /manager; do sleep 0.3; done' ||
  { echo "the nodelet manager did not come up within 60 s:"; cat "$ROS_HOME/manager.log"; exit 1; }
rosparam set /perception/model "$ROS_HOME/corrupt.pt"
ros_session_spawn "$ROS_HOME/load.log" rosrun nodelet nodelet load simstack/PerceptionNodelet \
  manager __name:=perception --no-bond
for _ in $(seq 120); do grep -q "model refused.*corrupt.pt" "$ROS_HOME/manager.log" && break; sleep 0.5; done
grep -q "ERROR.*model refused.*corrupt.pt" "$ROS_HOME/manager.log" ||
  { echo "the manager did not report the model:"; cat "$ROS_HOME/manager.log"; exit 1; }
# The nodelet reads it from its own namespace (a nodelet's "~" handle is its manager's).
rosparam set /transport/image_transport nosuch
ros_session_spawn "$ROS_HOME/load2.log" rosrun nodelet nodelet load simstack/PerceptionNodelet \
  manager __name:=transport --no-bond
for _ in $(seq 120); do grep -q "FATAL.*~image_transport 'nosuch'" "$ROS_HOME/manager.log" && break; sleep 0.5; done
grep -q "FATAL.*~image_transport 'nosuch' cannot be loaded" "$ROS_HOME/manager.log" ||
  { echo "the nodelet did not read its ~image_transport:"; cat "$ROS_HOME/manager.log"; exit 1; }
# A nodelet that refused its settings says so where a launch file or task code waits for it.
timeout 60 rostopic echo -n 1 /transport/ready | grep -q "data: False" ||
  { echo "the refused nodelet's ~ready is not false"; exit 1; }
timeout 60 /usr/bin/python3 - <<'PY' || { echo "the refused nodelet reports no ERROR on /diagnostics"; exit 1; }
import sys, rospy
from diagnostic_msgs.msg import DiagnosticArray
rospy.init_node("diagnostics_reader", anonymous=True)
while not rospy.is_shutdown():
    for s in rospy.wait_for_message("/diagnostics", DiagnosticArray, timeout=15).status:
        if s.name.startswith("transport") and s.level == 2 and "nosuch" in s.message:
            sys.exit(0)
PY
rosnode ping -c 1 /manager > /dev/null || { echo "the manager died"; cat "$ROS_HOME/manager.log"; exit 1; }
echo "bad models refused (ERROR, ~ready false, no objects), the node and the manager alive; a bad transport or setting exits 1 (a nodelet: ~ready false, ERROR)"
