#!/usr/bin/env bash
# Copy the later evaluations of already collected training runs (<run>/eval__*/ folders with summary.json that the
# destination's copy of the run lacks) as studies/paper/collect.sh copies runs: no TorchRL logs or videos, CSVs and
# logs xz-compressed; prints the folders copied (for git add -f):
#   bash studies/braking/collect_evaluations.sh <sweep dir> <destination, e.g. studies/braking/runs/release_sumo>
set -euo pipefail
SRC=${1:?usage: collect_evaluations.sh <sweep dir> <destination>}
DST=${2:?usage: collect_evaluations.sh <sweep dir> <destination>}
for ev in "$SRC"/*/eval__*/; do
  [ -f "$ev/summary.json" ] || continue
  run=$(basename "$(dirname "$ev")")
  out="$DST/$run/$(basename "$ev")"
  [ -d "$DST/$run" ] && [ ! -f "$out/summary.json" ] || continue
  (cd "$ev" && find . -path ./logs -prune -o -path ./videos -prune -o -type f -print) | while read -r f; do
    mkdir -p "$out/$(dirname "$f")"
    case "$f" in
      *.csv|*.log) xz -9 -c "$ev/$f" > "$out/$f.xz" ;;
      *) cp "$ev/$f" "$out/$f" ;;
    esac
  done
  echo "$out"
done
