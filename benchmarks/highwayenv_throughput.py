"""Throughput of the HighwayEnv adapter (``kddrl_trl.envs.highwayenv``, extra ``.[highway]``) against HighwayEnv alone.

Arms, in one run, taking turns (``--repeats`` rounds; the median of each arm is reported), all on highway-v0 with
3 lanes, ``--vehicles`` background vehicles, 10 Hz policy and simulation frequency, random actions:

(a) ``bare_fps``: HighwayEnv's own ``highway-v0`` (Kinematics observation, ``DiscreteMetaAction``) through the
    Gymnasium API, reset when an episode ends: the simulator's limit.
(b) ``adapter_fps``: ``HighwayEnvAdapter`` (K roads) with random (lane command, acceleration) actions, through
    ``env.rollout`` (TorchRL auto-resets).
(c) ``stack_fps``: (b) inside ``TransformedEnv(..., make_kddrl_transforms())`` (eager; the leader history kept by
    ``LeaderHistory``).

Ego-frames per second = frames x K / wall seconds. The ratios (b)/(a) and (c)/(b) are what compare; absolute
figures depend on the machine and its load.

    python -m benchmarks.highwayenv_throughput                       # K = 1, 4; 300 frames per arm
    python -m benchmarks.highwayenv_throughput --roads 1 --frames 100 --repeats 1 --out /tmp/hw.json

Writes ``benchmarks/results/highwayenv_throughput.json`` (``--out``).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)

from torchrl.envs import TransformedEnv  # noqa: E402

from kddrl_trl.baselines import RandomDrivingPolicy  # noqa: E402
from kddrl_trl.envs.highwayenv import HighwayEnvAdapter, HighwayEnvOptions  # noqa: E402
from kddrl_trl.transforms import make_kddrl_transforms  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "highwayenv_throughput.json"


def bare(k: int, frames: int, vehicles: int, seed: int) -> float:
    """(a) HighwayEnv alone, k instances stepped in turn, random meta-actions."""
    from highway_env.envs.highway_env import HighwayEnv

    config = {
        "lanes_count": 3,
        "vehicles_count": vehicles,
        "policy_frequency": 10,
        "simulation_frequency": 10,
        "duration": 1e9,
    }
    envs = [HighwayEnv(config=config) for _ in range(k)]
    rng = np.random.default_rng(seed)
    for i, env in enumerate(envs):
        env.reset(seed=seed + i)
    t0 = time.perf_counter()
    for _ in range(frames):
        for env in envs:
            _, _, terminated, truncated, _ = env.step(int(rng.integers(5)))
            if terminated or truncated:
                env.reset()
    return frames * k / (time.perf_counter() - t0)


def adapter(k: int, frames: int, vehicles: int, seed: int, stack: bool) -> float:
    """(b) / (c) the adapter's rollout, bare or with the KDDRL stack."""
    env = HighwayEnvAdapter(num_roads=k, seed=seed, options=HighwayEnvOptions(vehicles_count=vehicles))
    env = TransformedEnv(env, make_kddrl_transforms()) if stack else env
    policy = RandomDrivingPolicy(generator=torch.Generator().manual_seed(seed))
    try:
        env.rollout(5, policy, break_when_any_done=False)  # warm-up, not timed
        t0 = time.perf_counter()
        env.rollout(frames, policy, break_when_any_done=False)
        return frames * k / (time.perf_counter() - t0)
    finally:
        env.close()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--roads", type=int, nargs="+", default=[1, 4])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--vehicles", type=int, default=30)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    rows = []
    for k in args.roads:
        runs = {"bare_fps": [], "adapter_fps": [], "stack_fps": []}
        for rep in range(args.repeats):  # arms take turns: a load change hits all of them
            seed = args.seed + rep
            runs["bare_fps"].append(bare(k, args.frames, args.vehicles, seed))
            runs["adapter_fps"].append(adapter(k, args.frames, args.vehicles, seed, stack=False))
            runs["stack_fps"].append(adapter(k, args.frames, args.vehicles, seed, stack=True))
        row = {"num_roads": k, **{name: statistics.median(v) for name, v in runs.items()}, "runs": runs}
        row["adapter_over_bare"] = row["adapter_fps"] / row["bare_fps"]
        row["stack_over_adapter"] = row["stack_fps"] / row["adapter_fps"]
        rows.append(row)
    print(
        f"{'K':>3} {'bare fps':>10} {'adapter fps':>12} {'+stack fps':>11} {'adapter/bare':>13} {'stack/adapter':>14}"
    )
    for r in rows:
        print(
            f"{r['num_roads']:>3} {r['bare_fps']:>10.1f} {r['adapter_fps']:>12.1f} {r['stack_fps']:>11.1f} "
            f"{r['adapter_over_bare']:>13.2f} {r['stack_over_adapter']:>14.2f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "rows": rows,
        "machine": {"platform": platform.platform(), "torch": torch.__version__},
    }
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(payload, indent=2))
    tmp.replace(args.out)
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
