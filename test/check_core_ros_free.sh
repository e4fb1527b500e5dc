#!/usr/bin/env bash
# Fails when the ROS-free core (src/core, include/simstack) includes a ROS header.
set -u
root=${1:-$(dirname "$0")/..}
hits=$(grep -rnE '#include *[<"](ros/|nodelet/|sensor_msgs/|std_msgs/|geometry_msgs/|visualization_msgs/|tf2_ros/|tf2_msgs/|image_transport/|cv_bridge/|pluginlib/|message_filters/|rosbag/|pcl_conversions/|pcl_ros/)' \
  "$root/src/core" "$root/include/simstack" 2>/dev/null)
if [ -n "$hits" ]; then
  echo "The ROS-free core includes ROS headers:"
  echo "$hits"
  exit 1
fi
echo "core is ROS-free: $(find "$root/src/core" "$root/include/simstack" -name '*.cpp' -o -name '*.h' | wc -l) files checked"
