#!/usr/bin/env bash
# Builds the libFuzzer target for the depth readers with clang (Debian's clang and
# libclang-rt-dev carry libFuzzer) against the build's simstack_core, seeds it with a valid PCD,
# PNG and TIFF, and runs it. Crashing inputs are kept as BUILD_DIR/fuzz/crash-* files.
# Usage: test/fuzz/run_fuzz.sh [SECONDS=180] [BUILD_DIR=build] [DEVEL_DIR=BUILD_DIR/devel]
# (directories absolute or from the package directory; ctest `fuzz_depth_readers` runs it for
# 20 s, skipped without clang)
set -eu
seconds=${1:-180}
build=${2:-build}
root=$(cd "$(dirname "$0")/../.." && pwd)
[[ "$build" = /* ]] || build=$root/$build
devel=${3:-$build/devel}
[[ "$devel" = /* ]] || devel=$root/$devel
work=$build/fuzz
mkdir -p "$work/corpus"
lib=$devel/lib
# 77: ctest's skip.
command -v clang++ > /dev/null || { echo "needs clang: sudo apt-get install clang libclang-rt-dev"; exit 77; }
clang++ -std=c++17 -O1 -g -fsanitize=fuzzer -I"$root/include" -I/usr/include/eigen3 \
  "$root/test/fuzz/fuzz_depth_readers.cpp" -L"$lib" -lsimstack_core -Wl,-rpath,"$lib" \
  -o "$work/fuzz_depth_readers"
# Seeds: one valid file of each format, the first byte choosing the reader.
seed=$(mktemp -d)
trap 'rm -rf "$seed"' EXIT
"$lib/simstack/simstack_generate" --scenes 1 --seed 1 --resolution 16 --output "$seed/d.h5" \
  --views 1 > /dev/null
convert "$seed/d_views/scene_000000_view_0_depth.png" -resize 64x48 "$seed/small.png"
{ printf '\001'; cat "$seed/small.png"; } > "$work/corpus/seed_png"
{ printf '\000'; printf '# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 2\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 4\nDATA ascii\n0 0 1\n1 0 1\n0 1 1\n1 1 1\n'; } > "$work/corpus/seed_pcd"
convert -size 8x6 xc:gray -depth 32 -define quantum:format=floating-point "$seed/f.tiff" 2> /dev/null || true  # writes the file, complains about a tag
{ printf '\002'; cat "$seed/f.tiff"; } > "$work/corpus/seed_tiff"
cd "$work"
# A crash ends it with 1, not libFuzzer's default 77 (ctest's skip here).
./fuzz_depth_readers -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=10 -error_exitcode=1 \
  -timeout_exitcode=1 \
  -max_len=65536 corpus
