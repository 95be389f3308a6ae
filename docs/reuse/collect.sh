#!/usr/bin/env bash
# Copy the reuse study's finished results into docs/reuse/runs/ (the training runs as docs/paper/collect.sh copies
# them: no checkpoints, CSVs and logs xz-compressed; the example's JSON results as they are), then the results:
#   bash docs/reuse/collect.sh <study output dir, e.g. ../reuse/runs/reuse>
set -euo pipefail
SRC=${1:?usage: collect.sh <study output dir>}
HERE=$(dirname "$0")
for sweep in highwayenv_gans sumo_gans highwayenv_driver; do
  [ -d "$SRC/$sweep" ] && bash "$HERE/../paper/collect.sh" "$SRC/$sweep" "$HERE/runs/$sweep"
done
if [ -d "$SRC/example" ]; then
  mkdir -p "$HERE/runs/example"
  for f in "$SRC"/example/*.json; do [ -e "$f" ] && cp "$f" "$HERE/runs/example/"; done
fi
python "$HERE/report.py" "$HERE/runs" --out "$HERE"
