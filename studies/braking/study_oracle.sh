#!/usr/bin/env bash
# Section 2 of the braking study (studies/braking/README.md), online: KDDRL with the event oracle
# (algo.transforms.event_oracle=true) and its control (KDDRL as it is), both from one checkout of main at a commit
# that has the oracle, 1000 episodes on braking, seeds 0-4; resumes job by job like study.sh:
#   bash studies/braking/study_oracle.sh [SWEEP_DIR, default runs/braking]
# JOBS (default 1) at a time, one torch thread each: the machine is shared with the verdict study's sweep.
set -euo pipefail
SWEEP=${1:-runs/braking}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}

jobs() {
  local seed
  for seed in 0 1 2 3 4; do
    echo "oracle +scenario=braking algo=kddrl seed=$seed algo.transforms.event_oracle=true"
    echo "control +scenario=braking algo=kddrl seed=$seed"
  done
}

one() {  # <arm> <overrides...>: train into SWEEP/<arm>
  local arm=$1
  shift
  # shellcheck disable=SC2068
  python -m kddrl_trl.train -m progress=false resume="$SWEEP/$arm" $@ || echo "study_oracle.sh: job failed: $*" >&2
}
export -f one
export SWEEP
jobs | xargs -d '\n' -P "${JOBS:-1}" -I{} bash -c 'one $1' _ {}
