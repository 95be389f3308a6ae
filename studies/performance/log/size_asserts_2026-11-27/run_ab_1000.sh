#!/usr/bin/env bash
# the default job, before (8de2a6c) and after (3d44d53: size asserts off) side by side, one torch thread each
cd "$(git rev-parse --show-toplevel)"  # worktrees: /tmp/ab_a at 8de2a6c, /tmp/ab_b at 3d44d53
OMP_NUM_THREADS=1 PYTHONPATH=/tmp/ab_a/src python -m kddrl_trl.train progress=false eval_episodes=100 hydra.run.dir=/tmp/ab1000/before > /tmp/ab1000/before.log 2>&1 &
OMP_NUM_THREADS=1 PYTHONPATH=/tmp/ab_b/src python -m kddrl_trl.train progress=false eval_episodes=100 hydra.run.dir=/tmp/ab1000/after > /tmp/ab1000/after.log 2>&1 &
wait
date > /tmp/ab1000/done
