#!/usr/bin/env bash
# End-to-end check of simstack_rank_grasps on a two-box stack written as simstack_reconstruct
# writes scenes: the table, grasps.json and grasps.png, the best grasp lifting the top box
# straight up, the settings file and the options over it, and clear errors (non-zero exit) for
# an unknown id and bad files.
set -eu
rank=$1
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
cat > "$dir/stack.yaml" <<'YAML'
frame: table
objects:
  - {id: 0, scale: [0.03, 0.03, 0.06], exponents: [20, 20, 20], position: [0, 0, 0.06], orientation: [1, 0, 0, 0]}
  - {id: 7, scale: [0.06, 0.06, 0.03], exponents: [20, 20, 20], position: [0, 0, 0.1505], orientation: [1, 0, 0, 0]}
YAML
"$rank" --scene "$dir/stack.yaml" --target 7 --candidates 16 --pregrasp-distance 0.08 --output "$dir/out" > "$dir/log.txt"
cat "$dir/log.txt"
grep -q "16 grasps ranked" "$dir/log.txt"
grep -q "no measured cloud" "$dir/log.txt"  # none beside the scene: said, not silent
test -s "$dir/out/grasps.png"
/usr/bin/python3 - "$dir/out/grasps.json" <<'PY'
import json, sys
doc = json.load(open(sys.argv[1]))
assert doc["target_id"] == 7 and len(doc["grasps"]) == 16, doc["target_id"]
best = doc["grasps"][0]
assert best["approach"][2] > 0.9, best["approach"]          # straight up
assert best["failed_share"] == 0 and best["freed_share"] == 1, best
assert all(g["failed_share"] >= best["failed_share"] for g in doc["grasps"])
assert best["held"] and best["freed"], best
# The tool pose: at the contact, z into the surface (the best lifts straight up: z down); the
# pre-grasp 8 cm back along the approach.
x, y, z, qw, qx, qy, qz = best["tool_pose"]
assert [x, y, z] == best["contact_m"], best
tool_z = (2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx), 1 - 2 * (qx * qx + qy * qy))
assert sum(a * b for a, b in zip(tool_z, best["approach"])) < -0.999, tool_z
pre = best["pregrasp_pose"]
assert all(abs(pre[i] - (best["contact_m"][i] + 0.08 * best["approach"][i])) < 1e-9 for i in range(3)), pre
assert pre[3:] == best["tool_pose"][3:], pre
PY
expect_error() {  # expect_error WORDS ARGS...: non-zero exit and WORDS in the message
  local words=$1; shift
  if "$rank" "$@" > /dev/null 2> "$dir/err"; then echo "accepted: $*"; exit 1; fi
  grep -q -- "$words" "$dir/err" || { echo "expected '$words':"; cat "$dir/err"; exit 1; }
}
expect_error "no object with id 3" --scene "$dir/stack.yaml" --target 3
echo "objects: [1, 2" > "$dir/broken.yaml"
expect_error "broken.yaml" --scene "$dir/broken.yaml" --target 0
sed 's/0.03, 0.03, 0.06/.nan, 0.03, 0.06/' "$dir/stack.yaml" > "$dir/nan.yaml"
expect_error "nan.yaml" --scene "$dir/nan.yaml" --target 7
sed 's/exponents: \[20, 20, 20\], position: \[0, 0, 0.06\]/exponents: [0.5, 20, 20], position: [0, 0, 0.06]/' \
  "$dir/stack.yaml" > "$dir/low.yaml"
expect_error "exponents" --scene "$dir/low.yaml" --target 7
# An object beyond a workcell's reach (Embree refuses rays from 1e30 m) is named, not simulated.
sed 's/position: \[0, 0, 0.06\]/position: [1e30, 0, 0.06]/' "$dir/stack.yaml" > "$dir/far.yaml"
expect_error "m from the table's origin" --scene "$dir/far.yaml" --target 7
expect_error "nope.yaml" --scene "$dir/nope.yaml" --target 0
expect_error "pull-distance" --scene "$dir/stack.yaml" --target 7 --pull-distance 0
# CLI11's ranges let nan through: the option is named, not the scene file.
expect_error "--pull-distance: 'nan' is not a finite number" --scene "$dir/stack.yaml" --target 7 \
  --pull-distance nan
# The settings come from config/grasps.yaml, or the file --config names (the server's own keys
# passed over), and the options given
# override it: a seal that breaks at 0.5 N drops the top box (1.7 N) in every pull, unless
# --max-force says otherwise; perturbed copies from the file show in the outcome.
printf 'objects_topic: perception/objects\ndiagnostic_period: 2\nrank_grasps_action: rank\nactionlib_status_frequency: 5\nmax_force_n: 0.5\nperturbed_copies: 2\n' > "$dir/weak.yaml"
"$rank" --scene "$dir/stack.yaml" --target 7 --candidates 8 --config "$dir/weak.yaml" --output "$dir/weak" > /dev/null
"$rank" --scene "$dir/stack.yaml" --target 7 --candidates 8 --config "$dir/weak.yaml" --max-force 30 \
  --output "$dir/strong" > /dev/null
/usr/bin/python3 - "$dir/weak/grasps.json" "$dir/strong/grasps.json" "$dir/out/grasps.json" <<'PY'
import json, sys
weak, strong, default = (json.load(open(p))["grasps"] for p in sys.argv[1:])
assert all(g["failed_share"] == 1 for g in weak), [g["failed_share"] for g in weak]
assert strong[0]["failed_share"] == 0, strong[0]  # held in the pile and in both copies
assert all(g["perturbed_held_share"] is not None for g in weak + strong), weak[0]
assert all(g["perturbed_held_share"] is None for g in default), default[0]  # the shipped file: none
PY
printf 'max_force: 0.5\n' > "$dir/misspelt.yaml"
expect_error "unknown key 'max_force'" --scene "$dir/stack.yaml" --target 7 --config "$dir/misspelt.yaml"
printf 'surface_samples: 2.5\n' > "$dir/typed.yaml"
expect_error "typed.yaml: surface_samples" --scene "$dir/stack.yaml" --target 7 --config "$dir/typed.yaml"
sed 's/id: 7/id: -1/' "$dir/stack.yaml" > "$dir/negative.yaml"
expect_error "ids are 0 or more" --scene "$dir/negative.yaml" --target -1
# Measured points labelled 8 (id 7 + 1): on the top box's upper face, they judge its seals; a
# metre away (another scene's cloud), they are refused.
/usr/bin/python3 - "$dir" <<'PY'
import sys
def cloud(path, dx):
    pts = [(dx + 0.005 * i, 0.005 * j, 0.1805, 8) for i in range(-10, 11) for j in range(-10, 11)]
    with open(path, "w") as f:
        f.write("VERSION 0.7\nFIELDS x y z label\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\n")
        f.write("WIDTH %d\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS %d\nDATA ascii\n" % (len(pts), len(pts)))
        f.writelines("%g %g %g %d\n" % p for p in pts)
cloud(sys.argv[1] + "/on_top.pcd", 0.0)
cloud(sys.argv[1] + "/elsewhere.pcd", 1.0)
PY
"$rank" --scene "$dir/stack.yaml" --target 7 --candidates 8 --measured "$dir/on_top.pcd" > "$dir/measured.txt"
grep -q "seals judged on 441 points of object 7" "$dir/measured.txt"
expect_error "is it this scene's cloud" --scene "$dir/stack.yaml" --target 7 --measured "$dir/elsewhere.pcd"
echo "tool_rank_grasps ok"
