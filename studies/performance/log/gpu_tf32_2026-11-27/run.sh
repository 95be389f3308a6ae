#!/usr/bin/env bash
# Device check: matmul_precision=high (TensorFloat-32 matmuls) against highest (IEEE float32) in training on a GPU.
# The braking scenario, seeds 0-3, each trained EP episodes and evaluated on EV episodes with device=cuda at both
# precisions: 8 runs at once, 2 cores each, sharing the GPU (each run's timings are an upper bound of the run alone;
# the two precisions of one seed run side by side under the same load).
# No SUMO on the device machine: the libsumo wheel and its shared libraries travel in three pieces (calls 1-2 copy
# theirs to /root/g with STAGE=copy), the road files are pre-built (KDDRL_TRL_CACHE).
set -u
export PYTHONUNBUFFERED=1
G=/root/g S=/root/g/site
mkdir -p $G
for c in .gpu/c*; do [ -d "$c" ] && cp -r "$c"/. $G/; done
[ "${STAGE:-run}" = copy ] && { ls -la $G; nvidia-smi -L; nproc; exit 0; }
mkdir -p $S && cat $G/libsumo.part0? | xz -d | tar x -C $S || exit 2
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target $S $G/whl/*.whl || exit 3
cp -r $G/sumo_data $S/ && mkdir -p $S/sumo $S/sumo_data/bin && : > $S/sumo_data/bin/sumo
echo "SUMO_HOME = '$S/sumo_data'" > $S/sumo/__init__.py
export SUMO_HOME=$S/sumo_data PYTHONPATH=$PWD/src:$S KDDRL_TRL_CACHE=$G/cache LD_LIBRARY_PATH=$G/xlibs:${LD_LIBRARY_PATH:-}
nvidia-smi -L; nproc
python3 -c "import torch, torchrl, tensordict, libsumo, kddrl_trl; print(torch.__version__, torchrl.__version__, \
tensordict.__version__, torch.cuda.get_device_name())" 2>&1 | tail -3 || exit 5
EP=${EP:-300} EV=${EV:-200} T=${RUN_TIMEOUT:-470}
nvidia-smi dmon -s u -d 5 > $OUT/dmon.txt 2>&1 & DMON=$!
TS=(); command -v taskset > /dev/null && TS=(taskset -c)
go() {  # seed precision cores
  local s=$1 p=$2 c=$3 d=/tmp/tf32/${2}_$1 T0=$(date +%s)
  mkdir -p /tmp/tf32
  OMP_NUM_THREADS=1 TORCHINDUCTOR_CACHE_DIR=/tmp/ind_${p}_$s timeout $T ${TS[@]+"${TS[@]}"} ${TS[@]+$c} python3 -m kddrl_trl.train \
    +scenario=braking seed=$s episodes=$EP eval_episodes=$EV train.eval_every=0 device=cuda matmul_precision=$p \
    progress=false hydra.run.dir=$d > $d.log 2>&1
  echo "$p seed=$s cores=$c rc=$? wall=$(( $(date +%s) - T0 )) s" | tee -a $OUT/wall.txt
}
i=0 pids=()
for s in ${SEEDS:-0 1 2 3}; do for p in highest high; do go $s $p $((2*i))-$((2*i+1)) & pids+=($!) i=$((i+1)); done; done
wait "${pids[@]}"
kill $DMON 2>/dev/null
tar cJf $OUT/tf32_runs.tar.xz -C /tmp --exclude=checkpoints --exclude=logs --exclude=videos tf32
ls -la $OUT
