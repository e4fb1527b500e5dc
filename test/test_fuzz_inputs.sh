#!/usr/bin/env bash
# Malformed inputs through the tools (a corpus generated here: no third-party files). Every case
# must end with a non-zero exit and one message line naming the problem, or with exit 0 and a
# sensible result: never a signal, never a hang (a refusal within 120 s, a run that works within
# 300 s: limits for a loaded 2-core machine, where the slowest case takes about 17 s idle).
# Usage: test_fuzz_inputs.sh BIN_DIR
set -u
bin=$1
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
fail=0
reconstruct="$bin/simstack_reconstruct"
K=525,525,319.5,239.5

# expect NAME WORDS CMD...: non-zero exit (not a signal), WORDS in stderr, within 120 s;
# with want_rc=N before it, exit code N (the one docs/reference.md gives).
expect() {
  local name=$1 words=$2; shift 2
  timeout 120 "$@" > "$dir/out.txt" 2> "$dir/err.txt"
  local rc=$?
  if [ $rc -eq 0 ]; then echo "FAIL $name: accepted"; fail=1; return; fi
  if [ $rc -eq 124 ]; then echo "FAIL $name: still running after 120 s"; fail=1; return; fi
  if [ $rc -ge 128 ]; then echo "FAIL $name: killed by signal $((rc - 128))"; fail=1; return; fi
  if [ -n "${want_rc:-}" ] && [ $rc -ne "$want_rc" ]; then
    echo "FAIL $name: exit $rc, not $want_rc"; fail=1; return; fi
  if ! grep -q -- "$words" "$dir/err.txt"; then
    echo "FAIL $name: no '$words' in:"; cat "$dir/err.txt"; fail=1; return; fi
  echo "ok   $name: $(grep -m1 -- "$words" "$dir/err.txt" | cut -c1-150)"
}
# survive NAME WORDS CMD...: exit 0 or 1 (a result, or an error naming WORDS), no signal, within
# 300 s.
survive() {
  local name=$1 words=$2; shift 2
  timeout 300 "$@" > "$dir/out.txt" 2> "$dir/err.txt"
  local rc=$?
  if [ $rc -gt 1 ]; then echo "FAIL $name: exit $rc"; cat "$dir/err.txt"; fail=1; return; fi
  if [ $rc -eq 1 ] && ! grep -q -- "$words" "$dir/err.txt"; then
    echo "FAIL $name: exit 1 without '$words' in:"; cat "$dir/err.txt"; fail=1; return; fi
  echo "ok   $name (exit $rc)"
}
# succeed NAME CMD...: exit 0 within 300 s.
succeed() {
  local name=$1; shift
  if timeout 300 "$@" > "$dir/out.txt" 2> "$dir/err.txt"; then echo "ok   $name"; else
    echo "FAIL $name: exit $?"; cat "$dir/err.txt"; fail=1; fi
}

# A good view to start from.
"$bin/simstack_generate" --scenes 1 --seed 5 --output "$dir/d.h5" --views 1 --noise > /dev/null ||
  { echo "FAIL setup: simstack_generate"; exit 1; }
view="$dir/d_views/scene_000000_view_0"
good="${view}_depth.png"

# Depth files that are not what their name says.
echo "just some text" > "$dir/text.pcd"
cp "$good" "$dir/png.pcd"
head -c 5000 /dev/urandom > "$dir/random.pcd"
printf '# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 640\nHEIGHT 480\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 307200\nDATA binary\n' > "$dir/short.pcd"
head -c 20000 /dev/urandom >> "$dir/short.pcd"
printf '# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 999999999\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 999999999\nDATA binary\n' > "$dir/huge.pcd"
cp "$dir/text.pcd" "$dir/TEXT.PCD"
for f in text.pcd png.pcd random.pcd short.pcd huge.pcd TEXT.PCD; do
  expect "depth $f" "$f" "$reconstruct" --depth "$dir/$f" --intrinsics $K --output "$dir/o"
done
# A float TIFF of random bits (depths of 1e30 m, NaN, negative): outside the sensor's range.
head -c $((64 * 48 * 4)) /dev/urandom > "$dir/raw.bin"
# ImageMagick 6 writes the float TIFF but exits 1 over a predictor tag it cannot set: the file
# is what counts.
convert -size 64x48 -depth 32 -define quantum:format=floating-point -endian LSB gray:"$dir/raw.bin" \
  "$dir/random.tiff" 2> /dev/null
[ -s "$dir/random.tiff" ] || { echo "FAIL setup: convert (ImageMagick) made no float TIFF"; exit 1; }
survive "random float TIFF" "random.tiff" "$reconstruct" --depth "$dir/random.tiff" \
  --intrinsics 52.5,52.5,31.5,23.5 --output "$dir/o"
convert -size 64x48 xc:red -depth 16 PNG48:"$dir/rgb16.png" ||
  { echo "FAIL setup: convert"; exit 1; }
