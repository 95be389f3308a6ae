#!/usr/bin/env bash
# The periodic validation beside the training: how the records in this folder were made (2-core Intel Xeon, idle).
# BEFORE: a worktree of 54abe69; AFTER: one of the commit holding this folder.
set -euo pipefail
BEFORE=${BEFORE:-/tmp/ab_a}; AFTER=${AFTER:-/tmp/ab_b}
A150="seed=0 episodes=150 eval_episodes=30 train.eval_episodes=20 progress=false"
# ab_150_episodes.json: the arms side by side, one thread each
OMP_NUM_THREADS=1 PYTHONPATH=$BEFORE/src python -m kddrl_trl.train $A150 train.eval_every=0 hydra.run.dir=/tmp/abrun0_a &
OMP_NUM_THREADS=1 PYTHONPATH=$BEFORE/src python -m kddrl_trl.train $A150 train.eval_every=50 hydra.run.dir=/tmp/abrun_a &
wait
OMP_NUM_THREADS=1 PYTHONPATH=$AFTER/src python -m kddrl_trl.train $A150 train.eval_every=50 hydra.run.dir=/tmp/abrun_b3
for code in $BEFORE $AFTER; do  # one checkpoint, validated by each code
  OMP_NUM_THREADS=1 PYTHONPATH=$code/src python "$(dirname "$0")/same_validation.py" /tmp/abrun_b3 \
    /tmp/sameval3_$(basename $code).csv $A150 train.eval_every=50
done
# train_1000_episodes.json: the default job, each run alone, back to back
PYTHONPATH=$BEFORE/src python -m kddrl_trl.train progress=false hydra.run.dir=/tmp/full_old
PYTHONPATH=$BEFORE/src python -m kddrl_trl.train progress=false eval_episodes=100 train.eval_every=0 hydra.run.dir=/tmp/full_old0
PYTHONPATH=$AFTER/src python -m kddrl_trl.train progress=false eval_episodes=100 hydra.run.dir=/tmp/full_nice
OMP_NUM_THREADS=1 PYTHONPATH=$AFTER/src python -m kddrl_trl.train progress=false eval_episodes=100 hydra.run.dir=/tmp/full_new_1t
