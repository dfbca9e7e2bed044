#!/usr/bin/env bash
# The README's first command's build (`cargo build --release`) from fresh
# clones of the given commits, all at once so that every build sees the same
# load: for each commit, the packages it builds (`cargo tree -e normal,build
# --prefix none`, each name and version once) and the build's wall time.
# The clones and their target folders are removed afterwards.
#
# Usage: tools/build_time.sh COMMIT [COMMIT ...]   (from the repository)
set -u
repo=$(git rev-parse --show-toplevel)
work=$(mktemp -d /tmp/insuwb-build-time.XXXXXX)
one() {
  local rev=$1 d=$work/$1
  git clone -q "$repo" "$d" && git -C "$d" checkout -q "$rev" || return 1
  local n s e rc
  n=$(cd "$d" && cargo tree -e normal,build --prefix none 2>/dev/null |
    sed 's/ (\*)//; s/ (proc-macro)//' | awk '{print $1, $2}' | sort -u | wc -l)
  s=$(date +%s)
  (cd "$d" && cargo build --release >"$work/$rev.log" 2>&1)
  rc=$?
  e=$(date +%s)
  echo "$rev packages=$n build_s=$((e - s)) rc=$rc"
}
for rev in "$@"; do one "$rev" & done
wait
rm -rf "$work"
