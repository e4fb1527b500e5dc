# Sourced by scripts/demo and the rviz test: a ROS master of our own on a free port, an Xvfb
# display, and everything started here stopped again on exit, Ctrl-C or failure.
# Usage: source scripts/ros_session.bash BUILD_DIR; ros_session_start; ros_session_xvfb; ...
# BUILD_DIR: a build directory holding devel/, or a devel space itself (a catkin workspace's
# <ws>/devel); ROS_SESSION_DEVEL names the devel space found.
# With ROS_SESSION_REMOVE_HOME=1 the ROS_HOME (logs) is removed at the end too.

ROS_SESSION_DEVEL=$1
[ -f "$ROS_SESSION_DEVEL/setup.bash" ] || ROS_SESSION_DEVEL=$1/devel
# shellcheck disable=SC1091
source "$ROS_SESSION_DEVEL/setup.bash"  # (Debian's ROS profile reads unset variables: no set -u before)
export PATH=/usr/bin:$PATH    # ROS Python tools need the system interpreter, not a pyenv one
export ROS_HOSTNAME=localhost
export ROS_HOME=${ROS_HOME:-$(mktemp -d)}
ROS_SESSION_PIDS=()

ros_session_stop() {  # every process group started here: INT, then TERM, then KILL
  local pid signal
  for signal in INT TERM KILL; do
    for pid in "${ROS_SESSION_PIDS[@]}"; do kill -"$signal" -- -"$pid" 2>/dev/null || true; done
    for _ in $(seq 30); do
      local alive=0
      for pid in "${ROS_SESSION_PIDS[@]}"; do kill -0 -- -"$pid" 2>/dev/null && alive=1; done
      [ $alive -eq 0 ] && break
      sleep 0.5
    done
  done
  ROS_SESSION_PIDS=()
  if [ "${ROS_SESSION_REMOVE_HOME:-0}" = 1 ]; then rm -rf "$ROS_HOME"; fi
}
# Stops one process group started by ros_session_spawn and forgets it.
ros_session_kill() {  # ros_session_kill PID
  local pid=$1 keep=()
  kill -INT -- -"$pid" 2>/dev/null || true
  for _ in $(seq 120); do kill -0 -- -"$pid" 2>/dev/null || break; sleep 0.5; done
  if kill -0 -- -"$pid" 2>/dev/null; then
    echo "process group $pid still ran 60 s after SIGINT: killed" >&2
    kill -KILL -- -"$pid" 2>/dev/null || true
  fi
  for p in "${ROS_SESSION_PIDS[@]}"; do [ "$p" != "$pid" ] && keep+=("$p"); done
  ROS_SESSION_PIDS=("${keep[@]}")
}
trap ros_session_stop EXIT
trap 'exit 130' INT TERM

free_port() {
  /usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("localhost", 0)); print(s.getsockname()[1])'
}

# Runs a command in the background (its own process group) and remembers it for the cleanup.
ros_session_spawn() {  # ros_session_spawn LOG COMMAND...
  local log=$1; shift
  setsid "$@" > "$log" 2>&1 &
  ROS_SESSION_PIDS+=($!)
}

ros_session_start() {  # a master on a free port
  local port
  port=$(free_port)
  export ROS_MASTER_URI=http://localhost:$port
  ros_session_spawn "$ROS_HOME/roscore.log" roscore -p "$port"
  for _ in $(seq 50); do rostopic list > /dev/null 2>&1 && return 0; sleep 0.2; done
  echo "the ROS master did not start (log: $ROS_HOME/roscore.log)" >&2
  return 1
}

ros_session_xvfb() {  # a virtual display for rviz
  local n free=""
  for n in $(seq 90 120); do
    if [ ! -e "/tmp/.X11-unix/X$n" ] && [ ! -e "/tmp/.X$n-lock" ]; then free=$n; break; fi
  done
  [ -n "$free" ] || { echo "no free X display in :90-:120 for Xvfb" >&2; return 1; }
  export DISPLAY=:$free
  ros_session_spawn "$ROS_HOME/xvfb.log" Xvfb "$DISPLAY" -screen 0 1280x800x24
  local xvfb=${ROS_SESSION_PIDS[-1]}
  for _ in $(seq 50); do
    # Ours, not another server's: the display answers while our Xvfb runs.
    kill -0 "$xvfb" 2> /dev/null || break
    xwd -root -silent > /dev/null 2>&1 && return 0
    sleep 0.2
  done
  echo "Xvfb did not start (log: $ROS_HOME/xvfb.log)" >&2
  return 1
}

# Waits until TOPIC carries a message (at most SECONDS).
ros_session_wait_topic() {  # ros_session_wait_topic TOPIC SECONDS
  timeout "$2" rostopic echo -n 1 --noarr "$1" > /dev/null 2>&1
}

# rviz now and then aborts while it starts under software GL (a heap corruption inside rviz
# itself). Prints the launch log's line saying so when it did.
ros_session_rviz_died() {  # ros_session_rviz_died LAUNCH_LOG
  local line
  line=$(grep -m1 "simstack_rviz-[0-9]*\] process has died" "$1") || return 1
  printf '%s\n' "$line" | sed 's/\x1b\[[0-9;]*m//g'  # without roslaunch's colours
}

ros_session_screenshot() {  # ros_session_screenshot FILE.png
  xwd -root -silent | convert xwd:- "$1"
}
