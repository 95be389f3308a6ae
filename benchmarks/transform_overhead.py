"""Cost of the KDDRL predictive-state stack on the SUMO highway env, measured in one run.

For K in {1, 8, 32} roads (``--roads``) ONE ``SumoHighwayEnv`` is driven by the IDM+MOBIL rule policy in
several ways ("arms") that take turns every ``--segment`` frames on the same simulation:

* ``none``: the bare env;
* ``eager``: inside ``TransformedEnv(env, make_kddrl_transforms())`` (IDM prior -> trajGAN -> MOBIL prior ->
  lcGAN prior, the shipped weights, run as one fused function per frame for all K envs);
* ``compiled``: ``make_kddrl_transforms(compile=True)``, the training default where a C++ compiler exists:
  the same fused function through ``torch.compile`` (the transforms' one compile site,
  ``kddrl_trl.transforms.stack.compiled_frames``), its warm graph called directly
  (``kddrl_trl.transforms.stack.warm_frames``);
* ``compiled_dynamo``: the same compiled stack with every call under TorchDynamo's guards (never warm).

One-off compilation happens in an untimed warm-up. Taking turns on one simulation pairs the arms in time and
traffic, so the drifts of this noisy machine hit all alike. Every arm steps with TorchRL's
``step_and_maybe_reset`` (partial resets included, as in a collector). Reports ego-frames per second and each
arm's cost ``1 - fps_arm / fps_none`` (time summed over all turns; the median of the per-turn ratios beside
it), what compiling earns: ``compile_gain = fps_compiled / fps_eager - 1`` (collection fps; a compile site is
kept only where it earns >= 5 %), and what calling the warm graph directly earns:
``direct_call_gain = fps_compiled / fps_compiled_dynamo - 1``. Goal: cost of the default compiled stack <= 25 % at
K = 32. Prints a table and writes ``benchmarks/results/transform_overhead.json``.

    python -m benchmarks.transform_overhead [--roads 1 8 32] [--frames 1500] [--segment 50]
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

from kddrl_trl import keys as K
from kddrl_trl.atomic_files import write_json_atomic
from kddrl_trl.baselines import IDMMobilPolicy
from kddrl_trl.envs import SumoHighwayEnv
from kddrl_trl.transforms import make_kddrl_transforms
from kddrl_trl.transforms.stack import warm_frames

ARMS = ("none", "eager", "compiled", "compiled_dynamo")
#: what the stack writes (dropped before a bare turn)
OUT_KEYS = (K.PRED_PRIOR_TRAJ, K.PRED_TRAJ, K.PRED_KEY_GAPS, K.PRIOR_P_MOBIL, K.PRIOR_P_LCGAN)


def make_arm(name: str, seed: int):
    """The transform stack of arm ``name`` (None: bare env)."""
    if name == "none":
        return None
    stack = make_kddrl_transforms(seed=seed, compile=name.startswith("compiled"))
    if name == "compiled_dynamo":
        warm_frames(stack).guard_every_call()
    return stack


def run_segment(run, stack, policy, td, frames: int):
    """``frames`` steps of ``run`` (TorchRL ``step_and_maybe_reset``) from the root ``td``: (seconds, last
    root). The stack's keys are first dropped from ``td`` and, for a stacked arm, recomputed (untimed), as a
    reset of that arm would have."""
    td = td.exclude(*OUT_KEYS)
    if stack is not None:
        td = stack._call(td)
    t0 = time.perf_counter()
    for _ in range(frames):
        _, td = run.step_and_maybe_reset(policy(td))
    return time.perf_counter() - t0, td


def measure(k: int, frames: int, segment: int, seed: int) -> dict[str, list[float]]:
    """Seconds per turn of each arm: ``frames // segment`` turns of ``segment`` frames on one simulation."""
    env = SumoHighwayEnv("baseline", num_roads=k, seed=seed)
    try:
        stacks = {n: make_arm(n, seed) for n in ARMS}
        runs = {n: env if s is None else TransformedEnv(env, s) for n, s in stacks.items()}
        policy = IDMMobilPolicy()
        td = env.reset()
        for name in ARMS:  # warm-up (and the one-off compilations), untimed
            _, td = run_segment(runs[name], stacks[name], policy, td, 20)
        times = {n: [] for n in ARMS}
        for _ in range(max(1, frames // segment)):
            for name in ARMS:
                dt, td = run_segment(runs[name], stacks[name], policy, td, segment)
                times[name].append(dt)
        return times
    finally:
        env.close()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--roads", type=int, nargs="+", default=[1, 8, 32])
    ap.add_argument("--frames", type=int, default=1500, help="frames per arm and K")
    ap.add_argument("--segment", type=int, default=50, help="frames per turn")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "transform_overhead.json"))
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for k in args.roads:
        times = measure(k, args.frames, args.segment, args.seed)
        n = len(times["none"]) * args.segment * k
        fps = {a: n / sum(times[a]) for a in ARMS}
        cost = {a: 1.0 - fps[a] / fps["none"] for a in ARMS}
        turn = {a: statistics.median(1.0 - t0 / t for t0, t in zip(times["none"], times[a])) for a in ARMS}
        gains = {}
        for name, before in (("compile_gain", "eager"), ("direct_call_gain", "compiled_dynamo")):
            gains[name] = fps["compiled"] / fps[before] - 1.0
            gains[f"median_turn_{name}"] = statistics.median(
                tb / tc - 1.0 for tb, tc in zip(times[before], times["compiled"])
            )
        rows.append(
            {"num_roads": k, "fps": fps, "cost": cost, "median_turn_cost": turn, **gains, "seconds_per_turn": times}
        )
        print(f"K={k}: " + "  ".join(f"{a} {fps[a]:,.0f}" for a in ARMS) + " ego-frames/s", flush=True)
    print(
        f"\nKDDRL transform stack on SumoHighwayEnv (baseline, IDM+MOBIL policy), {args.frames} frames per arm "
        f"in turns of {args.segment}: ego-frames/s, cost = 1 - fps / fps(none) (median over turns in brackets)"
    )
    print(
        f"{'K':>3s} {'none fps':>9s} "
        + " ".join(f"{a:>25s}" for a in ARMS[1:])
        + f" {'compile gain':>17s} {'direct call gain':>17s}  goal (compiled <= 25 % at K=32)"
    )
    for r in rows:
        cells = " ".join(
            f"{r['fps'][a]:>7,.0f} {100 * r['cost'][a]:6.1f}% ({100 * r['median_turn_cost'][a]:5.1f}%)"
            for a in ARMS[1:]
        )
        gain = " ".join(
            f"{100 * r[g]:+6.1f}% ({100 * r[f'median_turn_{g}']:+5.1f}%)" for g in ("compile_gain", "direct_call_gain")
        )
        goal = ("PASS" if r["cost"]["compiled"] <= 0.25 else "FAIL") if r["num_roads"] >= 32 else "-"
        print(f"{r['num_roads']:3d} {r['fps']['none']:9,.0f} {cells} {gain}  {goal}")
    write_json_atomic(
        args.out,
        {
            "machine": {"platform": platform.platform(), "python": sys.version.split()[0], "torch": torch.__version__},
            "args": vars(args),
            "rows": rows,
        },
    )
    print(f"results written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