expect "16-bit RGB PNG" "one channel" "$reconstruct" --depth "$dir/rgb16.png" --intrinsics 52.5,52.5,31.5,23.5 --output "$dir/o"
convert -size 5000x10 xc:black -depth 16 "$dir/wide.png" || { echo "FAIL setup: convert"; exit 1; }
expect "5000-pixel-wide PNG" "4096" "$reconstruct" --depth "$dir/wide.png" --intrinsics $K --output "$dir/o"

# A PNG whose header claims 100000 x 100000 pixels: refused before it is decoded.
/usr/bin/python3 - "$good" "$dir/claims_huge.png" <<'PY'
import struct, sys
data = bytearray(open(sys.argv[1], "rb").read())
data[16:24] = struct.pack(">II", 100000, 100000)
open(sys.argv[2], "wb").write(data)
PY
expect "PNG header claiming 100000x100000" "100000x100000" "$reconstruct" --depth "$dir/claims_huge.png" --intrinsics $K --output "$dir/o"
expect "mask PNG header claiming 100000x100000" "claims_huge.png: 100000x100000" "$reconstruct" \
  --depth "$good" --intrinsics $K --mask "$dir/claims_huge.png" --output "$dir/o"

# A PNG whose text chunk, after the image, declares 800 MB in a file of a few kB: refused
# before libpng allocates the chunk.
/usr/bin/python3 - "$good" "$dir/long_chunk.png" <<'PY'
import struct, sys
data = open(sys.argv[1], "rb").read()
end = data.rfind(b"IEND") - 4
chunk = struct.pack(">I", 805306405) + b"tEXt" + b"Comment\0" + b"x" * 29
open(sys.argv[2], "wb").write(data[:end] + chunk)
PY
expect "PNG chunk declaring 800 MB" "past the file's end" "$reconstruct" --depth "$dir/long_chunk.png" --intrinsics $K --output "$dir/o"
expect "mask PNG chunk declaring 800 MB" "long_chunk.png: its PNG chunk 'tEXt'" "$reconstruct" \
  --depth "$good" --intrinsics $K --mask "$dir/long_chunk.png" --output "$dir/o"

# Peak memory (maximum resident set, kB) of a run, whatever it ends with.
peak_kb() {
  /usr/bin/python3 -c 'import resource, subprocess, sys
subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=300)
print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)' "$@"
}
good_kb=$(peak_kb "$reconstruct" --depth "$good" --intrinsics $K --output "$dir/mem_good")
for f in huge.pcd short.pcd claims_huge.png long_chunk.png wide.png; do
  kb=$(peak_kb "$reconstruct" --depth "$dir/$f" --intrinsics $K --output "$dir/mem")
  # A measurement that failed (a run past 300 s, a crash of the probe) is a failure, not a pass.
  if ! [[ "$kb" =~ ^[0-9]+$ && "$good_kb" =~ ^[0-9]+$ ]]; then
    echo "FAIL memory $f: not measured ('$kb', good view '$good_kb')"; fail=1
  elif [ "$kb" -gt $((2 * good_kb)) ]; then echo "FAIL memory $f: $kb kB, a good view takes $good_kb kB"; fail=1
  else echo "ok   memory $f: $kb kB (a good 640x480 view: $good_kb kB)"; fi
done

# Intrinsics that do not fit the image.
expect "tiny focal length" "field of view" "$reconstruct" --depth "$good" --intrinsics 1e-9,1e-9,319.5,239.5 --output "$dir/o"
expect "normalized intrinsics" "field of view" "$reconstruct" --depth "$good" --intrinsics 0.82,1.09,0.5,0.5 --output "$dir/o"
expect "principal point outside" "cx = 1999.5" "$reconstruct" --depth "$good" --intrinsics 525,525,1999.5,239.5 --output "$dir/o"
convert "$good" -resize 320x240 "$dir/half.png" || { echo "FAIL setup: convert"; exit 1; }
expect "a half-size image with the full size's intrinsics" "middle half of the 320-pixel-wide" \
  "$reconstruct" --depth "$dir/half.png" --intrinsics $K --output "$dir/o"
expect "depth scale nan" "depth-scale" "$reconstruct" --depth "$good" --intrinsics $K --depth-scale nan --output "$dir/o"
expect "depth scale with a float TIFF" "16-bit images only" "$reconstruct" --depth "$dir/random.tiff" \
  --intrinsics 52.5,52.5,31.5,23.5 --depth-scale 5 --output "$dir/o"
# Output names a file system cannot hold, or none.
expect "empty --output" "the path is empty" "$reconstruct" --depth "$good" --intrinsics $K --output ""
expect "--output with a newline" "control character" "$reconstruct" --depth "$good" --intrinsics $K \
  --output "$dir/two
lines"
expect "--output of 300 characters" "at most 255" "$reconstruct" --depth "$good" --intrinsics $K \
  --output "$dir/$(printf 'a%.0s' $(seq 300))"

