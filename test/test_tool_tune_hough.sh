#!/usr/bin/env bash
# End-to-end check of simstack_tune_hough on a few generated piles: the chosen setting comes
# from the values tried (or is the config's own), scores at least as well as the config's own
# setting, is written as a model card's perception: section, and bad input is refused.
set -euo pipefail
generate=$1
tune=$2
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
"$generate" --scenes 3 --seed 9 --output "$dir/val.h5" > /dev/null
"$tune" --dataset "$dir/val.h5" --views 1 --threads 1 --refinement 5 --min-traversals 2 3 \
  --bandwidth 0.04 0.05 --min-instance-voxels 10 --min-vote-norm 0 --output "$dir/tuned.yaml" \
  > "$dir/log.txt" 2> "$dir/err.txt" || { echo "simstack_tune_hough failed:"; cat "$dir/err.txt"; exit 1; }
grep -q "chosen setting written" "$dir/log.txt" || { cat "$dir/log.txt"; exit 1; }
# First table row (the chosen one) and the config's own row: count exact is column 8.
chosen=$(grep -m1 '^| [0-9]' "$dir/log.txt" | awk -F'|' '{print $8}' | tr -d ' %')
own=$(tail -n 4 "$dir/log.txt" | grep '^| [0-9]' | awk -F'|' '{print $8}' | tr -d ' %')
[ -n "$chosen" ] && [ -n "$own" ] || { echo "no table rows parsed"; cat "$dir/log.txt"; exit 1; }
awk -v a="$chosen" -v b="$own" 'BEGIN { exit !(a >= b) }' ||
  { echo "chosen setting ($chosen %) is worse than the config's ($own %)"; cat "$dir/log.txt"; exit 1; }
/usr/bin/python3 -c "import yaml" || { echo "python3-yaml is missing (scripts/setup installs it)"; exit 1; }
  /usr/bin/python3 - "$dir/tuned.yaml" "$(dirname "$0")/../models/simstack_r32_fc.yaml" <<'PY'
import sys, yaml
c = yaml.safe_load(open(sys.argv[1]))
assert set(c) == {"perception"}, c.keys()
p = c["perception"]
h = p["hough"]
o = yaml.safe_load(open(sys.argv[2]))["perception"]["hough"]
key = lambda x: (x["refinement"], x["min_traversals"], x["bandwidth_m"], x["min_instance_voxels"])
tried = (h["refinement"] == 5 and h["min_traversals"] in (2, 3) and h["bandwidth_m"] in (0.04, 0.05)
         and h["min_instance_voxels"] == 10 and h["min_vote_norm"] == 0)
own = key(h) == key(o)
assert tried or own, h
assert p["samples"] == 1, p  # the default model, `fc`, has no latent code
PY
# --apply puts the chosen section into the model's card in place of its own, every other
# section kept; a model without a card gets one holding only that section.
models=$(dirname "$0")/../models
cp "$models/simstack_r32_fc.pt" "$dir/m.pt"
cp "$models/simstack_r32_fc.yaml" "$dir/m.yaml"
cp "$models/simstack_r32_fc.pt" "$dir/bare.pt"
for m in m bare; do
  "$tune" --model "$dir/$m.pt" --dataset "$dir/val.h5" --views 1 --threads 1 --refinement 5 \
    --min-traversals 2 --bandwidth 0.04 --min-instance-voxels 10 --min-vote-norm 0 --apply \
    --output "$dir/$m.tuned.yaml" > "$dir/$m.log" 2> "$dir/err.txt" ||
    { echo "simstack_tune_hough --apply failed:"; cat "$dir/err.txt"; exit 1; }
  grep -q "and put into the card $dir/$m.yaml" "$dir/$m.log" || { cat "$dir/$m.log"; exit 1; }
done
/usr/bin/python3 - "$dir" "$models/simstack_r32_fc.yaml" <<'PY'
import sys, yaml
d, shipped = sys.argv[1], yaml.safe_load(open(sys.argv[2]))
for m in ("m", "bare"):
    card = yaml.safe_load(open(f"{d}/{m}.yaml"))
    tuned = yaml.safe_load(open(f"{d}/{m}.tuned.yaml"))
    assert card["perception"] == tuned["perception"], (card["perception"], tuned["perception"])
    assert card["perception"]["hough"]["refinement"] in (5, shipped["perception"]["hough"]["refinement"])
    others = {k: v for k, v in card.items() if k != "perception"}
    expected = {k: v for k, v in shipped.items() if k != "perception"} if m == "m" else {}
    assert others == expected, (m, sorted(others), sorted(expected))
