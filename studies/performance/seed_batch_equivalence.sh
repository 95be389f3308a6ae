#!/usr/bin/env bash
# The runs of a seed-batch equivalence study: KDDRL, each seed alone (a sweep) and the same seeds in batches, on one
# machine. studies/performance/seed_batch_plan.md (the defaults: seeds 200-209, one batch) and
# studies/performance/seed_batch_confirm_plan.md (BATCHES: three batches of ten). Run it from a checkout of the
# plan's pinned commit, its venv active (this script may be main's: the code it runs is the checkout's):
#   bash studies/performance/seed_batch_equivalence.sh [OUT]   # default runs/seed_batch
# BATCHES: the batches, space-separated, each a comma-separated list of seeds; the alone arm runs every seed of
# them. Per scenario the jobs go batch 1, its seeds alone, batch 2, its seeds alone, ..., so that both arms advance
# together. Two jobs at a time (JOBS), one torch thread each; it resumes job by job (resume=true: finished runs are
# skipped, killed ones continue from their checkpoint). SCENARIOS (default "baseline braking") picks the scenarios.
# LAUNCH_BY and BATCH_LAUNCH_BY (epoch seconds, optional): an alone run, or a batch, due to start later is not
# started (it says so; the next call of the same line starts it), so that a session's end stops no job.
set -euo pipefail
OUT=${1:-runs/seed_batch}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
BATCHES=${BATCHES:-200,201,202,203,204,205,206,207,208,209}
jobs() {
  local sc batch seed
  for sc in ${SCENARIOS:-baseline braking}; do
    for batch in $BATCHES; do
      echo "batched $sc $batch"
      for seed in ${batch//,/ }; do echo "alone $sc $seed"; done
    done
  done
}
slot() {
  local arm sc seeds by
  read -r arm sc seeds <<< "$1"
  if [ "$arm" = batched ]; then by=${BATCH_LAUNCH_BY:-}; else by=${LAUNCH_BY:-}; fi
  if [ -n "$by" ] && [ "$(date +%s)" -gt "$by" ]; then
    echo "seed_batch_equivalence.sh: not started (past its launch time): $1" >&2
    return 0
  fi
  if [ "$arm" = batched ]; then
    python -m kddrl_trl.train -m progress=false +scenario="$sc" "seeds=[$seeds]" \
      hydra.sweep.dir="$OUT/batched" resume=true || echo "seed_batch_equivalence.sh: failed: $1" >&2
  else
    python -m kddrl_trl.train -m progress=false +scenario="$sc" seed="$seeds" \
      hydra.sweep.dir="$OUT/alone" resume=true || echo "seed_batch_equivalence.sh: failed: $1" >&2
  fi
}
export -f slot
export OUT LAUNCH_BY BATCH_LAUNCH_BY
jobs | xargs -d '\n' -P "${JOBS:-2}" -I{} bash -c 'slot "$1"' _ {}
