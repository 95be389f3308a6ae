#!/usr/bin/env bash
cd "$(git rev-parse --show-toplevel)"  # BEFORE: a worktree of 8de2a6c at /tmp/ab_a; AFTER: this commit
A150="seed=0 episodes=150 eval_episodes=30 train.eval_every=50 train.eval_episodes=20 progress=false"
OMP_NUM_THREADS=1 PYTHONPATH=/tmp/ab_a/src python -m kddrl_trl.train $A150 hydra.run.dir=/tmp/ab150/before > /tmp/ab150/before.log 2>&1 &
OMP_NUM_THREADS=1 PYTHONPATH=/work/main/src python -m kddrl_trl.train $A150 hydra.run.dir=/tmp/ab150/after > /tmp/ab150/after.log 2>&1 &
wait
echo done > /tmp/ab150/done
