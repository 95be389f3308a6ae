#!/usr/bin/env bash
# The braking study's runs (studies/braking/README.md), from a checkout of the study's commit of main; it resumes
# job by job (a finished training, summary.json, is skipped; a killed one continues from its newest checkpoint).
#   bash studies/braking/study.sh [SWEEP_DIR, default runs/braking]
# Section 4, the scenario check: KDDRL trained on braking as it is (release=sumo) at seeds 0-4, each trained
# policy then evaluated on the same test traffic with the programmed release (<run>/eval__braking__<seed>__<time>/).
# Section 3, the training length: KDDRL, then D3QN+TD3+LG, 3000 episodes on braking (validation every 200 episodes,
# on the validation traffic), seeds 0-4 (SWEEP/length_3000); then D3QN+TD3+LG's control, 1000 episodes as the paper
# trains, seeds 0-4 (SWEEP/length_1000; KDDRL's 1000-episode control is section 4's release_sumo).
# Section 5, the reward: KDDRL with env.reward=safe, seeds 0-4 (SWEEP/reward_safe; its control is release_sumo), then
# Ni and Peng with the paper's reward and with the safe one, seed by seed (SWEEP/reward_paper, SWEEP/reward_safe).
# JOBS (default 1) at a time, one torch thread each: the machine is shared with the verdict study's sweep.
set -euo pipefail
SWEEP=${1:-runs/braking}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}

jobs() {
  local seed algo
  for seed in 0 1 2 3 4; do echo "release_sumo $seed +scenario=braking algo=kddrl seed=$seed"; done
  for algo in kddrl d3qn_td3_lg; do for seed in 0 1 2 3 4; do
    echo "length_3000 $seed +scenario=braking algo=$algo seed=$seed episodes=3000"; done; done
  for seed in 0 1 2 3 4; do echo "length_1000 $seed +scenario=braking algo=d3qn_td3_lg seed=$seed"; done
  for seed in 0 1 2 3 4; do echo "reward_safe $seed +scenario=braking algo=kddrl seed=$seed env.reward=safe"; done
  for algo in ni peng; do for seed in 0 1 2 3 4; do
    echo "reward_paper $seed +scenario=braking algo=$algo seed=$seed"
    echo "reward_safe $seed +scenario=braking algo=$algo seed=$seed env.reward=safe"; done; done
}

one() {  # <arm> <seed> <overrides...>: train into SWEEP/<arm>; release_sumo: then evaluate with the programmed release
  local arm=$1 seed=$2
  shift 2
  # shellcheck disable=SC2068
  python -m kddrl_trl.train -m progress=false resume="$SWEEP/$arm" $@ || { echo "study.sh: job failed: $*" >&2; return; }
  [ "$arm" = release_sumo ] || return 0
  local run="$SWEEP/$arm/braking__kddrl__$seed"
  ls "$run"/eval__braking__*/summary.json > /dev/null 2>&1 && return
  python -m kddrl_trl.evaluate run="$run" +scenario=braking seed="$seed" env.braking.release=programmed progress=false \
    || echo "study.sh: evaluation failed: $run" >&2
}
export -f one
export SWEEP
jobs | xargs -d '\n' -P "${JOBS:-1}" -I{} bash -c 'one $1' _ {}