PY
# A CRLF card with a column-0 comment and a blank line inside its section: the section is
# replaced whole and the next one kept. A card whose text the splice would change elsewhere (a
# quoted string holding "perception:" at column 0) is refused and left as it was; --apply
# without --model (it would rewrite the shipped card) is an argument error.
cp "$models/simstack_r32_fc.pt" "$dir/odd.pt"
printf 'model:\r\n  note: 1\r\nperception:\r\n  samples: 1\r\n\r\n# inside\r\n  hough:\r\n    refinement: 8\r\n\r\n# above\r\nevaluation:\r\n  x: 1\r\n' > "$dir/odd.yaml"
cp "$models/simstack_r32_fc.pt" "$dir/quoted.pt"
printf 'model:\n  note: "a note that\nperception: says it"\nperception:\n  samples: 1\n' > "$dir/quoted.yaml"
cp "$dir/quoted.yaml" "$dir/quoted.orig"
tune_apply() {
  "$tune" --model "$dir/$1.pt" --dataset "$dir/val.h5" --views 1 --threads 1 --refinement 5 \
    --min-traversals 2 --bandwidth 0.04 --min-instance-voxels 10 --min-vote-norm 0 --apply \
    --output "$dir/$1.tuned.yaml" > "$dir/$1.log" 2>&1
}
tune_apply odd || { echo "--apply failed on a CRLF card:"; cat "$dir/odd.log"; exit 1; }
/usr/bin/python3 - "$dir" <<'PY'
import sys, yaml
d = sys.argv[1]
card, tuned = yaml.safe_load(open(f"{d}/odd.yaml")), yaml.safe_load(open(f"{d}/odd.tuned.yaml"))
assert card == {"model": {"note": 1}, "perception": tuned["perception"], "evaluation": {"x": 1}}, card
PY
if tune_apply quoted; then echo "--apply spliced a card it could not splice safely"; exit 1; fi
grep -q "without changing the rest of it" "$dir/quoted.log" || { cat "$dir/quoted.log"; exit 1; }
grep -q "the model's setting (defaults: .*quoted.yaml has no hough:)" "$dir/quoted.log" ||
  { echo "a card without hough: was taken for the model's setting"; cat "$dir/quoted.log"; exit 1; }
cmp -s "$dir/quoted.yaml" "$dir/quoted.orig" || { echo "the refused card was changed"; exit 1; }
if "$tune" --dataset "$dir/val.h5" --apply --output "$dir/x.yaml" 2> "$dir/e0"; then
  echo "--apply without --model was accepted"; exit 1; fi
grep -q "apply needs --model" "$dir/e0" || { cat "$dir/e0"; exit 1; }
# Several validation sets pool their views and each is scored on its own.
"$generate" --scenes 2 --seed 10 --objects 5:6 --sizes 0.05:0.15 --output "$dir/val58.h5" > /dev/null
"$tune" --dataset "$dir/val.h5" --dataset "$dir/val58.h5" --views 1 --threads 1 --refinement 5 \
  --min-traversals 3 --bandwidth 0.03 0.05 --min-instance-voxels 10 --min-vote-norm 0 \
  --output "$dir/pooled.yaml" > "$dir/pooled.txt" 2> "$dir/err.txt" || { echo "simstack_tune_hough failed:"; cat "$dir/err.txt"; exit 1; }
grep -q "^5 views, model" "$dir/pooled.txt" || { echo "views not pooled"; cat "$dir/pooled.txt"; exit 1; }
grep -q "/val.h5 (3 views): " "$dir/pooled.txt" || { echo "no per-dataset line"; cat "$dir/pooled.txt"; exit 1; }
grep -q "val58.h5 (2 views): " "$dir/pooled.txt" || { echo "no per-dataset line"; cat "$dir/pooled.txt"; exit 1; }
grep -q "val.h5 + .*val58.h5 (5 views)" "$dir/pooled.yaml" || { cat "$dir/pooled.yaml"; exit 1; }
if "$tune" --dataset "$dir/nope.h5" --output "$dir/x.yaml" 2> "$dir/e1"; then
  echo "accepted a missing dataset"; exit 1; fi
grep -q "nope.h5" "$dir/e1" || { cat "$dir/e1"; exit 1; }
echo "not hdf5" > "$dir/bad.h5"
if "$tune" --dataset "$dir/bad.h5" --output "$dir/x.yaml" > /dev/null 2> "$dir/e2"; then
  echo "accepted a corrupt dataset"; exit 1; fi
grep -q "bad.h5" "$dir/e2" || { cat "$dir/e2"; exit 1; }
# A bad file among several is named before the network runs on the good one.
if "$tune" --dataset "$dir/val.h5" --dataset "$dir/bad.h5" --output "$dir/x.yaml" > "$dir/o3" 2> "$dir/e3"; then
  echo "accepted a corrupt second dataset"; exit 1; fi
grep -q "bad.h5" "$dir/e3" || { cat "$dir/e3"; exit 1; }
if grep -q "running the network" "$dir/o3" "$dir/e3"; then echo "ran the network before checking"; exit 1; fi
echo "simstack_tune_hough ok"
