#!/usr/bin/env bash
# Device check: where the GPU TD3 update's time goes (benchmarks/gpu_update_gap.py --breakdown): raw graph replays,
# the update without CudaGraphModule's synchronize, the host's time alone, kernels per update from the profiler;
# then the same with TorchInductor's combo kernels (horizontal fusion) at minibatch 256.
# No TorchRL on the device machine: its wheels (cp312) travel in the carry (.gpu/c2/whl); SUMO is not needed.
. studies/performance/log/device_setup.sh  # the wheels installed, PYTHONPATH set (these lines were inline when it ran)
nproc
python3 -c "import torch, torchrl, tensordict; print(torch.__version__, torchrl.__version__, tensordict.__version__, \
torch.cuda.get_device_name())" 2>&1 | tail -1 || exit 5
quiet() { grep -v -iE "warn|inline_inbuilt|LazyTensorStorage|^\s*$|record_function"; }
T0=$(date +%s)
timeout ${T1:-300} python3 benchmarks/gpu_update_gap.py --breakdown --out $OUT/breakdown_default.json 2>&1 | quiet
echo "default: rc=${PIPESTATUS[0]} $(( $(date +%s) - T0 )) s"
T0=$(date +%s)
timeout ${T2:-150} python3 benchmarks/gpu_update_gap.py --breakdown --batches 256 --arms ours torchrl_mujoco \
  --inductor combo_kernels=True --out $OUT/breakdown_combo.json 2>&1 | quiet
echo "combo_kernels: rc=${PIPESTATUS[0]} $(( $(date +%s) - T0 )) s"
