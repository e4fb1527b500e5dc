#!/usr/bin/env bash
# roslaunch-check on every launch file of the package (and the rostests): arguments,
# substitutions, packages and node types resolve. Then what the launch files hand the nodes:
# the model each hypotheses setting picks, the arguments grasps.launch passes on, and
# clear_params on every node that loads a config.
# Usage: check_launch_files.sh DEVEL_DIR SOURCE_DIR   (DEVEL_DIR: the devel space, or a build
# holding devel/)
set -e
devel=$1
[ -f "$devel/setup.bash" ] || devel=$1/devel
source_dir=$2
# shellcheck disable=SC1091
source "$devel/setup.bash"
ROS_HOME=$(mktemp -d)
export ROS_HOME
trap 'rm -rf "$ROS_HOME"' EXIT
status=0
for f in "$source_dir"/launch/*.launch "$source_dir"/test/ros/*.test; do
  if out=$(/usr/bin/python3 /usr/share/roslaunch/scripts/roslaunch-check "$f" 2>&1); then
    echo "ok: $f"
  else
    echo "FAILED: $f"; echo "$out"; status=1
  fi
done

# expect LABEL PATTERN COMMAND...: COMMAND's output holds a line matching PATTERN.
expect() {
  local label=$1 pattern=$2
  shift 2
  if "$@" 2>&1 | grep -Eq "$pattern"; then
    echo "ok: $label"
  else
    echo "FAILED: $label: no line matching '$pattern' in the output of: $*"; status=1
  fi
}
# absent LABEL PATTERN COMMAND...: COMMAND succeeds with some output and no line matches PATTERN.
absent() {
  local label=$1 pattern=$2 out
  shift 2
  if ! out=$("$@" 2>&1) || [ -z "$out" ]; then
    echo "FAILED: $label: $* failed or printed nothing"; echo "$out"; status=1
  elif echo "$out" | grep -E "$pattern"; then
    echo "FAILED: $label"; status=1
  else
    echo "ok: $label"
  fi
}
launch=$source_dir/launch
dump() { roslaunch --dump-params "$@"; }
expect "perception.launch: the config's model" 'perception/model: models/simstack_r32_fc.pt$' \
  dump "$launch/perception.launch"
expect "perception.launch decompose_samples:=3: the C-VAE" 'perception/model: .*/simstack_r32.pt$' \
  dump "$launch/perception.launch" decompose_samples:=3
expect "perception.launch decompose_samples:=3 model:=M: M" 'perception/model: /tmp/m.pt$' \
  dump "$launch/perception.launch" decompose_samples:=3 model:=/tmp/m.pt
expect "perception.launch model:=relative: left to the node (the package directory)" \
  'perception/model: models/simstack_r32.pt$' \
  bash -c 'cd /tmp && roslaunch --dump-params "$1" model:=models/simstack_r32.pt' _ "$(cd "$launch" && pwd)/perception.launch"
expect "replay.launch bag:=relative: from roslaunch's directory" ' /tmp/runs/my.bag __name' \
  bash -c 'cd /tmp && roslaunch --args /player "$1" bag:=runs/my.bag' _ "$(cd "$launch" && pwd)/replay.launch"
expect "replay.launch bag:=~/b.bag: from HOME" " $HOME/b.bag __name" \
  roslaunch --args /player "$launch/replay.launch" 'bag:=~/b.bag'
sed 's#^model: .*#model: models/simstack_r32_fc_plain.pt#' "$source_dir/config/perception.yaml" \
  > "$ROS_HOME/own.yaml"
expect "perception.launch decompose_samples:=3 config:=C: C's model" \
  'perception/model: models/simstack_r32_fc_plain.pt$' \
  dump "$launch/perception.launch" decompose_samples:=3 config:="$ROS_HOME/own.yaml"
expect "grasps.launch: 3 hypotheses from the C-VAE" 'perception/model: .*/simstack_r32.pt$' \
  dump "$launch/grasps.launch"
expect "grasps.launch hypotheses:=1: the config's model" 'perception/model: models/simstack_r32_fc.pt$' \
  dump "$launch/grasps.launch" hypotheses:=1
# Another config keeps its own model and decompose_samples: own.yaml's `fc_plain` draws one
# scene, and 3 hypotheses would stop it at start.
expect "grasps.launch config:=C: its model" 'perception/model: models/simstack_r32_fc_plain.pt$' \
  dump "$launch/grasps.launch" config:="$ROS_HOME/own.yaml"
