#!/usr/bin/env bash
# On a new machine (or a fresh worktree), put the study's finished runs back into its sweep folder, so that
# study.sh skips them (a job whose folder holds summary.json is finished) and runs only what is missing:
#   bash studies/paper/restore.sh <study sweep dir> [records folder, default studies/paper/runs]
set -euo pipefail
DST=${1:?usage: restore.sh <study sweep dir>}
SRC=${2:-$(dirname "$0")/runs}
mkdir -p "$DST"
for run in "$SRC"/*/; do
  name=$(basename "$run")
  [ -f "$run/summary.json" ] && [ ! -e "$DST/$name" ] || continue
  cp -r "$run" "$DST/$name"
  echo "restored $name"
done
