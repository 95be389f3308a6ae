"""Cost of the KDDRL predictive-state stack on the SUMO highway env, measured in one run.

For K in {1, 8, 32} roads (``--roads``) this times ``env.rollout(frames, policy)`` of ``SumoHighwayEnv``
bare, inside ``TransformedEnv(env, make_kddrl_transforms())`` (IDM prior -> trajGAN -> MOBIL prior ->
lcGAN prior, the shipped weights, one generator call per frame for all K envs x 3 leaders), and with
``make_kddrl_transforms(compile=True)`` (physics priors and GAN inference through ``torch.compile``; the
one-off compile happens in the untimed warm-up), with the IDM+MOBIL rule policy, and reports ego-frames per second and
the stack's cost ``1 - fps_with / fps_bare``. Goal: cost <= 25 % at K = 32. Prints a table and writes
``benchmarks/results/transform_overhead.json``.

    python benchmarks/transform_overhead.py [--roads 1 8 32] [--frames 1000] [--repeats 3]
"""
from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

import torch
from torchrl.envs import TransformedEnv

from kddrl_trl.baselines import IDMMobilPolicy
from kddrl_trl.envs import SumoHighwayEnv
from kddrl_trl.io import write_json_atomic
from kddrl_trl.transforms import make_kddrl_transforms


def measure(k: int, frames: int, stack: str, seed: int) -> float:
    """``stack``: "none", "eager" or "compiled"."""
    env = SumoHighwayEnv("baseline", num_roads=k, seed=seed)
    try:
        run = env if stack == "none" else TransformedEnv(env, make_kddrl_transforms(seed=seed,
                                                                                   compile=stack == "compiled"))
        policy = IDMMobilPolicy()
        run.rollout(20, policy, break_when_any_done=False)
        t0 = time.perf_counter()
        run.rollout(frames, policy, break_when_any_done=False)
        return frames * k / (time.perf_counter() - t0)
    finally:
        env.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--roads", type=int, nargs="+", default=[1, 8, 32])
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "transform_overhead.json"))
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for k in args.roads:
        fps = {"none": [], "eager": [], "compiled": []}
        for _ in range(args.repeats):  # interleaved, so drifts of the machine hit all alike
            for name in fps:
                fps[name].append(measure(k, args.frames, name, args.seed))
        b, f, c = (statistics.median(fps[n]) for n in ("none", "eager", "compiled"))
        rows.append({"num_roads": k, "env_fps": b, "env_stack_fps": f, "env_stack_compiled_fps": c,
                     "cost": 1.0 - f / b, "cost_compiled": 1.0 - c / b, "fps_all": fps})
        print(f"K={k}: bare {b:,.0f}  stack {f:,.0f}  compiled stack {c:,.0f} ego-frames/s", flush=True)
    print(f"\nKDDRL transform stack on SumoHighwayEnv (baseline, IDM+MOBIL policy), {args.frames} frames, "
          f"median of {args.repeats}")
    print(f"{'K':>3s} {'env fps':>10s} {'+stack fps':>11s} {'cost':>7s} {'+compiled fps':>14s} {'cost':>7s}"
          "  goal (<= 25 % at K=32)")
    for r in rows:
        goal = "-"
        if r["num_roads"] >= 32:
            goal = f"eager {'PASS' if r['cost'] <= 0.25 else 'FAIL'}, compiled {'PASS' if r['cost_compiled'] <= 0.25 else 'FAIL'}"
        print(f"{r['num_roads']:3d} {r['env_fps']:10,.0f} {r['env_stack_fps']:11,.0f} {100 * r['cost']:6.1f}% "
              f"{r['env_stack_compiled_fps']:14,.0f} {100 * r['cost_compiled']:6.1f}%  {goal}")
    write_json_atomic(args.out, {"machine": {"platform": platform.platform(), "python": sys.version.split()[0],
                                             "torch": torch.__version__}, "args": vars(args), "rows": rows})
    print(f"results written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
