#!/usr/bin/env bash
# The runs of studies/performance/seed_batch_plan.md: KDDRL on baseline and braking, seeds 200-209, each seed alone
# (a sweep) and the ten in one batch, on one machine. Run it from a checkout of the plan's pinned commit, its venv
# active (this script may be main's: the code it runs is the checkout's):
#   bash studies/performance/seed_batch_equivalence.sh [OUT]   # default runs/seed_batch
# Two jobs at a time (JOBS), one torch thread each; it resumes job by job (resume=true: finished runs are skipped,
# killed ones continue from their checkpoint). The batched arm runs one job per scenario. SCENARIOS (default
# "baseline braking") picks the scenarios, so that a scenario's two arms run in one session on one machine.
set -euo pipefail
OUT=${1:-runs/seed_batch}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
SEEDS=200,201,202,203,204,205,206,207,208,209
jobs() {
  local sc
  for sc in ${SCENARIOS:-baseline braking}; do
    echo "batched $sc"
    for seed in ${SEEDS//,/ }; do echo "alone $sc $seed"; done
  done
}
slot() {
  local arm sc seed
  read -r arm sc seed <<< "$1"
  if [ "$arm" = batched ]; then
    python -m kddrl_trl.train -m progress=false +scenario="$sc" "seeds=[$SEEDS]" \
      hydra.sweep.dir="$OUT/batched" resume=true || echo "seed_batch_equivalence.sh: failed: $1" >&2
  else
    python -m kddrl_trl.train -m progress=false +scenario="$sc" seed="$seed" \
      hydra.sweep.dir="$OUT/alone" resume=true || echo "seed_batch_equivalence.sh: failed: $1" >&2
  fi
}
export -f slot
export OUT SEEDS
jobs | xargs -d '\n' -P "${JOBS:-2}" -I{} bash -c 'slot "$1"' _ {}
