#!/usr/bin/env bash
# A missing or corrupt model, or a ~image_transport no plugin provides, at start: perception_node
# exits non-zero with a ROS_FATAL that names it (no crash); the nodelet reports it and its manager
# keeps running.
# Usage: test_bad_model.sh BUILD_DIR SOURCE_DIR
set -e
build=$1
export ROS_HOME=$(mktemp -d)  # before the session script, which would make one of its own
# shellcheck disable=SC1091
source "$2/scripts/ros_session.bash" "$build"
set -u
ROS_SESSION_REMOVE_HOME=1
ros_session_start
node="$build/devel/lib/simstack/perception_node"
echo "not a model" > "$ROS_HOME/corrupt.pt"
for model in "$ROS_HOME/missing.pt" "$ROS_HOME/corrupt.pt"; do
  set +e
  timeout 60 "$node" __ns:=bad _perception/model:="$model" > "$ROS_HOME/node.log" 2>&1
  status=$?
  set -e
  if [ "$status" -ne 1 ]; then
    echo "perception_node with $model exited with $status, not 1"; cat "$ROS_HOME/node.log"; exit 1
  fi
  grep -q "FATAL.*$(basename "$model")" "$ROS_HOME/node.log" ||
    { echo "no FATAL naming $model:"; cat "$ROS_HOME/node.log"; exit 1; }
done
# image_transport's own parameter, ~image_transport, names a transport that no plugin provides.
set +e
timeout 60 "$node" __ns:=bad _perception/model:="$2/models/simstack_r32_fc.pt" \
  _image_transport:=nosuch > "$ROS_HOME/node.log" 2>&1
status=$?
set -e
[ "$status" -eq 1 ] && grep -q "FATAL.*~image_transport 'nosuch' cannot be loaded" "$ROS_HOME/node.log" ||
  { echo "perception_node with ~image_transport nosuch exited with $status:"; cat "$ROS_HOME/node.log"; exit 1; }
ros_session_spawn "$ROS_HOME/manager.log" rosrun nodelet nodelet manager __name:=manager
timeout 30 bash -c 'until rosnode list 2>/dev/null | grep -q /manager; do sleep 0.3; done'
rosparam set /perception/perception/model "$ROS_HOME/corrupt.pt"
ros_session_spawn "$ROS_HOME/load.log" rosrun nodelet nodelet load simstack/PerceptionNodelet \
  manager __name:=perception --no-bond
for _ in $(seq 120); do grep -q "FATAL.*corrupt.pt" "$ROS_HOME/manager.log" && break; sleep 0.5; done
grep -q "FATAL.*corrupt.pt" "$ROS_HOME/manager.log" ||
  { echo "the manager did not report the model:"; cat "$ROS_HOME/manager.log"; exit 1; }
# The nodelet reads it from its own namespace (a nodelet's "~" handle is its manager's).
rosparam set /transport/perception/model "$2/models/simstack_r32_fc.pt"
rosparam set /transport/image_transport nosuch
ros_session_spawn "$ROS_HOME/load2.log" rosrun nodelet nodelet load simstack/PerceptionNodelet \
  manager __name:=transport --no-bond
for _ in $(seq 120); do grep -q "FATAL.*~image_transport 'nosuch'" "$ROS_HOME/manager.log" && break; sleep 0.5; done
grep -q "FATAL.*~image_transport 'nosuch' cannot be loaded" "$ROS_HOME/manager.log" ||
  { echo "the nodelet did not read its ~image_transport:"; cat "$ROS_HOME/manager.log"; exit 1; }
rosnode ping -c 1 /manager > /dev/null || { echo "the manager died"; cat "$ROS_HOME/manager.log"; exit 1; }
echo "bad models and transports refused: node exits 1, nodelet reports and its manager lives"
