#!/usr/bin/env bash
# Copy the reuse study's finished results into studies/reuse/runs/ (the training runs as studies/paper/collect.sh copies
# them: no checkpoints, CSVs and logs xz-compressed; the example's JSON results as they are, its logs xz-compressed),
# then write the results of every arm (results.md/json), the example's training curves (curves.md/json) and the
# package's report of the training runs (report/: kddrl_trl.report):
#   bash studies/reuse/collect.sh <study output dir, e.g. ../reuse/runs/reuse>
set -euo pipefail
SRC=${1:?usage: collect.sh <study output dir>}
HERE=$(dirname "$0")
for sweep in highwayenv_gans sumo_gans highwayenv_driver; do
  [ -d "$SRC/$sweep" ] && bash "$HERE/../paper/collect.sh" "$SRC/$sweep" "$HERE/runs/$sweep"
done
for dir in "$SRC"/example*/; do  # every part of the example (study.sh: PART)
  [ -d "$dir" ] || continue
  example=$(basename "$dir")
  mkdir -p "$HERE/runs/$example"
  for f in "$SRC/$example"/*.json; do
    [ -e "$f" ] || continue
    cp "$f" "$HERE/runs/$example/"
    log="${f%.json}.log"  # its training curve's source (curves.py), xz-compressed
    [ -f "$log" ] && xz -c "$log" > "$HERE/runs/$example/$(basename "$log").xz"
  done
done
# the records of the runs landed earlier, which main keeps in its history (kddrl_trl.devtools.records)
(cd "$HERE" && python -m kddrl_trl.devtools.records restore reuse > /dev/null)
python "$HERE/report.py" "$HERE/runs" --out "$HERE"
python "$HERE/curves.py" "$HERE/runs" --out "$HERE"  # the example's training curves, from its logs
# Figs. 16-17 from the metrics of the lcGAN these runs used (HighwayEnv's)
OMP_NUM_THREADS=1 python -m kddrl_trl.report "$HERE/runs" out="$HERE/report" title="Reuse on HighwayEnv report" \
  lcgan_metrics="$HERE/../../src/kddrl_trl/generative/weights/highwayenv/lcgan.metrics.json"