# Poses that cannot be a camera over a table.
/usr/bin/python3 - "$view.yaml" "$dir" <<'PY'
import re, sys
text = open(sys.argv[1]).read()
open(sys.argv[2] + "/bad_pose.yaml", "w").write(re.sub(r"(translation: \[)[^,\]]+", r"\1.nan", text, count=1))
# The camera mirrored below the table: z of the translation negated.
m = re.search(r"translation: \[([^\]]+)\]", text)
x, y, z = [float(v) for v in m.group(1).split(",")]
open(sys.argv[2] + "/below.yaml", "w").write(text.replace(m.group(0), "translation: [%g, %g, %g]" % (x, y, -z)))
# A kilometre away and more; no rotation at all.
open(sys.argv[2] + "/far.yaml", "w").write(text.replace(m.group(0), "translation: [1e6, %g, %g]" % (y, z)))
open(sys.argv[2] + "/zero_q.yaml", "w").write(re.sub(r"rotation_xyzw: \[[^\]]+\]", "rotation_xyzw: [0, 0, 0, 0]", text))
# No pose at all: named with the file.
open(sys.argv[2] + "/no_pose.yaml", "w").write(re.sub(r"T_table_camera:(\n  .*)*", "", text))
PY
expect "view file without T_table_camera" "no_pose.yaml: it has no T_table_camera" "$reconstruct" \
  --depth "$good" --table-pose "$dir/no_pose.yaml" --output "$dir/o"
expect "NaN pose" "pose is not finite" "$reconstruct" --depth "$good" --intrinsics $K --table-pose "$dir/bad_pose.yaml" --output "$dir/o"
expect "camera below the table" "above" "$reconstruct" --depth "$good" --intrinsics $K --table-pose "$dir/below.yaml" --output "$dir/o"
expect "camera 1e6 m away" "at most 100 m" "$reconstruct" --depth "$good" --intrinsics $K --table-pose "$dir/far.yaml" --output "$dir/o"
expect "zero quaternion" "rotation_xyzw is zero" "$reconstruct" --depth "$good" --intrinsics $K --table-pose "$dir/zero_q.yaml" --output "$dir/o"

# Configs out of range.
sed 's/min_pile_height_m: 0.01/min_pile_height_m: -1/' "$(dirname "$0")/../config/perception.yaml" > "$dir/neg.yaml"
sed -i "s|model: models/|model: $(cd "$(dirname "$0")/.." && pwd)/models/|" "$dir/neg.yaml"
expect "min_pile_height_m -1" "min_pile_height_m" "$reconstruct" --config "$dir/neg.yaml" --depth "$good" --intrinsics $K --output "$dir/o"
succeed "threads 1000 (capped at the cores)" "$reconstruct" --depth "$good" --intrinsics $K --threads 1000 --output "$dir/o1000"

# Models and their cards: cut short, random bytes, a card that is not YAML; the pipeline's
# sample count and threads out of range in a config.
pkg=$(cd "$(dirname "$0")/.." && pwd)
with_model() {  # with_model NAME: a config whose model is $dir/NAME.pt
  sed "s|model: models/[a-z0-9_]*\.pt|model: $dir/$1.pt|" "$pkg/config/perception.yaml" > "$dir/$1_config.yaml"
}
head -c 100000 "$pkg/models/simstack_r32.pt" > "$dir/cut_model.pt"
head -c 3000 /dev/urandom > "$dir/random_model.pt"
cp "$pkg/models/simstack_r32.pt" "$dir/bad_card.pt"
echo "perception: [" > "$dir/bad_card.yaml"
for m in cut_model random_model bad_card; do
  with_model $m
  expect "model $m" "$m" "$reconstruct" --config "$dir/${m}_config.yaml" --depth "$good" --intrinsics $K --output "$dir/o"
