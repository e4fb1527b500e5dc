#!/usr/bin/env bash
# Fails when a module includes what its layer must not (the libraries follow the folders;
# CMakeLists.txt): the ROS-free core includes a ROS header; a file outside src/core/model
# includes libtorch; a module of simstack_core includes the model or the pipeline; the
# inference path (the pipeline and CvaeInference) includes training code.
set -u
root=${1:-$(dirname "$0")/..}
fail=0
report() {  # report "what" "hits"
  if [ -n "$2" ]; then echo "$1:"; echo "$2"; fail=1; fi
}
report "The ROS-free core includes ROS headers" "$(grep -rnE \
  '#include *[<"](ros/|nodelet/|sensor_msgs/|std_msgs/|geometry_msgs/|visualization_msgs/|tf2_ros/|tf2_msgs/|image_transport/|cv_bridge/|pluginlib/|message_filters/|rosbag/|pcl_conversions/|pcl_ros/)' \
  "$root/src/core" "$root/include/simstack" 2>/dev/null)"
report "libtorch outside src/core/model" "$(grep -rnE '#include *[<"](torch/|ATen/)' \
  "$root/src" "$root/include" 2>/dev/null | grep -v -e '/src/core/model/' -e '/include/simstack/model/')"
report "simstack_core includes the model or the pipeline" "$(grep -rnE \
  '#include *"simstack/(model|pipeline)/' "$root/src/core" "$root/include/simstack" 2>/dev/null |
  grep -v -e '/core/model/' -e '/core/pipeline/' -e '/simstack/model/' -e '/simstack/pipeline/')"
report "the inference path includes training code" "$(grep -rnE \
  '#include *"simstack/model/(cvae_trainer|training_sample)\.h"' "$root/src/core/pipeline" \
  "$root/include/simstack/pipeline" "$root/src/core/model/cvae_inference.cpp" \
  "$root/include/simstack/model/cvae_inference.h" 2>/dev/null)"
[ $fail -eq 0 ] && echo "layers ok: $(find "$root/src" "$root/include" -name '*.cpp' -o -name '*.h' | wc -l) files checked"
exit $fail
