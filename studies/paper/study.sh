#!/usr/bin/env bash
# The paper's verdict study: every cell of Tables II-V at seeds 0-4, and the preset's confirmation at seeds 5-9.
# PHASE=extension: the primary cells of the analysis plan (studies/paper/plan.md) at seeds 5-14, without the shield,
# baseline and congested first; braking only with BRAKING=1 (it waits for the braking study's scenario check).
# Run it from a checkout of the study's pinned commit (studies/paper/README.md); it resumes job by job: a finished run
# (summary.json) is skipped, a killed one continues from its newest checkpoint.
#   bash studies/paper/study.sh [SWEEP_DIR] [extra Hydra overrides...]
#   PHASE=extension bash studies/paper/study.sh runs/paper_5-14
# Every job runs in a process of its own, JOBS (default 2) at a time, one torch thread each: a worker process that
# ran earlier jobs (joblib's, Ray's) keeps their compiled graphs, and the pinned commit's learner then hits
# TorchDynamo's recompile limit and falls back to eager (about 3x slower; the numbers are the same).
# On a Ray cluster instead, one Hydra sweep per table through the Ray launcher (the optional extra .[ray]):
#   LAUNCHER="hydra/launcher=ray" bash studies/paper/study.sh ...
set -euo pipefail
SWEEP=${1:-runs/paper}
shift || true
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
EXTRA=("$@")

extension() {  # the plan's cells at seeds 5-14, seed-major; IDM+MOBIL where b88a84a has not evaluated it yet
  local seed sc algo
  for seed in 5 6 7 8 9 10 11 12 13 14; do
    for algo in kddrl ni peng d3qn_td3 d3qn_td3_lg kddrl_same_clock; do echo "seed=$seed +scenario=baseline algo=$algo"; done
    for algo in kddrl ni peng; do echo "seed=$seed +scenario=congested algo=$algo"; done
    echo "seed=$seed +scenario=congested algo=idm_mobil"
    [ "$seed" -lt 10 ] || echo "seed=$seed +scenario=baseline algo=idm_mobil"
  done
  [ "${BRAKING:-0}" = 1 ] || return 0
  for seed in 5 6 7 8 9 10 11 12 13 14; do
    for algo in kddrl ni peng; do echo "seed=$seed +scenario=braking algo=$algo"; done
    [ "$seed" -lt 10 ] || echo "seed=$seed +scenario=braking algo=idm_mobil"
  done
}

jobs() {  # one line of Hydra overrides per job, seed-major, so every system's seed 0 lands first
  local seed sc algo
  # Table II (baseline: KDDRL, Ni, Peng, the two unified systems), Table V (baseline: the ablations), IDM+MOBIL
  for seed in 0 1 2 3 4; do
    for algo in ni pasac_unified kddrl peng d3qn_unified d3qn_td3 d3qn_td3_lg kddrl_same_clock idm_mobil; do
      echo "seed=$seed +scenario=baseline algo=$algo"; done; done
  # Tables III (congested) and IV (braking)
  for seed in 0 1 2 3 4; do for sc in congested braking; do for algo in kddrl ni peng idm_mobil; do
    echo "seed=$seed +scenario=$sc algo=$algo"; done; done; done
  # The preset's confirmation on fresh seeds (never used to choose it), for KDDRL and D3QN+TD3, and IDM+MOBIL on the
  # same seeds (the preset's goals are relative to it)
  for seed in 5 6 7 8 9; do for sc in baseline braking; do for algo in kddrl d3qn_td3; do
    echo "seed=$seed +scenario=$sc +preset=plus algo=$algo"; done; done; done
  for seed in 5 6 7 8 9; do for sc in baseline braking; do echo "seed=$seed +scenario=$sc algo=idm_mobil"; done; done
}

if [ -n "${LAUNCHER:-}" ]; then
  run() { python -m kddrl_trl.train -m $LAUNCHER progress=false resume="$SWEEP" "$@" ${EXTRA[@]+"${EXTRA[@]}"}; }
  if [ "${PHASE:-}" = extension ]; then
    run seed=5,6,7,8,9,10,11,12,13,14 +scenario=baseline algo=kddrl,ni,peng,d3qn_td3,d3qn_td3_lg,kddrl_same_clock
    run seed=5,6,7,8,9,10,11,12,13,14 +scenario=congested algo=kddrl,ni,peng,idm_mobil
    run seed=10,11,12,13,14 +scenario=baseline algo=idm_mobil
    if [ "${BRAKING:-0}" = 1 ]; then
      run seed=5,6,7,8,9,10,11,12,13,14 +scenario=braking algo=kddrl,ni,peng
      run seed=10,11,12,13,14 +scenario=braking algo=idm_mobil
    fi
    exit
  fi
  run seed=0,1,2,3,4 +scenario=baseline \
      algo=ni,pasac_unified,kddrl,peng,d3qn_unified,d3qn_td3,d3qn_td3_lg,kddrl_same_clock,idm_mobil
  run seed=0,1,2,3,4 +scenario=congested,braking algo=kddrl,ni,peng,idm_mobil
  run seed=5,6,7,8,9 +scenario=baseline,braking +preset=plus algo=kddrl,d3qn_td3
  run seed=5,6,7,8,9 +scenario=baseline,braking algo=idm_mobil
  exit
fi

one() {  # a single-job sweep into the shared folder: its subdir is named as in a full sweep
  # shellcheck disable=SC2086
  python -m kddrl_trl.train -m progress=false resume="$SWEEP" $1 $STUDY_EXTRA \
    || echo "study.sh: job failed: $1" >&2
}
export -f one
export SWEEP STUDY_EXTRA="${EXTRA[*]:-}"
if [ "${PHASE:-}" = extension ]; then extension; else jobs; fi | xargs -d '\n' -P "${JOBS:-2}" -I{} bash -c 'one "$1"' _ {}
