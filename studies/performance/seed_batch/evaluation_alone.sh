#!/usr/bin/env bash
# The batched seeds' final policies (latest checkpoint) evaluated alone, by kddrl_trl.evaluate, on their own
# test traffic; and one alone run re-evaluated the same way (the evaluator's reproduction of itself). Results:
# each run's eval__baseline__<seed>__<time>/summary.json, gathered in evaluation_alone.json:
#   bash studies/performance/seed_batch/evaluation_alone.sh [checkout]
set -uo pipefail
cd "${1:-.}"  # a checkout of the pinned commit (4b290611) holding runs/seed_batch, its venv active
export OMP_NUM_THREADS=1
B=runs/seed_batch/batched/baseline__kddrl__seeds200-209
{ echo "runs/seed_batch/alone/baseline__kddrl__200 200"; for s in 200 201 202 203 204 205 206 207 208 209; do echo "$B/baseline__kddrl__$s $s"; done; } |
  xargs -P 2 -L 1 bash -c 'python -m kddrl_trl.evaluate run=$0 seed=$1 progress=false > /tmp/diag_$1_$(basename $(dirname $0)).log 2>&1; echo done $0 $?'
