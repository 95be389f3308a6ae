#!/usr/bin/env bash
# Device check, prepared for the next lent GPU: the per-seed cost of the learner's update against N seeds batched
# (benchmarks/seed_batch.py, HierarchicalLearner(seeds=N), compiled arms CUDA-graphed), and how many seeds one GPU
# takes before the per-seed cost stops falling. One call, about 9 minutes on an H200 (each compiled arm compiles
# for about 25 s; ../seed_batch_gpu_2026-12-04/); T1 bounds the sweep, T2 the largest N: the benchmark writes its
# table only at the end, so a bound that cuts it loses the sweep.
# No TorchRL on the device machine: its wheels (cp312) travel in the carry (.gpu/c2/whl, git-ignored), made here with
#   pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 -d .gpu/c2/whl torchrl==0.14.1 \
#     tensordict==0.14.3 importlib_metadata orjson pyvers hoptorch hydra-core omegaconf gymnasium farama-notifications
#   pip wheel --no-deps -w .gpu/c2/whl antlr4-python3-runtime==4.9.3   # Hydra's parser: a source release only
# (the versions of this checkout's venv; cloudpickle, zipp and packaging are in the image); SUMO is not needed.
# Run with: device run, command "bash studies/performance/log/seed_batch_gpu/run.sh", carry [".gpu"], timeout 580.
. studies/performance/log/device_setup.sh
python3 -c "import torch, torchrl, tensordict; print(torch.__version__, torchrl.__version__, tensordict.__version__, \
torch.cuda.get_device_name())" 2>&1 | tail -1 || exit 5
quiet() { grep -v -iE "warn|inline_inbuilt|LazyTensorStorage|^\s*$"; }
T0=$(date +%s)
timeout ${T1:-420} python3 -m benchmarks.seed_batch --device cuda --seeds 1 4 16 64 --updates 200 --repeats 3 \
  --note "lent GPU, studies/performance/log/seed_batch_gpu/run.sh" --out $OUT/seed_batch_gpu.json 2>&1 | quiet
echo "seeds 1-64: rc=${PIPESTATUS[0]} $(( $(date +%s) - T0 )) s"
T0=$(date +%s)  # the largest batches, compiled only in effect: where the per-seed cost flattens
timeout ${T2:-120} python3 -m benchmarks.seed_batch --device cuda --seeds 256 1024 --updates 50 --repeats 2 \
  --out $OUT/seed_batch_gpu_large.json 2>&1 | quiet
echo "seeds 256-1024: rc=${PIPESTATUS[0]} $(( $(date +%s) - T0 )) s"