expect "grasps.launch config:=C: the config's decompose_samples (1), not 3" \
  'perception/decompose_samples: 1$' \
  dump "$launch/grasps.launch" config:="$ROS_HOME/own.yaml"
# A model of the user's own keeps the config's decompose_samples: 3 would stop a model without
# a latent code at start.
expect "grasps.launch model:=M leaves decompose_samples to the config (1)" \
  'perception/decompose_samples: 1$' \
  dump "$launch/grasps.launch" model:="$source_dir/models/simstack_r32_fc.pt"
expect "replay.launch decompose_samples:=3: the C-VAE" 'perception/model: .*/simstack_r32.pt$' \
  dump "$launch/replay.launch" decompose_samples:=3
expect "grasps.launch image_transport:=compressedDepth reaches the node" \
  'perception/image_transport: compressedDepth$' dump "$launch/grasps.launch" image_transport:=compressedDepth
expect "replay.launch image_transport:=compressedDepth reaches the node" \
  'perception/image_transport: compressedDepth$' dump "$launch/replay.launch" image_transport:=compressedDepth
expect "grasps.launch accumulate_views:=true reaches the node" 'perception/accumulate_views: true$' \
  dump "$launch/grasps.launch" accumulate_views:=true
expect "grasps.launch output_frame:=base_link reaches the node" 'perception/output_frame: base_link$' \
  dump "$launch/grasps.launch" output_frame:=base_link
# An argument left empty keeps the node config's field; one given overrides it.
sed -e 's#^output_frame: .*#output_frame: base_link#' -e 's#^table_frame: .*#table_frame: bench#' \
  -e 's#^estimate_table: .*#estimate_table: true#' "$source_dir/config/perception_node.yaml" \
  > "$ROS_HOME/node.yaml"
dump "$launch/perception.launch" node_config:="$ROS_HOME/node.yaml" > "$ROS_HOME/node_dump.txt"
for field in "output_frame: base_link" "table_frame: bench" "estimate_table: true"; do
  expect "perception.launch node_config:=N: N's ${field%%:*}" "perception/$field\$" \
    cat "$ROS_HOME/node_dump.txt"
done
expect "perception.launch node_config:=N table_frame:=T: T" 'perception/table_frame: T$' \
  dump "$launch/perception.launch" node_config:="$ROS_HOME/node.yaml" table_frame:=T
expect "grasps.launch node_config:=N reaches the perception" 'perception/output_frame: base_link$' \
  dump "$launch/grasps.launch" node_config:="$ROS_HOME/node.yaml"
expect "replay.launch node_config:=N: N's output_frame" 'perception/output_frame: base_link$' \
  dump "$launch/replay.launch" node_config:="$ROS_HOME/node.yaml"
expect "replay.launch: the bag's table frame over N's" 'perception/table_frame: table$' \
  dump "$launch/replay.launch" node_config:="$ROS_HOME/node.yaml"
expect "replay.launch accumulate_views:=true reaches the node" 'perception/accumulate_views: true$' \
  dump "$launch/replay.launch" accumulate_views:=true
expect "grasps.launch manager:=driver loads into it" 'PerceptionNodelet driver ' \
  roslaunch --args /camera/perception "$launch/grasps.launch" manager:=driver
# One name per setting: no parameter of the perception node lies in a section named after the
# node's own settings or the pipeline's (the names of an older layout: ~perception/symmetries,
# ~node/table_frame).
absent "perception.launch: one name per setting (none under ~perception/ or ~node/)" \
  '^/camera/perception/(perception|node)/' dump "$launch/perception.launch"
# A node that loads a config clears what an earlier launch left in its namespace.
if ! /usr/bin/python3 - "$launch"/*.launch <<'PY'
import sys, xml.etree.ElementTree as ET
bad = [f"{f}: node {n.get('name')}" for f in sys.argv[1:] for n in ET.parse(f).iter("node")
       if any(r.get("command") == "load" for r in n.iter("rosparam")) and n.get("clear_params") != "true"]
print("\n".join(f"FAILED: {b} loads a config without clear_params=\"true\"" for b in bad) or "ok: clear_params")
sys.exit(1 if bad else 0)
PY
then status=1; fi
exit $status
