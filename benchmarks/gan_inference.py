"""Latency of the batched generative-model inference modules, as the transforms will call them.

For batches of 1, 8 and 32 environments (x 3 leaders) this times, in one run, one call of
``TrajGANPredictor`` (one sample, and the mean of K = 8 samples) and of ``LCGANPredictor`` built from
the weights shipped with the package, on raw observations of ``FakeHighwayEnv`` plus the IDM prior
and key gaps from the transforms ``IDMPrior`` + ``KeyGapsFromPrior``, i.e. inputs of the right shapes and ranges. Prints
a table (median microseconds per call and per environment) and writes ``benchmarks/results/gan_inference.json``.

    python -m benchmarks.gan_inference [--envs 1 8 32] [--calls 300] [--device cpu]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

from kddrl_trl.atomic_files import write_json_atomic
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.generative import load_predictor
from kddrl_trl.transforms import IDMPrior, KeyGapsFromPrior


def inputs(num_envs: int, device: torch.device):
    """A raw observation batch with the derived keys the predictors read."""
    env = FakeHighwayEnv("congested", num_roads=num_envs, seed=0)
    td = env.rollout(25, break_when_any_done=False)[:, -1]["next"]
    return KeyGapsFromPrior()(IDMPrior()(td)).to(device)


def time_calls(module, td, calls: int) -> float:
    for _ in range(10):
        module(td.clone())
    if td.device.type == "cuda":
        torch.cuda.synchronize()
    times = []
    for _ in range(calls):
        x = td.clone()
        t0 = time.perf_counter()
        module(x)
        if td.device.type == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e6


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--envs", type=int, nargs="+", default=[1, 8, 32])
    ap.add_argument("--calls", type=int, default=300)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "gan_inference.json"))
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    models = {
        "trajgan (1 sample)": load_predictor("trajgan", num_samples=1).to(device),
        "trajgan (mean of 8)": load_predictor("trajgan", num_samples=8, reduce="mean").to(device),
        "lcgan": load_predictor("lcgan").to(device),
    }
    rows = []
    for n in args.envs:
        td = inputs(n, device)
        for name, module in models.items():
            us = time_calls(module, td, args.calls)
            rows.append({"model": name, "envs": n, "us_per_call": us, "us_per_env": us / n})
    print(f"\ngenerative inference, {device}, {args.threads} thread(s), median of {args.calls} calls")
    print(f"{'model':22s} {'envs':>5s} {'µs / call':>11s} {'µs / env':>10s}")
    for r in rows:
        print(f"{r['model']:22s} {r['envs']:5d} {r['us_per_call']:11.1f} {r['us_per_env']:10.1f}")
    write_json_atomic(
        args.out,
        {
            "machine": {
                "platform": platform.platform(),
                "python": sys.version.split()[0],
                "torch": torch.__version__,
                "device": str(device),
            },
            "args": vars(args),
            "rows": rows,
        },
    )
    print(f"results written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
