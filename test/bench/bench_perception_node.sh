#!/usr/bin/env bash
# The perception node under load (640x480 depth at 30 Hz for 60 s): answers per second,
# latency from image stamp to ~objects (median, 95th percentile), frames not answered (dropped
# by the one-slot mailbox) and the node's resident memory at 10 s and at the end; once on idle
# cores and once beside one busy process (the camera driver and the planner of a workcell), with
# OpenMP's passive wait policy (the node's default) and with spinning workers.
# Usage: bench_perception_node.sh BUILD_DIR [SECONDS]
set -eo pipefail
build=$1
seconds=${2:-60}
root=$(cd "$(dirname "$0")/../.." && pwd)
export ROS_HOME=$(mktemp -d)  # before the session script, which would make one of its own
# shellcheck disable=SC1091
source "$root/scripts/ros_session.bash" "$build"
set -u
ROS_SESSION_REMOVE_HOME=1
ros_session_start
results=()
for case in idle busy_passive busy_spinning; do
  policy=passive
  [ "$case" = busy_spinning ] && policy=active
  rosparam delete /camera/perception > /dev/null 2>&1 || true
  rosparam load "$root/config/perception.yaml" /camera/perception
  OMP_WAIT_POLICY=$policy ros_session_spawn "$ROS_HOME/node_$case.log" \
    "$build/devel/lib/simstack/perception_node" __ns:=camera __name:=perception
  node_pid=${ROS_SESSION_PIDS[-1]}
  # Ready (latched true) once warmed up and subscribed: no frame of the window is lost to start-up.
  ready=$(timeout 120 rostopic echo -n 1 /camera/perception/ready 2>/dev/null || true)
  [[ $ready == *"data: True"* ]] \
    || { echo "the perception node did not report ready within 120 s (log: $ROS_HOME/node_$case.log)" >&2; exit 1; }
  busy_pid=
  if [ "$case" != idle ]; then
    # A busy loop that stops on SIGINT (a background job starts with SIGINT ignored).
    ros_session_spawn /dev/null perl -e '$SIG{INT} = "DEFAULT"; 1 while 1'
    busy_pid=${ROS_SESSION_PIDS[-1]}
  fi
  line=$("$build/devel/lib/simstack/bench_node_driver" --pid "$node_pid" --label "$case" \
           --seconds "$seconds" --early "$(( seconds < 20 ? seconds / 2 : 10 ))" | tail -1)
  echo "$line"
  results+=("$line")
  if [ -n "$busy_pid" ]; then ros_session_kill "$busy_pid"; fi
  ros_session_kill "$node_pid"
done
/usr/bin/python3 - "${results[@]}" <<'PY'
import json, sys
r = {d["case"]: d for d in map(json.loads, sys.argv[1:])}
print("\n== perception node, 640x480 depth at 30 Hz (same run)")
for name, d in r.items():
    growth = 100 * (d["rss_end_mb"] / d["rss_early_mb"] - 1) if d["rss_early_mb"] > 0 else float("nan")
    print(f"{name}: {d['answers_per_s']:.1f} frames/s answered, latency median {d['latency_median_ms']:.0f} ms, "
          f"p95 {d['latency_p95_ms']:.0f} ms, {d['not_answered']} of {d['sent']} frames not answered, "
          f"RSS {d['rss_early_mb']:.0f} -> {d['rss_end_mb']:.0f} MB ({growth:+.1f} %)")
idle = r.get("idle")
for name in ("busy_passive", "busy_spinning"):
    if idle and name in r:
        print(f"{name} / idle: {r[name]['latency_median_ms'] / idle['latency_median_ms']:.2f}x median latency, "
              f"{idle['answers_per_s'] / max(r[name]['answers_per_s'], 1e-9):.2f}x fewer frames per second")
PY
