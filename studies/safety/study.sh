#!/usr/bin/env bash
# The safety study (studies/safety/plan.md): KDDRL and D3QN+TD3 under +preset=safe, and IDM+MOBIL, on baseline,
# congested and braking at seeds 100-109, seed-major; each learning run's final policy is then evaluated again
# without the layer on the same test traffic (shield=none), into <SWEEP_DIR>_unshielded/<run name>/, in the same
# slot right after its training: a checkpoint does not outlive the machine it was written on, so the evaluation that
# reads it cannot wait for a later session. Run it from a checkout of the plan's pinned commit, its venv active
# (this script may be main's: the code it runs is the checkout's):
#   bash studies/safety/study.sh [SWEEP_DIR]                # default runs/safety
#   STOP_AT=07:20 bash studies/safety/study.sh runs/safety  # start no job that would end after 07:20 (a session's end)
#   LANDED=<main>/studies/safety bash studies/safety/study.sh runs/safety   # skip the runs landed on main already
#   SEEDS=103 ALGOS=kddrl bash studies/safety/study.sh runs/ship   # some seeds and algos only (a rerun to ship,
#                                                                    studies/safety/ship.py)
# It resumes job by job: a finished run (summary.json) with its unshielded evaluation is skipped, a killed one
# continues from its newest checkpoint. JOBS (default 2) at a time, one torch thread each. A job's expected wall
# (EXPECT_KDDRL, EXPECT_D3QN_TD3, EXPECT_IDM_MOBIL, minutes: 32, 24, 5 by default, measured two at a time on a
# 2-core machine) decides whether it starts before STOP_AT; what it skipped is logged.
set -euo pipefail
SWEEP=${1:-runs/safety}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} SWEEP
export STOP_EPOCH=$([ -n "${STOP_AT:-}" ] && date -d "$STOP_AT" +%s || echo 0)
export EXPECT_KDDRL=${EXPECT_KDDRL:-32} EXPECT_D3QN_TD3=${EXPECT_D3QN_TD3:-24} EXPECT_IDM_MOBIL=${EXPECT_IDM_MOBIL:-5}
SEEDS=${SEEDS:-"100 101 102 103 104 105 106 107 108 109"} ALGOS=${ALGOS:-"kddrl d3qn_td3 idm_mobil"}

jobs() {
  local seed sc algo
  for seed in $SEEDS; do for sc in baseline congested braking; do for algo in $ALGOS; do
    echo "$seed $sc $algo"
  done; done; done
}

slot() {  # one job: its training (a single-job sweep into the shared folder), then its unshielded evaluation
  local seed sc algo name expect preset
  read -r seed sc algo <<< "$1"
  name="${sc}__${algo}__${seed}"
  local where
  for where in "$SWEEP" ${LANDED:+"$LANDED/runs"}; do  # done here, or landed on main already (LANDED)
    if [ -f "$where/$name/summary.json" ] && { [ "$algo" = idm_mobil ] || [ -f "${where}_unshielded/$name/summary.json" ]; }; then
      return
    fi
  done
  case $algo in kddrl) expect=$EXPECT_KDDRL;; d3qn_td3) expect=$EXPECT_D3QN_TD3;; *) expect=$EXPECT_IDM_MOBIL;; esac
  if [ "$STOP_EPOCH" -gt 0 ] && [ $(( $(date +%s) + expect * 60 )) -gt "$STOP_EPOCH" ]; then
    echo "study.sh: $name not started: it would end after STOP_AT" >&2
    return
  fi
  preset=$([ "$algo" = idm_mobil ] && echo "" || echo "+preset=safe")
  # shellcheck disable=SC2086
  python -m kddrl_trl.train -m progress=false resume="$SWEEP" seed="$seed" +scenario="$sc" $preset algo="$algo" \
    || { echo "study.sh: job failed: $name" >&2; return; }
  if [ "$algo" != idm_mobil ] && [ ! -f "${SWEEP}_unshielded/$name/summary.json" ]; then
    python -m kddrl_trl.evaluate progress=false run="$SWEEP/$name" +scenario="$sc" seed="$seed" shield=none \
      hydra.run.dir="${SWEEP}_unshielded/$name" || echo "study.sh: evaluation failed: $name" >&2
  fi
}
export -f slot
jobs | xargs -d '\n' -P "${JOBS:-2}" -I{} bash -c 'slot "$1"' _ {}
