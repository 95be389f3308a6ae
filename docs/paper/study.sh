#!/usr/bin/env bash
# The paper's verdict study: every cell of Tables II-V at seeds 0-4, and the preset's confirmation at seeds 5-9.
# Run it from a checkout of the study's pinned commit (docs/paper/README.md); it resumes job by job: a finished run
# (summary.json) is skipped, a killed one continues from its newest checkpoint.
#   bash docs/paper/study.sh [SWEEP_DIR] [extra Hydra overrides...]
# Launcher: joblib, 2 runs at a time, one torch thread each (JOBS=N to change). On a Ray cluster instead:
#   LAUNCHER="hydra/launcher=ray" bash docs/paper/study.sh ...   (the optional extra .[ray])
set -euo pipefail
SWEEP=${1:-runs/paper}
shift || true
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
LAUNCHER=${LAUNCHER:-"hydra/launcher=joblib hydra.launcher.n_jobs=${JOBS:-2}"}
run() { python -m kddrl_trl.train -m $LAUNCHER progress=false resume="$SWEEP" "$@"; }
# Table II (baseline: KDDRL, Ni, Peng, the two unified systems) and Table V (baseline: the ablations), IDM+MOBIL;
# seed-major, so every system's seed 0 lands first
run seed=0,1,2,3,4 +scenario=baseline \
    algo=ni,pasac_unified,kddrl,peng,d3qn_unified,d3qn_td3,d3qn_td3_lg,kddrl_same_clock,idm_mobil "$@"
# Tables III (congested) and IV (braking)
run seed=0,1,2,3,4 +scenario=congested,braking algo=kddrl,ni,peng,idm_mobil "$@"
# The preset's confirmation on fresh seeds (never used to choose it), for KDDRL and D3QN+TD3
run seed=5,6,7,8,9 +scenario=baseline,braking +preset=plus algo=kddrl,d3qn_td3 "$@"
