#!/usr/bin/env bash
# Fails when the user's manuals hold what belongs in CHANGELOG.md or points to a design document
# that is not the package's own: a date (YYYY-MM-DD) or an issue number ("issue 25") in
# docs/reference.md, README.md, docs/results.md, docs/experiments.md, docs/design.md or
# docs/benchmarks.md (docs state what is, not how it came to be); a link to DESIGN.md or
# ../shared/*.md (../shared/data and ../shared/paper excepted; the design is docs/design.md) in
# docs/reference.md or README.md; or a README.md over 12,000 bytes (the README is a manual of
# about 10 KB, details live in docs/). Each finding is named FILE:LINE.
# Usage: test/check_docs.sh [PACKAGE_DIR]
set -u
root=${1:-$(dirname "$0")/..}
cd "$root" || exit 1
files="docs/reference.md README.md"
history_files="docs/results.md docs/experiments.md docs/design.md docs/benchmarks.md"
readme_limit=12000
fail=0
report() {  # report FILE REASON GREP_HITS ("LINE:TEXT" per line)
  [ -n "$3" ] || return 0
  fail=1
  while IFS= read -r hit; do
    echo "$1:${hit%%:*}: $2: ${hit#*:}"
  done <<< "$3"
}
for f in $files $history_files; do
  if [ ! -f "$f" ]; then
    echo "$f: missing"
    fail=1
    continue
  fi
  report "$f" "a date (history goes to CHANGELOG.md)" \
    "$(grep -nE '20[0-9][0-9]-[01][0-9]-[0-3][0-9]' "$f")"
  report "$f" "an issue number (history goes to CHANGELOG.md)" \
    "$(grep -niE '\bissues? +#?[0-9]+' "$f")"
  case " $history_files " in *" $f "*) continue ;; esac  # dates and issue numbers only
  report "$f" "DESIGN.md (the design is docs/design.md)" "$(grep -n 'DESIGN\.md' "$f")"
  report "$f" "a ../shared document (the design is docs/design.md)" \
    "$(grep -noE '\.\./shared/[A-Za-z0-9_./-]*\.md' "$f" |
      grep -vE '^[0-9]+:\.\./shared/(data|paper)([/._-]|$)' | grep -v 'DESIGN\.md')"
done
if [ -f README.md ]; then
  size=$(wc -c < README.md)
  if [ "$size" -gt "$readme_limit" ]; then
    echo "README.md:1: $size bytes, over $readme_limit: move details to docs/"
    fail=1
  fi
fi
[ $fail -eq 0 ] &&
  echo "docs ok: $files $history_files checked (README.md $(wc -c < README.md) bytes)"
exit $fail
