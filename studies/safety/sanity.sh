#!/usr/bin/env bash
# The learner's sanity check (studies/safety/plan.md): D3QN+TD3 on one lane whose leader brakes to a stop at a
# random frame of the first 30 s, no layer, 400 training and 200 test episodes, seeds 0-2, under the paper's reward
# and under the safe one; one sweep folder per reward (the run folders are named by scenario, algo and seed):
#   bash studies/safety/sanity.sh [SWEEP_PREFIX]          # default runs/safety_sanity -> ..._paper, ..._safe
set -euo pipefail
PREFIX=${1:-runs/safety_sanity}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} PREFIX
TASK="+scenario=braking algo=d3qn_td3 env.num_lanes=1 env.braking.trigger_frames=300 episodes=400 eval_episodes=200"
export TASK
for seed in 0 1 2; do for reward in paper safe; do echo "$seed $reward"; done; done \
  | xargs -P "${JOBS:-2}" -L1 bash -c '
      # shellcheck disable=SC2086
      python -m kddrl_trl.train -m progress=false resume="${PREFIX}_$1" seed=$0 env.reward=$1 $TASK \
        || echo "sanity.sh: job failed: seed $0 reward $1" >&2'
