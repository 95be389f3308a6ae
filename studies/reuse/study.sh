#!/usr/bin/env bash
# Do the predictive-state transforms help on a simulator that is not ours? Every arm on HighwayEnv (highway-v0,
# the optional extra .[highway]), seeds 0-2 (and 3-6 for (c), (d), (e)), the same budget for every learning arm:
# 300 training episodes on 4 roads and no periodic evaluation, then 100 greedy episodes on evaluation seeds
# (seed + 1,000,000) that training never saw.
#   (a) examples/transforms_in_torchrl_td3.py, with the transforms (its GANs trained on HighwayEnv's traffic)
#   (b) the same example without them (raw observations only)
#   (c) kddrl with the GANs trained on our SUMO traffic          (algo.transforms.weights=sumo)
#   (d) kddrl with the GANs trained on HighwayEnv's traffic      (the default on env=highwayenv)
#   (e) d3qn_td3 (the same agents, no predictive states)
#   (f) idm_mobil (our IDM+MOBIL policy through the adapter's action)
#   (g) HighwayEnv's own IDM/MOBIL vehicle as the ego                 (env.highwayenv.ego_driver=highwayenv)
# PART=example_safe: the example as it now stands, seeds 0-4 (OUT/example_safe), the same budget:
#   (h) with the transforms, the safe reward (the example's default), (i) the same without the transforms,
#   (j) the reference: HighwayEnv's IDM driving the ego with its lane kept (--reference; no training)
# PART=example_default: the same three arms at the example's own default budget, seeds 0-4 (OUT/example_default):
#   1000 training episodes on 8 roads, 100 greedy episodes on the evaluation traffic of 8 roads:
#   (n) with the transforms, (o) without, (p) the reference on that traffic
# PART=example_default_100k: the same with the 100,000-frame replay buffer the example first had (--buffer 100000;
#   OUT/example_default_100k): (k) with the transforms, (l) without, (m) the reference
# PART=example_best: the example_default arms keeping the greedy policy of the best validation (--validate-every 100
#   --validate-episodes 24; OUT/example_best), each JSON with the last policy's evaluation beside the kept one's:
#   (q) with the transforms, (r) without, (s) the reference; (t) and (u): the last policies of (q) and (r)
# PART=example_scaled: as example_best, the observation divided by fixed physical scales (--obs-scale;
#   OUT/example_scaled): (v) with the transforms, (w) without, (x) the reference; (y) and (z) the last policies
# SEEDS (default 0 1 2 3 4) and ARMS (default "reference transforms no-transforms"): the seeds and arms of an
#   example part, e.g. SEEDS=0 ARMS=no-transforms for a first look
# Run it from a checkout of one commit (studies/reuse/README.md); it resumes job by job (a finished run is skipped,
# a killed one continues from its newest checkpoint; an example arm with its JSON is skipped):
#   bash studies/reuse/study.sh [OUT_DIR]
# Every job runs in a process of its own, JOBS (default 1) at a time, one torch thread each.
set -euo pipefail
OUT=${1:-runs/reuse}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
EPISODES=300
ROADS=4
EVAL=100
case "${PART:-}" in
  example_default | example_default_100k | example_best | example_scaled) EPISODES=1000 ROADS=8 ;;  # its defaults
esac
COMMON="env=highwayenv episodes=$EPISODES eval_episodes=$EVAL train.eval_every=0 progress=false"

jobs() {  # seed-major, so that every arm's seed 0 lands first
  local seed
  case "${PART:-}" in
    example_safe | example_default | example_default_100k | example_best | example_scaled)
      for seed in ${SEEDS:-0 1 2 3 4}; do
        for arm in ${ARMS:-reference transforms no-transforms}; do
          echo "example $OUT/$PART seed=$seed $arm"
        done
      done
      return
      ;;
  esac
  for seed in 0 1 2; do
    echo "train $OUT/highwayenv_gans seed=$seed algo=kddrl"
    echo "example $OUT/example seed=$seed transforms"
    echo "example $OUT/example seed=$seed no-transforms"
    echo "train $OUT/sumo_gans seed=$seed algo=kddrl algo.transforms.weights=sumo"
    echo "train $OUT/highwayenv_gans seed=$seed algo=d3qn_td3"
    echo "train $OUT/highwayenv_gans seed=$seed algo=idm_mobil"
    echo "train $OUT/highwayenv_driver seed=$seed algo=idm_mobil env.highwayenv.ego_driver=highwayenv"
  done
  for seed in 3 4 5 6; do  # the three KDDRL arms, whose (d) - (e) and (c) - (e) 3 seeds could not settle
    echo "train $OUT/highwayenv_gans seed=$seed algo=kddrl"
    echo "train $OUT/sumo_gans seed=$seed algo=kddrl algo.transforms.weights=sumo"
    echo "train $OUT/highwayenv_gans seed=$seed algo=d3qn_td3"
  done
}

one() {
  # shellcheck disable=SC2086
  set -- $1
  local kind=$1 dir=$2 seed=${3#seed=}
  shift 3
  if [ "$kind" = train ]; then
    python -m kddrl_trl.train -m resume="$dir" seed="$seed" $COMMON "$@" || echo "study.sh: job failed: $*" >&2
    return
  fi
  local flag="" name="$1"
  [ "$name" = no-transforms ] && flag=--no-transforms
  [ "$name" = reference ] && flag=--reference
  if [ "$dir" = "$OUT/example" ]; then
    flag="$flag --reward paper"  # (a), (b): the paper's reward, as they ran
  else
    flag="$flag --reward safe"
  fi
  [ "$dir" = "$OUT/example_default_100k" ] && flag="$flag --buffer 100000"
  case "$dir" in
    "$OUT/example_best") flag="$flag --validate-every 100 --validate-episodes 24 --no-obs-scale" ;;
    "$OUT/example_scaled") flag="$flag --validate-every 100 --validate-episodes 24 --obs-scale" ;;
    *) flag="$flag --validate-every 0 --no-obs-scale" ;;  # every part's whole recipe, whatever the defaults
  esac
  local out="$dir/${name}__$seed.json"
  [ -f "$out" ] && return
  mkdir -p "$dir"
  python examples/transforms_in_torchrl_td3.py --env highwayenv $flag --seed "$seed" --roads "$ROADS" \
    --episodes $EPISODES --eval-episodes $EVAL --out "$out.tmp" > "$dir/${name}__$seed.log" 2>&1 \
    && python -c 'import json, sys; d = json.load(open(sys.argv[1])); d["commit"] = sys.argv[2]
json.dump(d, open(sys.argv[1], "w"), indent=1)' "$out.tmp" "$(git rev-parse --short HEAD)" \
    && mv "$out.tmp" "$out" || echo "study.sh: example failed: $name seed $seed" >&2
}
export -f one
export OUT COMMON EPISODES ROADS EVAL
jobs | xargs -d '\n' -P "${JOBS:-1}" -I{} bash -c 'one "$1"' _ {}
