#!/usr/bin/env bash
# Section 1 (studies/braking/README.md): trained policies evaluated again on braking's test traffic, as they were trained
# (release=sumo), by code whose records carry the onset and crash fields (EpisodeTracker ONSET_FIELDS, CRASH_FIELDS).
# Each run's evaluation goes to <run>/eval__braking__<seed>__fields/ (skipped when its summary.json is there):
#   bash studies/braking/evaluate_fields.sh <training run folder>...
# Run it with the code of a commit of main that writes those fields (the runs may come from an earlier commit: the
# learner's checkpoint is what is read). One evaluation at a time, one torch thread.
set -euo pipefail
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
for run in "$@"; do
  run=${run%/}
  seed=${run##*__}
  out="$run/eval__braking__${seed}__fields"
  [ -f "$out/summary.json" ] && continue
  python -m kddrl_trl.evaluate run="$run" +scenario=braking seed="$seed" progress=false "hydra.run.dir=$out" \
    || echo "evaluate_fields.sh: evaluation failed: $run" >&2
done
