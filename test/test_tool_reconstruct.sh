#!/usr/bin/env bash
# End-to-end check of simstack_reconstruct on a generated view: every output file, the table
# given or estimated, the grids readable with h5py, and clear errors on bad input.
set -eu
generate=$1
reconstruct=$2
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
"$generate" --scenes 1 --seed 5 --output "$dir/d.h5" --views 1 --noise > /dev/null
view="$dir/d_views/scene_000000_view_0"
"$reconstruct" --depth "${view}_depth.png" --intrinsics 525,525,319.5,239.5 \
  --table-pose "$view.yaml" --output "$dir/out" > "$dir/log.txt"
for f in superquadrics.yaml surface.ply instances.pcd labels.png grids.h5 depth.png instances.png \
         superquadrics_input_view.png superquadrics_second_view.png; do
  test -s "$dir/out/$f" || { echo "missing $f"; cat "$dir/log.txt"; exit 1; }
done
# labels.png: 16 bits, pixel for pixel with the depth, and label k + 1 on the pixels of the
# object of id k in superquadrics.yaml (its pixels' points lie around that shape).
raw16() { convert "$1" -depth 16 -endian MSB gray:- ; }
raw16 "$dir/out/labels.png" > "$dir/labels.raw"
raw16 "${view}_depth.png" > "$dir/depth.raw"
/usr/bin/python3 - "$dir" "$view.yaml" <<'PY'
import math, struct, sys, yaml
d, view = sys.argv[1], yaml.safe_load(open(sys.argv[2]))
w, h, k = view["width"], view["height"], view["intrinsics"]
labels = struct.unpack(">%dH" % (w * h), open(d + "/labels.raw", "rb").read())
depth = struct.unpack(">%dH" % (w * h), open(d + "/depth.raw", "rb").read())
shapes = {o["id"]: o for o in yaml.safe_load(open(d + "/out/superquadrics.yaml"))["objects"]}
t, (qx, qy, qz, qw) = view["T_table_camera"]["translation"], view["T_table_camera"]["rotation_xyzw"]
# One depth image: the file names the camera that measured the objects (its position).
camera = yaml.safe_load(open(d + "/out/superquadrics.yaml"))["camera"]
assert all(abs(a - b) < 1e-6 for a, b in zip(camera, t)), (camera, t)
R = [[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
     [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
     [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]]
near, total = {}, {}
for i, label in enumerate(labels):
    if label == 0:
        continue
    assert depth[i] > 0, "a label on missing depth"
    assert label - 1 in shapes, "label %d has no object %d in superquadrics.yaml" % (label, label - 1)
    z = depth[i] * 0.001
    c = ((i % w - k["cx"]) * z / k["fx"], (i // w - k["cy"]) * z / k["fy"], z)
    p = [sum(R[r][j] * c[j] for j in range(3)) + t[r] for r in range(3)]
    s = shapes[label - 1]
    total[label] = total.get(label, 0) + 1
    if math.dist(p, s["position"]) <= 1.5 * max(s["scale"]) + 0.02:
        near[label] = near.get(label, 0) + 1
assert len(total) >= 2, total
for label, n in total.items():
    assert near.get(label, 0) >= 0.9 * n, "label %d: %d of %d pixels near object %d" % (label, near.get(label, 0), n, label - 1)
PY
grep -q "objects in a grid of 0.64 m; 1 tile perceived; timings" "$dir/log.txt"
grep -q "^model .*simstack_r32_fc.pt (card .*simstack_r32_fc.yaml)$" "$dir/log.txt" ||
  { echo "the model and its card not named"; cat "$dir/log.txt"; exit 1; }
# same_shapes A B: the two superquadrics.yaml hold the same objects, in the same order, their
# positions and semi-axes within 1 mm (inputs that differ by a float's rounding).
same_shapes() {
  /usr/bin/python3 - "$1" "$2" <<'PY'
import math, sys, yaml
a, b = ([o for o in yaml.safe_load(open(p))["objects"]] for p in sys.argv[1:])
assert a and len(a) == len(b), "%d objects against %d" % (len(a), len(b))
for x, y in zip(a, b):
    assert math.dist(x["position"], y["position"]) < 1e-3, (x["position"], y["position"])
    assert max(abs(u - v) for u, v in zip(x["scale"], y["scale"])) < 1e-3, (x["scale"], y["scale"])
PY
}
# The view file holds the intrinsics: --intrinsics may be left out, and ones that differ are
# refused, naming the file; without either the depth is named.
"$reconstruct" --depth "${view}_depth.png" --table-pose "$view.yaml" --output "$dir/out_vi" \
  > "$dir/log_vi.txt"
cmp -s "$dir/out/superquadrics.yaml" "$dir/out_vi/superquadrics.yaml" ||
  { echo "the view file's intrinsics gave another result"; cat "$dir/log_vi.txt"; exit 1; }
if "$reconstruct" --depth "${view}_depth.png" --intrinsics 600,600,319.5,239.5 \
  --table-pose "$view.yaml" --output "$dir/out_x" > /dev/null 2> "$dir/e_vi"; then
  echo "accepted intrinsics that differ from the view file's"; exit 1; fi
grep -q "differ from those of .*view_0.yaml" "$dir/e_vi" || { cat "$dir/e_vi"; exit 1; }
if "$reconstruct" --depth "${view}_depth.png" --output "$dir/out_x" > /dev/null 2> "$dir/e_ni"; then
  echo "accepted a depth without intrinsics"; exit 1; fi
grep -q "intrinsics is needed for .*depth.png" "$dir/e_ni" || { cat "$dir/e_ni"; exit 1; }
# A view file's depth_scale_m is the PNG's unit: the same depth in tenths of a millimetre is
# perceived as the millimetre PNG; a --depth-scale that disagrees, and an unknown key, are refused.
convert "${view}_depth.png" -evaluate multiply 10 -depth 16 "$dir/tenths.png"
{ cat "$view.yaml"; echo "depth_scale_m: 0.0001"; } | grep -v "^depth_scale_m: 0.001$" > "$dir/tenths.yaml"
"$reconstruct" --depth "$dir/tenths.png" --table-pose "$dir/tenths.yaml" --output "$dir/out_t" \
  > "$dir/log_t.txt"
same_shapes "$dir/out/superquadrics.yaml" "$dir/out_t/superquadrics.yaml" ||
  { echo "the view file's depth_scale_m gave another result"; cat "$dir/log_t.txt"; exit 1; }
if "$reconstruct" --depth "$dir/tenths.png" --table-pose "$dir/tenths.yaml" --depth-scale 0.001 \
  --output "$dir/out_x" > /dev/null 2> "$dir/e_ds"; then
  echo "accepted a --depth-scale that differs from the view file's"; exit 1; fi
grep -q "depth-scale 0.001000 differs from .*tenths.yaml's depth_scale_m" "$dir/e_ds" || { cat "$dir/e_ds"; exit 1; }
# The view file's depth_scale_m is its PNG's: the same depth as a float TIFF in metres, given
# with that view file, is read in metres and perceived as the PNG.
/usr/bin/python3 - "$dir/depth.raw" "$dir/depth_m.tiff" "$view.yaml" <<'PY'
import struct, sys, numpy as np, yaml
view = yaml.safe_load(open(sys.argv[3]))
w, h = view["width"], view["height"]
mm = np.frombuffer(open(sys.argv[1], "rb").read(), ">u2")
data = (mm.astype(np.float64) * 0.001).astype("<f4").tobytes()
# One strip of 32-bit IEEE floats: width, height, bits, no compression, black is zero, strip
# offset, one sample, rows per strip, strip bytes, sample format float.
tags = [(256, 4, w), (257, 4, h), (258, 3, 32), (259, 3, 1), (262, 3, 1), (273, 4, 0),
        (277, 3, 1), (278, 4, h), (279, 4, len(data)), (339, 3, 3)]
out = b"II*\x00" + struct.pack("<IH", 8, len(tags))
for tag, kind, value in tags:
    value = 8 + 2 + 12 * len(tags) + 4 if tag == 273 else value
    out += struct.pack("<HHI", tag, kind, 1)
    out += struct.pack("<HH", value, 0) if kind == 3 else struct.pack("<I", value)
open(sys.argv[2], "wb").write(out + struct.pack("<I", 0) + data)
PY
"$reconstruct" --depth "$dir/depth_m.tiff" --table-pose "$view.yaml" --output "$dir/out_tiff" \
  > "$dir/log_tiff.txt" || { echo "a float TIFF with its view file was refused"; exit 1; }
cmp -s "$dir/out_vi/superquadrics.yaml" "$dir/out_tiff/superquadrics.yaml" ||
  { echo "the float TIFF gave another result than the PNG"; cat "$dir/log_tiff.txt"; exit 1; }
{ cat "$view.yaml"; echo "depth_scale: 0.001"; } > "$dir/typo.yaml"
if "$reconstruct" --depth "${view}_depth.png" --table-pose "$dir/typo.yaml" --output "$dir/out_x" \
  > /dev/null 2> "$dir/e_typo"; then
  echo "accepted a view file with an unknown key"; exit 1; fi
grep -q "typo.yaml: unknown key 'depth_scale'" "$dir/e_typo" || { cat "$dir/e_typo"; exit 1; }
# An unorganized PCD of the same view (the valid pixels' points, one row) is placed on the
# pixels of the intrinsics and perceived as the PNG; other intrinsics are refused, naming a point.
/usr/bin/python3 - "$dir" 640 480 > "$dir/loose.pcd" <<'PY'
import struct, sys
d, w, h = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
depth = struct.unpack(">%dH" % (w * h), open(d + "/depth.raw", "rb").read())
pts = [((i % w - 319.5) * z / 525, (i // w - 239.5) * z / 525, z)
       for i, z in ((i, v * 0.001) for i, v in enumerate(depth) if v > 0)]
print("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH %d\nHEIGHT 1\n"
      "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS %d\nDATA ascii" % (len(pts), len(pts)))
for p in pts:
    print("%.9g %.9g %.9g" % p)
PY
"$reconstruct" --depth "$dir/loose.pcd" --intrinsics 525,525,319.5,239.5 --table-pose "$view.yaml" \
  --output "$dir/out_pcd" > "$dir/log_pcd.txt"
same_shapes "$dir/out/superquadrics.yaml" "$dir/out_pcd/superquadrics.yaml" ||
  { echo "the unorganized PCD gave another result"; cat "$dir/log_pcd.txt"; exit 1; }
if "$reconstruct" --depth "$dir/loose.pcd" --intrinsics 600,600,319.5,239.5 --output "$dir/x" \
  2> "$dir/e_pcd"; then echo "accepted a cloud that does not fall on the pixels"; exit 1; fi
grep -q "loose.pcd: point 0 .* does not fall on a pixel of the 640x480 camera" "$dir/e_pcd" ||
  { cat "$dir/e_pcd"; exit 1; }
# A camera whose principal point is off the image's centre: the image its intrinsics centre
# (646 x 475) misses its last rows; given its size, the cloud is placed on it.
sed -n '1,10p' "$dir/loose.pcd" > "$dir/shifted.pcd"
/usr/bin/python3 - "$dir/loose.pcd" >> "$dir/shifted.pcd" <<'PY'
import sys
lines = open(sys.argv[1]).read().split("\n")[10:]
for line in filter(None, lines):
    x, y, z = map(float, line.split())
    u, v = x * 525 / z + 319.5, y * 525 / z + 239.5
    print("%.9g %.9g %.9g" % ((u - 322.3) * z / 525, (v - 236.8) * z / 525, z))
PY
"$reconstruct" --depth "$dir/shifted.pcd" --intrinsics 525,525,322.3,236.8,640,480 \
  --output "$dir/out_shifted" > "$dir/log_shifted.txt" || { cat "$dir/log_shifted.txt"; exit 1; }
if "$reconstruct" --depth "$dir/shifted.pcd" --intrinsics 525,525,322.3,236.8 --output "$dir/x" \
  2> "$dir/e_shifted"; then echo "placed a cloud on pixels the camera does not have"; exit 1; fi
grep -q "or an image of another size?" "$dir/e_shifted" || { cat "$dir/e_shifted"; exit 1; }
if "$reconstruct" --depth "${view}_depth.png" --intrinsics 525,525,319.5,239.5,320,240 \
  --output "$dir/x" 2> "$dir/e_size"; then echo "accepted intrinsics of another size"; exit 1; fi
grep -q "gives a 320x240 image, but it is 640x480" "$dir/e_size" || { cat "$dir/e_size"; exit 1; }
# Without a pose the table comes from RANSAC.
"$reconstruct" --depth "${view}_depth.png" --intrinsics 525,525,319.5,239.5 --output "$dir/out2" \
  > "$dir/log2.txt"
grep -q "estimated by RANSAC" "$dir/log2.txt"
# A mask: 8-bit PNG, 0 = ignore. Everything masked leaves no depth; a mask of another size is
# refused, naming both files.
png() {  # png FILE WIDTH HEIGHT VALUE: a grey 8-bit PNG of one value
  /usr/bin/python3 - "$@" <<'PY'
import struct, sys, zlib
path, w, h, value = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
def chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
rows = b"".join(b"\0" + bytes([value]) * w for _ in range(h))
with open(path, "wb") as f:
    f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
PY
}
png "$dir/all.png" 640 480 255
"$reconstruct" --depth "${view}_depth.png" --intrinsics 525,525,319.5,239.5 \
  --table-pose "$view.yaml" --mask "$dir/all.png" --output "$dir/out3" > "$dir/log3.txt"
cmp -s "$dir/out/superquadrics.yaml" "$dir/out3/superquadrics.yaml" ||
  { echo "a mask of ones changed the result"; exit 1; }
png "$dir/none.png" 640 480 0
if "$reconstruct" --depth "${view}_depth.png" --intrinsics 525,525,319.5,239.5 \
  --table-pose "$view.yaml" --mask "$dir/none.png" --output "$dir/x" 2> "$dir/e4"; then
  echo "accepted a mask that hides everything"; exit 1; fi
grep -q "mask" "$dir/e4" || { cat "$dir/e4"; exit 1; }
png "$dir/small.png" 320 240 255
if "$reconstruct" --depth "${view}_depth.png" --intrinsics 525,525,319.5,239.5 \
  --mask "$dir/small.png" --output "$dir/x" 2> "$dir/e5"; then
  echo "accepted a mask of another size"; exit 1; fi
grep -q "small.png is 320x240" "$dir/e5" || { cat "$dir/e5"; exit 1; }
/usr/bin/python3 -c "import h5py" || { echo "python3-h5py is missing (scripts/setup installs it)"; exit 1; }
  /usr/bin/python3 - "$dir/out/grids.h5" <<'PY'
import sys, h5py
f = h5py.File(sys.argv[1], "r")
for k in ("tsdf", "occupancy_probability", "labels", "partial_tsdf", "partial_weight"):
    assert f[k].shape == (32, 32, 32), (k, f[k].shape)
assert f.attrs["voxel_size_m"] > 0 and len(f.attrs["origin_table"]) == 3
p = f["occupancy_probability"][:]
assert p.min() >= 0 and p.max() <= 1
PY
# Bad input: non-zero exit and a message naming the problem.
if "$reconstruct" --depth "$dir/nope.png" --intrinsics 525,525,319.5,239.5 --output "$dir/x" 2> "$dir/e1"; then
  echo "accepted a missing file"; exit 1; fi
grep -q "nope.png" "$dir/e1" || { cat "$dir/e1"; exit 1; }
if "$reconstruct" --depth "${view}_depth.png" --intrinsics 525,abc,319.5,239.5 --output "$dir/x" 2> "$dir/e2"; then
  echo "accepted bad intrinsics"; exit 1; fi
grep -q "abc" "$dir/e2" || { cat "$dir/e2"; exit 1; }
echo "not an image" > "$dir/bad.png"
if "$reconstruct" --depth "$dir/bad.png" --intrinsics 525,525,319.5,239.5 --output "$dir/x" 2> "$dir/e3"; then
  echo "accepted a corrupt image"; exit 1; fi
grep -q "bad.png" "$dir/e3" || { cat "$dir/e3"; exit 1; }
echo "simstack_reconstruct ok"
