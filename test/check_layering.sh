#!/usr/bin/env bash
# Fails when a folder includes what its layer must not (CMakeLists.txt; docs/design.md,
# section 2): the runtime (src/core, include/simstack and the runtime's tools) includes a ROS
# header; the runtime or the ROS shell includes offline code (src/offline,
# include/simstack/offline); a file outside
# the model and the trainer includes libtorch; a low-level module of the runtime includes the
# model or the pipeline.
set -u
root=${1:-$(dirname "$0")/..}
fail=0
report() {  # report "what" "hits"
  if [ -n "$2" ]; then echo "$1:"; echo "$2"; fail=1; fi
}
# The ROS packages of package.xml, and the package's own generated messages (simstack/Name.h).
ros='(ros|nodelet|pluginlib|image_transport|image_geometry|std_msgs|std_srvs|geometry_msgs'
ros+='|sensor_msgs|visualization_msgs|shape_msgs|actionlib|actionlib_msgs|tf2|tf2_ros|tf2_eigen'
ros+='|tf2_msgs|diagnostic_updater|diagnostic_msgs|dynamic_reconfigure|rosbag|xmlrpcpp|cv_bridge'
ros+='|message_filters|pcl_conversions|pcl_ros|tf|eigen_conversions|octomap_msgs|nav_msgs)/'
ros+='|XmlRpc|simstack/[A-Z]'
inc='^[[:space:]]*#[[:space:]]*include[[:space:]]*[<"]'
# The runtime's command-line tools link simstack_core alone (CMakeLists.txt).
runtime_tools=("$root/src/tools/simstack_rank_grasps.cpp" "$root/src/tools/simstack_check_model.cpp"
  "$root/src/tools/perception_options.cpp" "$root/src/tools/perception_options.h"
  "$root/src/tools/depth_files.cpp" "$root/src/tools/depth_files.h" "$root/src/tools/cli_checks.h"
  "$root/src/tools/progress.h" "$root/src/tools/sensor_option.h")
for f in "${runtime_tools[@]}"; do  # a renamed tool must not drop out of the check unseen
  [ -f "$f" ] || report "A runtime tool this check names is missing" "$f"
done
# Nor a renamed folder (grep's errors go unseen below).
for d in src/core src/offline src/ros src/tools include/simstack include/simstack/offline \
         include/simstack_ros src/core/model src/core/pipeline src/offline/training; do
  [ -d "$root/$d" ] || report "A folder this check reads is missing" "$root/$d"
done
# Each pattern finds what it should where it is allowed (a pattern that matches nothing, or
# that grep cannot read, would pass every check below).
grep -rqE "${inc}simstack/model/" "$root/src/core/pipeline" ||
  report "The include pattern finds nothing" "no simstack/model/ include in src/core/pipeline"
grep -rqE "$inc($ros)" "$root/src/ros" ||
  report "The ROS pattern finds nothing" "no ROS include in src/ros"
grep -rqE "$inc(simstack/offline/|(\\.\\./)+offline/)" "$root/src/offline" ||
  report "The offline pattern finds nothing" "no offline include in src/offline"
grep -rqE "$inc(torch/|ATen/|c10/)" "$root/src/core/model" ||
  report "The libtorch pattern finds nothing" "no libtorch include in src/core/model"
report "The ROS-free runtime includes ROS headers" "$(grep -rnE "$inc($ros)" \
  "$root/src/core" "$root/src/offline" "$root/include/simstack" "${runtime_tools[@]}" 2>/dev/null)"
# simstack_make_bag is an offline tool that writes a bag (it generates piles), not a node.
report "The runtime or the ROS shell includes offline code" "$(grep -rnE \
  "$inc(simstack/offline/|(\\.\\./)+offline/)" "$root/src/core" "$root/include/simstack" \
  "$root/src/ros" "$root/include/simstack_ros" "${runtime_tools[@]}" 2>/dev/null |
  grep -v -e '/include/simstack/offline/' -e '/src/ros/make_example_bag.cpp:')"
report "libtorch outside the model and the trainer" "$(grep -rnE "$inc(torch/|ATen/|c10/)" \
  "$root/src" "$root/include" 2>/dev/null | grep -v -e '/src/core/model/' \
  -e '/include/simstack/model/' -e '/src/offline/training/' -e '/include/simstack/offline/training/')"
report "a low-level runtime module includes the model or the pipeline" "$(grep -rnE \
  "$inc"'simstack/(model|pipeline)/' "$root/src/core" "$root/include/simstack" 2>/dev/null |
  grep -v -e '/core/model/' -e '/core/pipeline/' -e '/simstack/model/' -e '/simstack/pipeline/' \
    -e '/include/simstack/offline/')"
[ $fail -eq 0 ] && echo "layers ok: $(find "$root/src" "$root/include" -name '*.cpp' -o -name '*.h' | wc -l) files checked"
exit $fail
