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
  # main keeps each run's config.yaml migrated to the current schema, and the study's pinned commit refuses a run
  # folder whose config differs from its own: the run gets back the config it wrote (the commit that landed it)
  landed=$(git -C "$run" log --diff-filter=A --format=%H -1 -- config.yaml)
  [ -n "$landed" ] && git -C "$run" show "$landed:./config.yaml" > "$DST/$name/config.yaml"
  echo "restored $name"
done
