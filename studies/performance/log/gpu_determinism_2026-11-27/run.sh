#!/usr/bin/env bash
# Device check: do the learner's CUDA-graphed updates repeat bit for bit? (benchmarks/gpu_determinism.py)
# Four processes at once on one GPU: two with float32 matmuls (the default), two with TF32 (matmul_precision=high);
# then each pair compared. No TorchRL on the device machine: its wheels travel in the carry (.gpu/c2/whl).
. studies/performance/log/device_setup.sh  # the wheels installed, PYTHONPATH set (these lines were inline when it ran)
B=benchmarks/gpu_determinism.py
for p in highest high; do
  for r in a b; do
    timeout ${T:-240} python3 $B --matmul-precision $p --out $OUT/${p}_$r.json > $OUT/${p}_$r.log 2>&1 &
  done
done
wait
for p in highest high; do
  tail -1 $OUT/${p}_a.log; tail -1 $OUT/${p}_b.log
  python3 $B --compare $OUT/${p}_a.json $OUT/${p}_b.json --out $OUT/compare_$p.json
done
