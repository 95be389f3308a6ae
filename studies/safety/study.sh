#!/usr/bin/env bash
# The safety study (studies/safety/plan.md): KDDRL and D3QN+TD3 under +preset=safe, and IDM+MOBIL, on baseline,
# congested and braking at seeds 100-109, seed-major; then (PHASE=unshielded) every learning run's final policy
# evaluated again without the layer on the same test traffic, each into <SWEEP_DIR>_unshielded/<run name>/. Run it
# with the plan's pinned commit on the path (a checkout of it, its venv active):
#   bash studies/safety/study.sh [SWEEP_DIR]                      # default runs/safety
#   PHASE=unshielded bash studies/safety/study.sh [SWEEP_DIR]
# It resumes job by job: a finished run (summary.json) is skipped, a killed one continues from its newest checkpoint;
# an unshielded evaluation already made (its summary.json) is skipped. JOBS (default 2) at a time, one torch thread
# each.
set -euo pipefail
SWEEP=${1:-runs/safety}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} SWEEP
SEEDS=${SEEDS:-"100 101 102 103 104 105 106 107 108 109"}

jobs() {
  local seed sc
  for seed in $SEEDS; do for sc in baseline congested braking; do
    echo "seed=$seed +scenario=$sc +preset=safe algo=kddrl"
    echo "seed=$seed +scenario=$sc +preset=safe algo=d3qn_td3"
    echo "seed=$seed +scenario=$sc algo=idm_mobil"
  done; done
}

one() {  # a single-job sweep into the shared folder: its subdir is named as in a full sweep
  # shellcheck disable=SC2086
  python -m kddrl_trl.train -m progress=false resume="$SWEEP" $1 || echo "study.sh: job failed: $1" >&2
}

unshielded() {  # the final policy of each finished learning run, on its own scenario's test traffic, no layer
  local run name sc seed
  for run in "$SWEEP"/*__kddrl__* "$SWEEP"/*__d3qn_td3__*; do
    [ -f "$run/summary.json" ] || continue
    name=$(basename "$run")
    [ -f "${SWEEP}_unshielded/$name/summary.json" ] && continue
    sc=${name%%__*}; seed=${name##*__}
    echo "run=$run +scenario=$sc seed=$seed shield=none hydra.run.dir=${SWEEP}_unshielded/$name"
  done
}

unshielded_one() {
  # shellcheck disable=SC2086
  python -m kddrl_trl.evaluate progress=false $1 || echo "study.sh: evaluation failed: $1" >&2
}
export -f one unshielded_one
if [ "${PHASE:-}" = unshielded ]; then
  unshielded | xargs -d '\n' -P "${JOBS:-2}" -I{} bash -c 'unshielded_one "$1"' _ {}
else
  jobs | xargs -d '\n' -P "${JOBS:-2}" -I{} bash -c 'one "$1"' _ {}
fi
