#!/usr/bin/env bash
# rviz with config/simstack.rviz under Xvfb, on the example bag replayed into the perception
# nodelet: the screenshot must show the superquadric markers (pixels in the objects' colours).
# Usage: test_rviz_screenshot.sh DEVEL_DIR SOURCE_DIR   (the devel space, or a build holding devel/)
set -e
source_dir=$2
export ROS_HOME=$(mktemp -d)  # before the session script, which would make one of its own
# shellcheck disable=SC1091
source "$source_dir/scripts/ros_session.bash" "$1"
set -u
ROS_SESSION_REMOVE_HOME=1
ros_session_start
ros_session_xvfb
# Played once: after the last frame its markers stay in rviz (a looping bag makes rviz reset
# whenever simulated time jumps back). An rviz that aborts (rviz's own fault while it starts, see
# ros_session_rviz_died) gets the whole replay again, at most three times, each one reported.
replay() {  # starts the replay; false when no markers come
  ros_session_spawn "$ROS_HOME/replay.log" roslaunch simstack replay.launch rviz:=true
  launch=${ROS_SESSION_PIDS[-1]}
  if ! ros_session_wait_topic /camera/perception/markers 120; then
    echo "no markers within 120 s"; tail -30 "$ROS_HOME/replay.log"; return 1
  fi
  sleep 12  # the rest of the bag; rviz draws with software GL
}
shot=$ROS_HOME/rviz.png
check() {
/usr/bin/python3 - "$shot" <<'PY'
import sys
import matplotlib.image as mpimg
import numpy as np
img = mpimg.imread(sys.argv[1])
if img.ndim != 3:
    sys.exit("the screenshot has no colour at all: no rviz window on the display")
img = img[:, :, :3]
if img.dtype != np.float32:
    img = img.astype(np.float32) / 255.0
# The render area (right of the panels); the objects' colours (io/image_io.cpp instanceColour)
# lit by rviz's light: a pixel counts when its hue and saturation are those of a colour.
view = img[60:760, 370:1270]
r, g, b = view[..., 0], view[..., 1], view[..., 2]
mx, mn = view.max(axis=2), view.min(axis=2)
sat = np.where(mx > 0, (mx - mn) / np.maximum(mx, 1e-6), 0)
hue = np.zeros_like(mx)
d = np.maximum(mx - mn, 1e-6)
hue = np.where(mx == r, ((g - b) / d) % 6, hue)
hue = np.where(mx == g, (b - r) / d + 2, hue)
hue = np.where(mx == b, (r - g) / d + 4, hue)
hue *= 60
colours = {"object 1 (red)": 6.6, "object 2 (blue)": 213.0, "object 3 (green)": 120.0}
found = {}
for name, h in colours.items():
    near = np.minimum(np.abs(hue - h), 360 - np.abs(hue - h)) < 12
    found[name] = int(np.count_nonzero(near & (sat > 0.35) & (mx > 0.2)))
print("pixels per object colour:", found)
ok = sum(n > 300 for n in found.values())
sys.exit(0 if ok >= 2 else 1)
PY
}
for replay_attempt in 1 2 3; do
  replay
  for _ in $(seq 20); do  # software GL under load may take a while to draw
    if died=$(ros_session_rviz_died "$ROS_HOME/replay.log"); then break; fi
    ros_session_screenshot "$shot"
    if check; then echo "rviz shows the markers"; exit 0; fi
    sleep 3
  done
  if [ -z "${died:-}" ]; then
    echo "rviz did not show the markers in 20 screenshots"; tail -20 "$ROS_HOME/replay.log"; exit 1
  fi
  echo "rviz aborted in replay $replay_attempt: $died"
  ros_session_kill "$launch"
  died=""
done
echo "rviz aborted in three replays"; exit 1
