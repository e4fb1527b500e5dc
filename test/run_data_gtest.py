#!/usr/bin/env python3
"""Runs a gtest binary's tests that need ../shared/data and tells ctest what happened.

ctest's SKIP_REGULAR_EXPRESSION would call the whole run skipped when any test skips, hiding
another test's failure; here any failure fails, no test at all fails (a renamed suite), and the
run is skipped (exit 77, the test's SKIP_RETURN_CODE) only when every test skipped.

Usage: run_data_gtest.py BINARY [GTEST ARGUMENTS...]
"""
import json
import os
import subprocess
import sys
import tempfile

SKIPPED = 77


def main():
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as scratch:
        report = os.path.join(scratch, "report.json")
        rc = subprocess.call(sys.argv[1:] + ["--gtest_output=json:" + report])
        if rc != 0:
            return rc
        try:
            with open(report) as f:
                suites = json.load(f).get("testsuites", [])
        except (OSError, ValueError) as e:
            print("run_data_gtest.py: no readable gtest report (%s)" % e, file=sys.stderr)
            return 1
    tests = [t for s in suites for t in s.get("testsuite", [])]
    if not tests:
        print("run_data_gtest.py: no test matched %s" % " ".join(sys.argv[2:]), file=sys.stderr)
        return 1
    skipped = [t for t in tests if t.get("result") == "SKIPPED"]
    if len(skipped) == len(tests):
        print("run_data_gtest.py: all %d tests skipped (their data is absent)" % len(tests))
        return SKIPPED
    return 0


if __name__ == "__main__":
    sys.exit(main())
