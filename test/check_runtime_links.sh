#!/usr/bin/env bash
# Fails when a runtime binary (a node, the nodelet, the ROS or core library, a runtime tool)
# depends on the offline library, directly or through another library: the robot runs
# without the dataset, training and evaluation code.
# Usage: test/check_runtime_links.sh BINARY...
set -u
[ $# -gt 0 ] || { echo "usage: $0 BINARY..."; exit 2; }
fail=0
for bin in "$@"; do
  if [ ! -f "$bin" ]; then
    echo "$bin: missing"
    fail=1
    continue
  fi
  # NEEDED entries name direct dependencies; ldd resolves the whole tree. They must show the
  # core library (the core itself: the C++ library), or the check could see nothing.
  tree=$( (readelf -d "$bin" | grep NEEDED; ldd "$bin") 2>&1)
  seen='libsimstack_core\.so'
  [[ "$(basename "$bin")" == libsimstack_core.so* ]] && seen='libstdc\+\+\.so'
  if ! echo "$tree" | grep -qE "$seen"; then
    echo "$bin: readelf and ldd show no libsimstack_core (a static build, or the tools failed):"
    echo "$tree"
    fail=1
    continue
  fi
  hits=$(echo "$tree" | grep -o 'libsimstack_offline\.so[.0-9]*' | sort -u)
  if [ -n "$hits" ]; then
    echo "$bin links the offline library: $hits"
    fail=1
  fi
done
[ $fail -eq 0 ] && echo "runtime links ok: $# binaries without libsimstack_offline"
exit $fail
