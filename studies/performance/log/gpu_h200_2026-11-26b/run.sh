#!/usr/bin/env bash
# Device check (issue 41): a 1000-episode device=cuda training run with 1 and with 8 collection workers.
#   STAGE=unpack: libsumo only (call 1);  STAGE=run: wheels, stub, the two runs side by side on disjoint cores
set -u
export PYTHONUNBUFFERED=1
S=$PWD/.gpu/site
mkdir -p "$S"
if [ "${STAGE:-run}" = unpack ]; then
  tar xJf .gpu/libsumo.tar.xz -C "$S" && ls "$S"; df -h . | tail -1; exit
fi
[ -d "$S/libsumo" ] || { echo "libsumo missing: machine was not kept"; exit 9; }
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$S" .gpu/whl/*.whl || exit 3
cp -r .gpu/sumo_data "$S/"
mkdir -p "$S/sumo/bin" && : > "$S/sumo/bin/sumo" && echo "SUMO_HOME = '$S/sumo_data'" > "$S/sumo/__init__.py"
mkdir -p "$S/sumo_data/bin" && : > "$S/sumo_data/bin/sumo"
export SUMO_HOME=$S/sumo_data PYTHONPATH=$PWD/src:$S KDDRL_TRL_CACHE=$PWD/.gpu/cache LD_LIBRARY_PATH=$PWD/.gpu/xlibs:${LD_LIBRARY_PATH:-}
nvidia-smi -L; nproc
python3 -c "import torch, torchrl, tensordict, libsumo, kddrl_trl; print(torch.__version__, torchrl.__version__, tensordict.__version__, torch.cuda.get_device_name())" 2>&1 | tail -3 || exit 5
go() {  # workers cores
  local w=$1 cores=$2 T0=$(date +%s)
  TORCHINDUCTOR_CACHE_DIR=/tmp/ind_w$w timeout ${E2E_TIMEOUT:-560} taskset -c $cores python3 -m kddrl_trl.train \
      device=cuda collector.workers=$w eval_episodes=20 hydra.run.dir=/tmp/e2e_w$w progress=true > $OUT/e2e_w$w.log 2>&1
  echo "e2e workers=$w cores=$cores rc=$? wall=$(( $(date +%s) - T0 )) s" | tee -a $OUT/e2e_wall.txt
  cp /tmp/e2e_w$w/summary.json $OUT/e2e_w$w.json 2>/dev/null
}
go 8 0-11 & go 1 12-15 & wait
for w in 8 1; do grep -E "train:" $OUT/e2e_w$w.log | tr '\r' '\n' | grep -E "ep/s|s/ep" | tail -2; done
