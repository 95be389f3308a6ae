#!/usr/bin/env bash
# Copy the study's finished runs (those with summary.json) into studies/paper/runs/, without checkpoints, TorchRL logs
# or per-run curve images (the report redraws them), their CSVs and logs xz-compressed (the report reads them as they are),
# the training records cut to the columns the report and a reader of the learning curves use (studies/compact_records.py):
#   bash studies/paper/collect.sh <study sweep dir> [destination, default studies/paper/runs]
set -euo pipefail
SRC=${1:?usage: collect.sh <study sweep dir> [destination]}
DST=${2:-$(dirname "$0")/runs}
mkdir -p "$DST"
[ -f "$DST/multirun.yaml" ] || cp "$SRC/multirun.yaml" "$DST/" 2>/dev/null || true
for run in "$SRC"/*/; do
  name=$(basename "$run")
  [ -f "$run/summary.json" ] || continue
  [ -f "$DST/$name/summary.json" ] && continue  # collected already: a finished run's records never change (a resumed
  # sweep rewrites a skipped job's .hydra/ with its own launch; the copy here keeps the run's own)
  mkdir -p "$DST/$name"
  (cd "$run" && find . -path ./checkpoints -prune -o -path ./logs -prune -o -name training_curves.png -prune -o -type f -print) \
    | while read -r f; do
        mkdir -p "$DST/$name/$(dirname "$f")"
        case "$f" in
          *.csv|*.log) [ -f "$DST/$name/$f.xz" ] || xz -9 -c "$run/$f" > "$DST/$name/$f.xz" ;;
          *) cp "$run/$f" "$DST/$name/$f" ;;
        esac
      done
done
python "$(dirname "$0")/../compact_records.py" "$DST"
ls "$DST"
