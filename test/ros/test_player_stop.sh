#!/usr/bin/env bash
# play_when_ready.py stopped as roslaunch stops a node (SIGINT to it alone) or by SIGTERM: the
# rosbag play it started leaves the master too, so that no dead publisher of the bag's topics
# stays registered for the nodes that come after (a live camera's perception on the same
# master).
# Usage: test_player_stop.sh DEVEL_DIR SOURCE_DIR   (the devel space, or a build holding devel/)
set -e
build=$1
export ROS_HOME=$(mktemp -d)  # before the session script, which would make one of its own
# shellcheck disable=SC1091
source "$2/scripts/ros_session.bash" "$build"
set -u
ROS_SESSION_REMOVE_HOME=1
ros_session_start
ros_session_spawn "$ROS_HOME/ready.log" rostopic pub -l /test_ready std_msgs/Bool "data: true"
players() { rosnode list 2>/dev/null | grep '^/play_[0-9]' || true; }
# Stopped by roslaunch (SIGINT) and by a service manager (SIGTERM).
for signal in INT TERM; do
  ros_session_spawn "$ROS_HOME/player_$signal.log" /usr/bin/python3 "$2/scripts/play_when_ready.py" \
    --ready /test_ready --timeout 120 -- --loop "$2/test/data/example_pile.bag"
  player=${ROS_SESSION_PIDS[-1]}
  for _ in $(seq 240); do [ -n "$(players)" ] && break; sleep 0.5; done
  [ -n "$(players)" ] ||
    { echo "FAIL: rosbag play never registered"; cat "$ROS_HOME/player_$signal.log"; exit 1; }
  echo "playing: $(players)"
  kill -"$signal" "$player"
  for _ in $(seq 60); do kill -0 "$player" 2>/dev/null || break; sleep 0.5; done
  if kill -0 "$player" 2>/dev/null; then
    echo "FAIL: play_when_ready still runs 30 s after SIG$signal"; exit 1; fi
  left=$(players)
  if [ -n "$left" ]; then
    echo "FAIL: $left is still registered on the master after SIG$signal stopped play_when_ready"
    exit 1
  fi
  echo "ok: SIG$signal: the bag player left the master with play_when_ready"
done
