#!/usr/bin/env bash
# Runs one rostest (its own master on a free port) against the devel space of a build, and
# fails unless every test case in its results passed (rostest can exit 0 also when a test
# node died before writing any result).
# Usage: run_rostest.sh DEVEL_DIR FILE.test   (DEVEL_DIR: the devel space, or a build holding devel/)
set -e
devel=$1
[ -f "$devel/setup.bash" ] || devel=$1/devel
test_file=$2
# shellcheck disable=SC1091
source "$devel/setup.bash"  # (not under set -u: Debian's ROS profile reads unset variables)
set -u
export ROS_HOSTNAME=localhost
# ROS Python nodes start with "env python3": the system interpreter, not a pyenv one on PATH.
export PATH=/usr/bin:$PATH
ROS_HOME=$(mktemp -d)
export ROS_HOME
trap 'rm -rf "$ROS_HOME"' EXIT
rostest "$test_file"
/usr/bin/python3 - "$ROS_HOME/test_results" <<'PY'
import glob, sys, xml.etree.ElementTree as ET
files = [f for f in glob.glob(sys.argv[1] + "/**/*.xml", recursive=True) if "rostest-" not in f]
cases = bad = 0
for f in files:
    root = ET.parse(f).getroot()
    for suite in ([root] if root.tag == "testsuite" else root.iter("testsuite")):
        cases += int(suite.get("tests", 0))
        bad += int(suite.get("failures", 0)) + int(suite.get("errors", 0))
print(f"rostest results: {cases} test cases, {bad} failed or in error ({len(files)} files)")
sys.exit(1 if bad or cases == 0 else 0)
PY
