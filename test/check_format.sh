#!/usr/bin/env bash
# Fails when a C++ file of the package differs from what clang-format (.clang-format: Google
# style, 100 columns) makes of it. Fix with: clang-format -i $(git ls-files '*.cpp' '*.h')
set -u
root=${1:-$(dirname "$0")/..}
cd "$root" || exit 1
command -v clang-format > /dev/null || { echo "clang-format is missing (scripts/setup)"; exit 1; }
files=$(find src include test -name '*.cpp' -o -name '*.h' | sort)
clang-format --dry-run --Werror $files || exit 1
echo "formatted: $(echo "$files" | wc -l) files checked"
