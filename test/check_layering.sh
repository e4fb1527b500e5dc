#!/usr/bin/env bash
# Fails when a folder includes what its layer must not (CMakeLists.txt; docs/design.md,
# section 2): the runtime (src/core, include/simstack) includes a ROS header; the runtime or
# the ROS shell includes offline code (src/offline, include/simstack/offline); a file outside
# the model and the trainer includes libtorch; a low-level module of the runtime includes the
# model or the pipeline.
set -u
root=${1:-$(dirname "$0")/..}
fail=0
report() {  # report "what" "hits"
  if [ -n "$2" ]; then echo "$1:"; echo "$2"; fail=1; fi
}
report "The ROS-free runtime includes ROS headers" "$(grep -rnE \
  '#include *[<"](ros/|nodelet/|sensor_msgs/|std_msgs/|geometry_msgs/|visualization_msgs/|tf2_ros/|tf2_msgs/|image_transport/|cv_bridge/|pluginlib/|message_filters/|rosbag/|pcl_conversions/|pcl_ros/)' \
  "$root/src/core" "$root/src/offline" "$root/include/simstack" 2>/dev/null)"
# simstack_make_bag is an offline tool that writes a bag (it generates piles), not a node.
report "The runtime or the ROS shell includes offline code" "$(grep -rnE \
  '#include *"simstack/offline/' "$root/src/core" "$root/include/simstack" "$root/src/ros" \
  "$root/include/simstack_ros" 2>/dev/null |
  grep -v -e '/include/simstack/offline/' -e '/src/ros/make_example_bag.cpp:')"
report "libtorch outside the model and the trainer" "$(grep -rnE '#include *[<"](torch/|ATen/)' \
  "$root/src" "$root/include" 2>/dev/null | grep -v -e '/src/core/model/' \
  -e '/include/simstack/model/' -e '/src/offline/training/' -e '/include/simstack/offline/training/')"
report "a low-level runtime module includes the model or the pipeline" "$(grep -rnE \
  '#include *"simstack/(model|pipeline)/' "$root/src/core" "$root/include/simstack" 2>/dev/null |
  grep -v -e '/core/model/' -e '/core/pipeline/' -e '/simstack/model/' -e '/simstack/pipeline/' \
    -e '/include/simstack/offline/')"
[ $fail -eq 0 ] && echo "layers ok: $(find "$root/src" "$root/include" -name '*.cpp' -o -name '*.h' | wc -l) files checked"
exit $fail
