#!/usr/bin/env bash
# same-hour alternating A/B of the torch thread count: 300 episodes of the default job, each run alone
# Runs one after another, alone on the idle 2-core Intel Xeon; summary.json from the runs by hand (see its "how").
cd "$(git rev-parse --show-toplevel)"
A="seed=0 episodes=300 eval_episodes=10 progress=false"
for arm in t2 t1 t1 t2 t2 t1; do
  i=$((${i:-0}+1))
  if [ $arm = t1 ]; then export OMP_NUM_THREADS=1; else unset OMP_NUM_THREADS; fi
  s=$(date +%s.%N)
  python -m kddrl_trl.train $A hydra.run.dir=${OUT:-/tmp/thr}/run${i}_$arm > ${OUT:-/tmp/thr}/run${i}_$arm.log 2>&1
  echo "$i $arm $(date +%H:%M:%S) process_s=$(echo "$(date +%s.%N) - $s" | bc)" >> ${OUT:-/tmp/thr}/done.txt
done
