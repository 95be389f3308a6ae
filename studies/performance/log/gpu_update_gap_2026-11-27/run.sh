#!/usr/bin/env bash
# Device check: what separates our CUDA-graphed TD3 update from TorchRL's own (benchmarks/gpu_update_gap.py), with
# torch.compile's default mode at minibatches 128 and 256, then max-autotune-no-cudagraphs at 128.
# No TorchRL on the device machine: its wheels (cp312) travel in the carry (.gpu/c2/whl); SUMO is not needed.
. studies/performance/log/device_setup.sh  # the wheels installed, PYTHONPATH set (these lines were inline when it ran)
nproc
python3 -c "import torch, torchrl, tensordict; print(torch.__version__, torchrl.__version__, tensordict.__version__, \
torch.cuda.get_device_name())" 2>&1 | tail -1 || exit 5
quiet() { grep -v -iE "warn|inline_inbuilt|LazyTensorStorage|^\s*$"; }
T0=$(date +%s)
timeout ${T1:-330} python3 benchmarks/gpu_update_gap.py --out $OUT/gap_default.json 2>&1 | quiet
echo "default: rc=${PIPESTATUS[0]} $(( $(date +%s) - T0 )) s"
T0=$(date +%s)
timeout ${T2:-190} python3 benchmarks/gpu_update_gap.py --mode max-autotune-no-cudagraphs --batches 128 \
  --arms ours torchrl_mujoco --out $OUT/gap_max_autotune.json 2>&1 | quiet
echo "max-autotune-no-cudagraphs: rc=${PIPESTATUS[0]} $(( $(date +%s) - T0 )) s"
# Results: gap_default.json (the first python call above; the max-autotune call timed out while autotuning, no JSON).
# gap_reversed.json: the second device call, right after, on the same warm machine, the arms and batches reversed:
#   python3 benchmarks/gpu_update_gap.py --batches 256 128 --arms torchrl_our_shapes torchrl_mujoco \
#     ours_no_embedding ours --repeats 5 --out $OUT/gap_reversed.json