done
# The shipped model with its card, 1000 bytes of the file inverted: the card's SHA-256 names it.
cp "$pkg/models/simstack_r32_fc.pt" "$dir/inverted.pt"
cp "$pkg/models/simstack_r32_fc.yaml" "$dir/inverted.yaml"
/usr/bin/python3 - "$dir/inverted.pt" <<'PY'
import sys
data = bytearray(open(sys.argv[1], "rb").read())
for i in range(len(data) // 2, len(data) // 2 + 1000):
    data[i] ^= 0xFF
open(sys.argv[1], "wb").write(bytes(data))
PY
expect "model with 1000 bytes inverted" "inverted.pt failed its SHA-256 check" "$reconstruct" \
  --model "$dir/inverted.pt" --depth "$good" --intrinsics $K --output "$dir/o"
{ echo "samples: 100000"; sed "s|model: models/|model: $pkg/models/|" "$pkg/config/perception.yaml"; } \
  > "$dir/samples.yaml"
expect "samples: 100000" "samples must lie in" "$reconstruct" --config "$dir/samples.yaml" --depth "$good" --intrinsics $K --output "$dir/o"
sed "s|decompose_samples: 1 |decompose_samples: 10|; s|model: models/|model: $pkg/models/|" \
  "$pkg/config/perception.yaml" > "$dir/decompose.yaml"
expect "decompose_samples: 10 with fc" "no latent code" "$reconstruct" --config "$dir/decompose.yaml" --depth "$good" --intrinsics $K --output "$dir/o"
sed "s|model: models/|model: $pkg/models/|" "$pkg/config/perception.yaml" > "$dir/gamma.yaml"
printf 'hough:\n  gamma: .nan\n' >> "$dir/gamma.yaml"
expect "hough gamma .nan" "hough.gamma" "$reconstruct" --config "$dir/gamma.yaml" --depth "$good" --intrinsics $K --output "$dir/o"
sed "s|lambda_dist: [0-9.]*|lambda_dist: .inf|; s|model: models/|model: $pkg/models/|" \
  "$pkg/config/perception.yaml" > "$dir/inf.yaml"
expect "fitting lambda_dist .inf" "fitting.lambda_dist: .inf is not a finite number" "$reconstruct" \
  --config "$dir/inf.yaml" --depth "$good" --intrinsics $K --output "$dir/o"
sed "s|threads: 2 |threads: 1000|; s|model: models/|model: $pkg/models/|" "$pkg/config/perception.yaml" > "$dir/threads.yaml"
succeed "threads: 1000 in a config (capped)" "$reconstruct" --config "$dir/threads.yaml" --depth "$good" --intrinsics $K --output "$dir/othreads"

# The evaluation's real scenes: a directory with a text file and a PNG named .pcd / .PCD.
mkdir "$dir/real"
cp "$dir/text.pcd" "$dir/real/a.pcd"
cp "$good" "$dir/real/b.PCD"
expect "evaluate --real on files that are not PCDs" "is not a PCD file" "$bin/simstack_evaluate" --real "$dir/real" --output "$dir/eval.json"
[ ! -e "$dir/eval.json" ] || { echo "FAIL evaluate --real: wrote eval.json"; fail=1; }
want_rc=1 expect "evaluate --output naming a --real scene" "is the input file" "$bin/simstack_evaluate" \
  --real "$dir/real" --output "$dir/real/a.pcd"
want_rc=2 expect "evaluate --real with --noise" "needs --dataset" "$bin/simstack_evaluate" \
  --real "$dir/real" --noise --output "$dir/eval.json"
# An organized cloud of a 64x48 camera (fx 52.5): refused with other intrinsics, which it names;
# without a label field, it is no real scene to score.
mkdir "$dir/organized"
/usr/bin/python3 - "$dir/organized/scene.pcd" <<'PY'
import sys
rows = ["%g %g 1" % ((u - 31.5) / 52.5, (v - 23.5) / 52.5) for v in range(48) for u in range(64)]
with open(sys.argv[1], "w") as f:
    f.write("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 64\nHEIGHT 48\n")
    f.write("VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3072\nDATA ascii\n" + "\n".join(rows) + "\n")
PY
want_rc=1 expect "organized cloud with other intrinsics" "they fit fx 52.5" "$reconstruct" \
  --depth "$dir/organized/scene.pcd" --intrinsics 105,105,31.5,23.5 --output "$dir/o"
want_rc=1 expect "evaluate --real on a cloud without labels" "has no label field" \
  "$bin/simstack_evaluate" --real "$dir/organized" --no-classical --output "$dir/eval.json"

# A generator run that cannot make its piles (a 0.2 m grid) leaves no file behind.
expect "generate with no pile possible" "no pile accepted" "$bin/simstack_generate" --scenes 2 --seed 1 --extent 0.2 --sizes 0.05:0.15 --output "$dir/g.h5"
[ -z "$(ls "$dir"/g.h5* 2> /dev/null)" ] || { echo "FAIL generate: a partial file stayed"; fail=1; }

# Results are atomic: nothing on the table is a result with no objects; a second run replaces
# the first's directory (test_dataset's StagedOutput: whole); a failed run leaves the earlier
# result as it was; an output that cannot be made fails before the work.
convert -size 640x480 xc:'#03E803E803E8' -depth 16 -colorspace gray "$dir/plane.png" ||
  { echo "FAIL setup: convert"; exit 1; }
succeed "nothing on the table" "$reconstruct" --depth "$dir/plane.png" --intrinsics $K --output "$dir/empty"
grep -q "^0 objects" "$dir/out.txt" || { echo "FAIL nothing on the table: no '0 objects' line"; fail=1; }
# A file put into the result since is not removed by a rerun: the rerun is refused, naming it.
touch "$dir/empty/instance_7.ply"
expect "rerun over a file added since" "did not write (instance_7.ply)" "$reconstruct" \
  --depth "$dir/plane.png" --intrinsics $K --output "$dir/empty"
[ -e "$dir/empty/instance_7.ply" ] || { echo "FAIL rerun: the added file was removed"; fail=1; }
rm "$dir/empty/instance_7.ply"
succeed "rerun into the same directory" "$reconstruct" --depth "$dir/plane.png" --intrinsics $K --output "$dir/empty"
cp "$dir/empty/superquadrics.yaml" "$dir/before.yaml"
expect "failed run into an earlier result" "field of view" "$reconstruct" --depth "$dir/plane.png" \
  --intrinsics 0.82,1.09,0.5,0.5 --output "$dir/empty"
cmp -s "$dir/before.yaml" "$dir/empty/superquadrics.yaml" || { echo "FAIL: the earlier result changed"; fail=1; }
[ -z "$(ls -d "$dir"/empty.partial-* 2> /dev/null)" ] || { echo "FAIL: a partial directory stayed"; fail=1; }
echo "a file" > "$dir/afile"
expect "output under a file" "afile" "$reconstruct" --depth "$dir/plane.png" --intrinsics $K --output "$dir/afile/sub"

# Training: nothing to resume; a dataset cut short.
train_config="$dir/train.yaml"  # the default config, validated on the one generated pile
sed 's/validation_scenes: [0-9]*/validation_scenes: 1/' "$(dirname "$0")/../config/train_r32.yaml" > "$train_config"
"$bin/simstack_generate" --scenes 2 --seed 6 --output "$dir/two.h5" > /dev/null ||
  { echo "FAIL setup: simstack_generate"; exit 1; }
expect "train --resume without a checkpoint" "no checkpoint" "$bin/simstack_train" --dataset "$dir/two.h5" \
  --config "$train_config" --output "$dir/run" --resume
for option in "--output $dir/run_v" --resume "--steps 3"; do
  # shellcheck disable=SC2086  # the option and its value are two words
  expect "train --validate-only with $option" "excludes" "$bin/simstack_train" \
    --dataset "$dir/two.h5" --config "$train_config" --validate-only "$pkg/models/simstack_r32_fc.pt" $option
done
sed 's/learning_rate:/lerning_rate:/' "$train_config" > "$dir/typo.yaml"
expect "training config with a misspelt field" "unknown field training.lerning_rate" \
  "$bin/simstack_train" --dataset "$dir/two.h5" --config "$dir/typo.yaml" --output "$dir/run_typo"
succeed "train 2 steps" "$bin/simstack_train" --dataset "$dir/two.h5" --config "$train_config" \
  --output "$dir/run_done" --steps 2 --threads 1
# The default config's 128 validation piles on a dataset of two: its last one validates, said.
succeed "train with more validation piles than the dataset holds" "$bin/simstack_train" \
  --dataset "$dir/two.h5" --config "$(dirname "$0")/../config/train_r32.yaml" \
  --output "$dir/run_small" --steps 2 --threads 1
grep -q "its last 1 are the validation" "$dir/out.txt" ||
  { echo "FAIL train on a small dataset: no note in:"; cat "$dir/out.txt"; fail=1; }
expect "train again into a run without --resume" "holds a training run" "$bin/simstack_train" \
  --dataset "$dir/two.h5" --config "$train_config" --output "$dir/run_done" --steps 2
# A log that cannot be written (/dev/full: a full disk) stops the run, naming it; the leftover
# of a run killed while writing its first checkpoint is that run's, started afresh.
mkdir -p "$dir/run_full" && ln -s /dev/full "$dir/run_full/train_log.csv"
expect "train with a log on a full disk" "cannot write $dir/run_full/train_log.csv" \
  "$bin/simstack_train" --dataset "$dir/two.h5" --config "$train_config" --output "$dir/run_full" \
  --steps 2 --threads 1
mkdir -p "$dir/run_cut" && echo "step" > "$dir/run_cut/train_log.csv"
head -c 1000 "$dir/run_done/checkpoint.pt" > "$dir/run_cut/checkpoint.pt.tmp"
succeed "train afresh beside a first checkpoint cut short" "$bin/simstack_train" \
  --dataset "$dir/two.h5" --config "$train_config" --output "$dir/run_cut" --steps 2 --threads 1
mkdir -p "$dir/theirs" && touch "$dir/theirs/precious.txt"
expect "train into a directory of other files" "holds no training run" "$bin/simstack_train" \
  --dataset "$dir/two.h5" --config "$train_config" --output "$dir/theirs" --steps 2
expect "train into the working directory" "working directory" "$bin/simstack_train" \
  --dataset "$dir/two.h5" --config "$train_config" --output . --steps 2
expect "train with a missing --ycb directory" "$dir/no_meshes" "$bin/simstack_train" \
  --dataset "$dir/two.h5" --config "$train_config" --output "$dir/run_ycb" --ycb "$dir/no_meshes"
head -c 3000 "$dir/d.h5" > "$dir/cut.h5"
expect "train on a truncated dataset" "cut.h5" "$bin/simstack_train" --dataset "$dir/cut.h5" \
  --config "$train_config" --output "$dir/run2"

# A dataset missing one array, or one attribute: each named.
cp "$dir/two.h5" "$dir/novotes.h5"
cp "$dir/two.h5" "$dir/noseed.h5"
/usr/bin/python3 - "$dir/novotes.h5" "$dir/noseed.h5" <<'PY'
import sys
import h5py
with h5py.File(sys.argv[1], "a") as f:
    del f["votes"]
with h5py.File(sys.argv[2], "a") as f:
    del f.attrs["seed"]
PY
expect "train on a dataset without votes" "no array 'votes'" "$bin/simstack_train" \
  --dataset "$dir/novotes.h5" --config "$train_config" --output "$dir/run_nv"
expect "train on a dataset without a seed" "no attribute 'seed'" "$bin/simstack_train" \
  --dataset "$dir/noseed.h5" --config "$train_config" --output "$dir/run_ns"
# Objects no pile holds: each named with the file, the scene and the object.
for spoil in quat0 hugeaxes farpos; do cp "$dir/two.h5" "$dir/$spoil.h5"; done
/usr/bin/python3 - "$dir" <<'PY'
import sys
import h5py
for name, columns, value in (("quat0", slice(11, 15), 0.0), ("hugeaxes", slice(2, 5), 1e6),
                             ("farpos", slice(8, 11), 1e6)):
    with h5py.File("%s/%s.h5" % (sys.argv[1], name), "a") as f:
        objects = f["objects"][...]
        objects[0, 0, columns] = value
        f["objects"][...] = objects
PY
expect "evaluate a dataset whose object has a zero quaternion" \
  "quat0.h5: scene 0, object 0: its orientation quaternion has norm 0" \
  "$bin/simstack_evaluate" --dataset "$dir/quat0.h5" --scenes 1 --views 1 --no-classical \
  --no-stability --output "$dir/q.json"
expect "evaluate a dataset whose object is a kilometre long" \
  "hugeaxes.h5: scene 0, object 0: a semi-axis is longer than the grid" \
  "$bin/simstack_evaluate" --dataset "$dir/hugeaxes.h5" --scenes 1 --views 1 --no-classical \
  --no-stability --output "$dir/q.json"
expect "evaluate a dataset whose object is far from its grid" \
  "farpos.h5: scene 0, object 0: its centre lies" "$bin/simstack_evaluate" \
  --dataset "$dir/farpos.h5" --scenes 1 --views 1 --no-classical --no-stability \
  --output "$dir/q.json"
cp "$dir/two.h5" "$dir/scrambled.h5"
dd if=/dev/urandom of="$dir/scrambled.h5" bs=1 seek=20000 count=20000 conv=notrunc 2> /dev/null
expect "train on a scrambled dataset" "scrambled.h5" "$bin/simstack_train" --dataset "$dir/scrambled.h5" \
  --config "$train_config" --output "$dir/run3"

expect "evaluate with intrinsics in metres" "invalid camera intrinsics" "$bin/simstack_evaluate" \
  --dataset "$dir/two.h5" --scenes 1 --views 1 --intrinsics 0.5,0.5,320,240 \
  --output "$dir/intrinsics.json" --no-classical --no-stability
expect "evaluate --sensor without --noise" "requires --noise" "$bin/simstack_evaluate" \
  --dataset "$dir/two.h5" --scenes 1 --sensor realsense --output "$dir/sensor.json"
expect "grasps --sensor with --no-noise" "excludes" "$bin/simstack_evaluate_grasps" \
  --dataset "$dir/two.h5" --scenes 1 --no-noise --sensor realsense --output "$dir/grasps.json"
expect "evaluate --sensor kinect2" "kinect2" "$bin/simstack_evaluate" --dataset "$dir/two.h5" \
  --scenes 1 --noise --sensor kinect2 --output "$dir/sensor.json"

# Grasp evaluation: more hypotheses than the model has distinct samples.
expect "grasps --hypotheses 3 with fc" "no latent code" "$bin/simstack_evaluate_grasps" \
  --dataset "$dir/two.h5" --scenes 1 --hypotheses 3 --no-classical --output "$dir/grasps.json"
expect "grasps --hypotheses 5 with the C-VAE's 3 samples" "raise --samples" \
  "$bin/simstack_evaluate_grasps" --model "$pkg/models/simstack_r32.pt" --dataset "$dir/two.h5" \
  --scenes 1 --hypotheses 5 --no-classical --output "$dir/grasps.json"

# An output that names an input: refused before the work, the input left as it was.
cp "$dir/two.h5" "$dir/keep.h5"
expect "evaluate --output naming its --dataset" "is the input file" "$bin/simstack_evaluate" \
  --dataset "$dir/keep.h5" --output "$dir/./keep.h5" --scenes 1 --views 1 --no-classical --no-stability
cmp -s "$dir/two.h5" "$dir/keep.h5" || { echo "FAIL evaluate: the dataset was replaced"; fail=1; }
expect "evaluate --summary naming --output" "is the --output file" "$bin/simstack_evaluate" \
  --dataset "$dir/keep.h5" --output "$dir/same.json" --summary "$dir/same.json" --scenes 1
# The same file by two relative names, neither there yet.
expect "evaluate --summary ./X beside --output X" "is the --output file" bash -c \
  "cd '$dir' && exec '$bin/simstack_evaluate' --dataset keep.h5 --output fresh.json --summary ./fresh.json --scenes 1"
expect "evaluate --summary empty" "path is empty" "$bin/simstack_evaluate" \
  --dataset "$dir/keep.h5" --output "$dir/s.json" --summary "" --scenes 1
expect "generate --views-dir empty" "path is empty" "$bin/simstack_generate" --scenes 1 \
  --views 1 --views-dir "" --output "$dir/v.h5"
expect "generate --extent 1e30" "extent" "$bin/simstack_generate" --scenes 1 --extent 1e30 \
  --output "$dir/v.h5"
expect "tune_hough --output naming its --dataset" "is the input file" "$bin/simstack_tune_hough" \
  --dataset "$dir/keep.h5" --output "$dir/keep.h5"
expect "evaluate_grasps --output naming the model's card" "is the input file" \
  "$bin/simstack_evaluate_grasps" --dataset "$dir/keep.h5" --model "$dir/bad_card.pt" \
  --output "$dir/bad_card.yaml"
mkdir -p "$dir/houghcard"
cp "$pkg/models/simstack_r32_fc.pt" "$dir/houghcard/m.pt"
sed 's/^\(    refinement:\).*/\1 100/' "$pkg/models/simstack_r32_fc.yaml" > "$dir/houghcard/m.yaml"
expect "check_model on a card whose Hough setting loading refuses" "hough.refinement must be in" \
  "$bin/simstack_check_model" "$dir/houghcard/m.pt"
mkdir -p "$dir/samplescard"
cp "$pkg/models/simstack_r32_fc.pt" "$dir/samplescard/m.pt"
sed 's/^\(  samples:\).*/\1 0/' "$pkg/models/simstack_r32_fc.yaml" > "$dir/samplescard/m.yaml"
expect "check_model on a card whose samples loading refuses" "perception.samples must lie in" \
  "$bin/simstack_check_model" "$dir/samplescard/m.pt"
expect "evaluate_grasps --perturb-position without --perturbed" "requires --perturbed" \
  "$bin/simstack_evaluate_grasps" --dataset "$dir/keep.h5" --perturb-position 0.05 \
  --output "$dir/pp.json"
expect "evaluate_grasps --perturb-scale with --perturbed 0" "need --perturbed N above 0" \
  "$bin/simstack_evaluate_grasps" --dataset "$dir/keep.h5" --perturbed 0 --perturb-scale 0.2 \
  --output "$dir/pp.json"
mkdir -p "$dir/dircard/m.yaml"
cp "$pkg/models/simstack_r32_fc.pt" "$dir/dircard/m.pt"
expect "check_model with a directory as card" "it is a directory" "$bin/simstack_check_model" \
  "$dir/dircard/m.pt"
cp "$pkg/models/simstack_r32_fc.yaml" "$dir/dircard/card.yaml"
expect "check_model given a card" "is a model card, not a model" "$bin/simstack_check_model" \
  "$dir/dircard/card.yaml"
expect "check_model --stamp given a card" "is a model card, not a model" \
  "$bin/simstack_check_model" --stamp "$dir/dircard/card.yaml"
want_rc=105 expect "tune_hough --refinement 100" "refinement" "$bin/simstack_tune_hough" \
  --dataset "$dir/keep.h5" --output "$dir/hough.yaml" --refinement 100
want_rc=105 expect "tune_hough --bandwidth nan" "bandwidth" "$bin/simstack_tune_hough" \
  --dataset "$dir/keep.h5" --output "$dir/hough.yaml" --bandwidth nan

# The table's RANSAC settings and the generator's object counts are checked.
sed "s|model: models/|model: $pkg/models/|; s|max_iterations: 1000|max_iterations: -5|" \
  "$pkg/config/perception.yaml" > "$dir/table.yaml"
expect "table max_iterations -5" "max_iterations" "$reconstruct" --config "$dir/table.yaml" \
  --depth "$good" --intrinsics $K --output "$dir/o"
for objects in 3x:4y 3:4:5 1:100000 0:2; do
  expect "generate --objects $objects" "objects" "$bin/simstack_generate" --scenes 1 --seed 1 \
    --objects "$objects" --output "$dir/obj.h5"
done

# A seed below 0 (CLI11 would wrap it to 2^64 - 1); intrinsics with a trailing comma.
want_rc=105 expect "generate --seed -1" "not a seed" "$bin/simstack_generate" --scenes 1 --seed -1 --output "$dir/s.h5"
want_rc=105 expect "generate --seed 2^64" "not a seed" "$bin/simstack_generate" --scenes 1 \
  --seed 18446744073709551616 --output "$dir/s.h5"
want_rc=1 expect "intrinsics with a trailing comma" "ends in a comma" "$reconstruct" --depth "$good" \
  --intrinsics $K, --output "$dir/o"

# A training config's bad value is reported at its line in the file.
sed 's/^\(  steps:\).*/\1 abc/' "$train_config" > "$dir/steps.yaml"
line=$(grep -n "steps: abc" "$dir/steps.yaml" | cut -d: -f1)
expect "training config steps: abc" "line $line," "$bin/simstack_train" --dataset "$dir/two.h5" \
  --config "$dir/steps.yaml" --output "$dir/run_steps"

# simstack_make_bag: values CLI11's ranges let through (nan), empty or equal frames, and a
# failed run leaves no bag.
for option in --distance --elevation --interval; do
  expect "make_bag $option nan" "not a finite number" "$bin/simstack_make_bag" \
    --output "$dir/nan.bag" "$option" nan
done
expect "make_bag with one frame for the table and the camera" "must differ" \
  "$bin/simstack_make_bag" --output "$dir/same.bag" --table-frame cam --camera-frame cam
for camera in 'bad name!' '~cam' 'cam/' 'a//b' '/cam'; do
  want_rc=105 expect "make_bag --camera '$camera'" "is not a namespace of ROS names" \
    "$bin/simstack_make_bag" --output "$dir/same.bag" --camera "$camera"
done
want_rc=105 expect "make_bag --table-frame /table" "no leading '/'" \
  "$bin/simstack_make_bag" --output "$dir/same.bag" --table-frame /table
# A seed written with a leading zero is the same seed (CLI11 alone reads 010 as octal 8).
if "$bin/simstack_make_bag" --output "$dir/s.bag" --views 1 --repeats 1 --seed 010 |
    grep -q "seed 10)"; then echo "ok   make_bag --seed 010 is seed 10"; else
  echo "FAIL make_bag --seed 010 is not seed 10"; fail=1; fi
# Every integer option reads decimal: 010 is ten, 0x10 is refused.
if "$bin/simstack_generate" --scenes 010 --seed 1 --resolution 16 --output "$dir/ten.h5" |
    grep -q "wrote 10 scenes"; then echo "ok   generate --scenes 010 is ten scenes"; else
  echo "FAIL generate --scenes 010 is not ten scenes"; fail=1; fi
want_rc=105 expect "generate --scenes 0x10" "'0x10' is not a whole number in decimal" \
  "$bin/simstack_generate" --scenes 0x10 --seed 1 --output "$dir/hex.h5"
[ ! -e "$dir/nan.bag" ] && [ ! -e "$dir/same.bag" ] || { echo "FAIL make_bag left a bag"; fail=1; }
# A depth file's bag: its frames with the view file's camera and table pose; the pile's
# options and a depth without a camera are refused.
"$bin/simstack_make_bag" --depth "$good" --table-pose "$view.yaml" --frames 3 \
  --output "$dir/file.bag" > /dev/null || { echo "FAIL make_bag --depth"; fail=1; }
/usr/bin/python3 - "$dir/file.bag" <<'PY' || fail=1
import sys
import rosbag
counts = {}
with rosbag.Bag(sys.argv[1]) as bag:
    for topic, msg, _ in bag.read_messages():
        counts[topic] = counts.get(topic, 0) + 1
        if topic.endswith("image_rect") and msg.encoding != "16UC1":
            sys.exit("FAIL make_bag --depth: encoding %s" % msg.encoding)
want = {"/tf": 3, "/camera/depth/camera_info": 3, "/camera/depth/image_rect": 3}
if counts != want:
    sys.exit("FAIL make_bag --depth: %s, not %s" % (counts, want))
print("ok   make_bag --depth: 3 frames of the depth file")
PY
expect "make_bag --depth with --seed" "excludes" "$bin/simstack_make_bag" --depth "$good" \
  --seed 3 --output "$dir/x.bag"
expect "make_bag --depth without a camera" "--intrinsics is needed" "$bin/simstack_make_bag" \
  --depth "$good" --output "$dir/x.bag"
# An --output naming its own depth or pose file: refused, the input left whole.
cp "$good" "$dir/own.png"
cp "$view.yaml" "$dir/own.yaml"
sum_before=$(md5sum "$dir/own.png" "$dir/own.yaml")
expect "make_bag --output its --depth" "which it would replace" "$bin/simstack_make_bag" \
  --depth "$dir/own.png" --table-pose "$dir/own.yaml" --output "$dir/own.png"
expect "make_bag --output its --table-pose" "which it would replace" "$bin/simstack_make_bag" \
  --depth "$dir/own.png" --table-pose "$dir/own.yaml" --output "$dir/own.yaml"
[ "$(md5sum "$dir/own.png" "$dir/own.yaml")" = "$sum_before" ] ||
  { echo "FAIL make_bag changed its input"; fail=1; }
# An existing device, pipe or socket is not replaced by an output file.
mkfifo "$dir/pipe"
expect "generate --output naming a pipe" "not a regular file" "$bin/simstack_generate" \
  --scenes 1 --seed 1 --output "$dir/pipe"
[ -p "$dir/pipe" ] || { echo "FAIL generate replaced a pipe"; fail=1; }
# The figures' script with no evaluation among its files draws nothing and says so.
echo '{"real_dir": "mosd_learn", "methods": {}}' > "$dir/real.json"
expect "plot_evaluation with only a --real report" "nothing drawn" /usr/bin/python3 \
  "$bin/plot_evaluation.py" "$dir/real.json" --output "$dir/figures"

[ $fail -eq 0 ] && echo "fuzz corpus: every case handled"
exit $fail
