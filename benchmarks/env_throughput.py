"""Throughput of the batched SUMO highway environment against the bare simulator it wraps.

For every scenario (``--scenarios``, default baseline + congested) and road count K (``--roads``,
default 1 8 32) this script measures, in one run, the **ego-frames per second**
(``frames x K / wall seconds``; one frame = one 0.1 s simulation step of all K roads) of:

(a) ``sim_limit_fps`` - the simulator core alone, no TorchRL: ``kddrl_trl.envs.sim.HighwaySim`` with
    ``make_config(scenario)``, stepped with numpy random actions (lane-change command uniform in
    {0, 1, 2}, acceleration uniform in [-5, 5] m/s²); roads whose ego left are re-designated with
    ``reset_roads`` after each step. ``HighwaySim.step`` performs all the per-ego libsumo queries (it
    fills ``sim.obs``), so this is the limit set by libsumo stepping the same K roads with the same
    per-ego queries.
(b) ``env_random_fps`` - ``SumoHighwayEnv(scenario, num_roads=K)`` driven by
    ``env.rollout(frames, RandomDrivingPolicy(), break_when_any_done=False)``: the same random action
    distribution as (a), drawn by a small TensorDict module (TorchRL's spec sampler would add its own
    cost, which is not the env's); TorchRL auto-resets the done roads.
(b') ``env_random_collector_fps`` - the random actions of (b) collected by TorchRL's ``Collector`` in
    batches of 200 frames x K (how training collects; no stacking at the end). Goal check stays on (b).
(c) ``env_rule_fps`` - the same env with the IDM+MOBIL rule policy
    (``kddrl_trl.baselines.IDMMobilPolicy``) as the rollout policy.

The goal is ``(b)/(a) >= 0.5`` at K >= 8 (TorchRL overhead at most doubles the cost of a frame); the
table marks PASS/FAIL for those rows.

Method: libsumo runs one simulation per process, so the three measurements run one after another,
each closing its simulation before the next opens. All three measurements of a setting use the same
seed. Construction (including SUMO's traffic warm-up) and a short warm-up of ``--warmup`` frames are
not timed; the timed part starts with a reset of all K roads (as ``env.rollout`` does) followed by
``--frames`` steps. With ``--repeats N`` every measurement is repeated N times (fresh construction each
time) and the median is reported. Each JSON row also records, per measurement, the number of
episodes that ended in the timed part (``*_episodes``, including the initial reset): re-designating
egos costs time. ``torch.set_num_threads(1)`` is set when it runs (not on import: other benchmarks import its
helpers): the environment is single-threaded and intra-op threads would only oversubscribe the cores.

Run (full benchmark; takes a while, use an otherwise idle machine)::

    python -m benchmarks.env_throughput

Quick check::

    python -m benchmarks.env_throughput --roads 1 8 --scenarios baseline --frames 200 --out /tmp/envbench.json

Results are printed as a table and written to ``benchmarks/results/env_throughput.json`` (``--out``),
atomically, after every completed setting.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import math
import os
import platform
import statistics
import sys
import time
import traceback
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from kddrl_trl.atomic_files import write_text_atomic
from kddrl_trl.baselines import IDMMobilPolicy, RandomDrivingPolicy
from kddrl_trl.envs import SumoHighwayEnv, make_config
from kddrl_trl.envs.sim import HighwaySim
from kddrl_trl.provenance import cpu_model

GOAL_RATIO = 0.5
GOAL_MIN_K = 8
DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "env_throughput.json"


# ------------------------------------------------------------------------------------ measurements
def measure_sim(
    scenario: str, k: int, seed: int, frames: int, warmup: int, timer=time.perf_counter
) -> tuple[float, int]:
    """(a) HighwaySim alone with numpy random actions; returns (ego-frames per second, episodes ended). ``timer``:
    the clock (``time.process_time``: CPU seconds of this process, for a machine shared with other jobs)."""
    cfg = make_config(scenario)
    sim = HighwaySim(cfg, k, seed=seed)
    try:
        rng = np.random.default_rng(seed)

        def run(n: int) -> None:
            sim.reset_roads(range(k))
            for _ in range(n):
                lc_cmd = rng.integers(0, 3, size=k)
                accel = rng.uniform(-5.0, 5.0, size=k)
                sim.step(lc_cmd, accel)
                done = np.flatnonzero(~sim.ego_present)
                if done.size:
                    sim.reset_roads(done)

        run(warmup)
        episodes0 = sim.stats["episodes"]
        t0 = timer()
        run(frames)
        elapsed = timer() - t0
        episodes = sim.stats["episodes"] - episodes0
    finally:
        sim.close()
    return frames * k / elapsed, episodes


def measure_env(scenario: str, k: int, seed: int, frames: int, warmup: int, rule: bool) -> tuple[float, int]:
    """(b)/(c) SumoHighwayEnv.rollout, random actions or IDM+MOBIL; (ego-frames/s, episodes ended)."""
    env = SumoHighwayEnv(scenario, num_roads=k, seed=seed)
    try:
        policy = IDMMobilPolicy() if rule else RandomDrivingPolicy(generator=torch.Generator().manual_seed(seed))
        if warmup > 0:
            env.rollout(warmup, policy, break_when_any_done=False)
        episodes0 = env.stats["episodes"]
        t0 = time.perf_counter()
        td = env.rollout(frames, policy, break_when_any_done=False)
        elapsed = time.perf_counter() - t0
        episodes = env.stats["episodes"] - episodes0
        steps = td.shape[-1]
        if steps != frames:
            raise RuntimeError(f"rollout returned {steps} steps, expected {frames}")
    finally:
        env.close()
    return frames * k / elapsed, episodes


def measure_collector(scenario: str, k: int, seed: int, frames: int, warmup: int) -> tuple[float, int]:
    """(b') the same random actions collected by TorchRL's ``Collector`` (the training path: batches are
    written into a preallocated buffer instead of stacked at the end); the first batch is not timed."""
    from torchrl.collectors import Collector

    env = SumoHighwayEnv(scenario, num_roads=k, seed=seed)
    try:
        policy = RandomDrivingPolicy(generator=torch.Generator().manual_seed(seed))
        batch = k * 200
        collector = Collector(env, policy, frames_per_batch=batch, total_frames=k * frames + batch)
        it = iter(collector)
        next(it)  # warm-up batch (includes the first reset)
        episodes0 = env.stats["episodes"]
        t0 = time.perf_counter()
        n = sum(b.numel() for b in it)
        elapsed = time.perf_counter() - t0
        episodes = env.stats["episodes"] - episodes0
        collector.shutdown()
    finally:
        env.close()
    return n / elapsed, episodes


MEASUREMENTS = {
    "sim_limit_fps": lambda s, k, seed, f, w: measure_sim(s, k, seed, f, w),
    "env_random_fps": lambda s, k, seed, f, w: measure_env(s, k, seed, f, w, rule=False),
    "env_rule_fps": lambda s, k, seed, f, w: measure_env(s, k, seed, f, w, rule=True),
    "env_random_collector_fps": lambda s, k, seed, f, w: measure_collector(s, k, seed, f, w),
}


# ------------------------------------------------------------------------------------------ output
def _version(dist: str) -> str | None:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


def machine_info() -> dict:
    try:
        import libsumo

        libsumo_version = getattr(libsumo, "__version__", None) or _version("libsumo")
    except ImportError:
        libsumo_version = None
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = None
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_model": cpu_model(),  # timings and float arithmetic differ between CPU models
        "python": sys.version.split()[0],
        "torch": torch.__version__,
        "torchrl": _version("torchrl"),
        "tensordict": _version("tensordict"),
        "libsumo": libsumo_version,
        "cpu_count": os.cpu_count(),
        "cpu_affinity": affinity,
        "torch_num_threads": torch.get_num_threads(),
    }


def _ratio(num: float, den: float) -> float:
    if not (math.isfinite(num) and math.isfinite(den)) or den <= 0:
        return float("nan")
    return num / den


def _goal(row: dict) -> str:
    if row["num_roads"] < GOAL_MIN_K:
        return "-"
    r = row["random_over_sim"]
    return "PASS" if math.isfinite(r) and r >= GOAL_RATIO else "FAIL"


def _json_safe(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_json_safe(v) for v in x]
    return x


def write_json(path: Path, payload: dict) -> None:
    """Write ``payload`` atomically (:func:`kddrl_trl.atomic_files.write_text_atomic`), keys in their order, a
    non-finite float as null."""
    write_text_atomic(path, json.dumps(_json_safe(payload), indent=2) + "\n")


def format_table(rows: list[dict]) -> str:
    header = [
        "scenario",
        "K",
        "sim_limit_fps",
        "env_random_fps",
        "env_rule_fps",
        "collector_random_fps",
        "random/sim",
        "rule/sim",
        "collector/sim",
        "goal",
    ]
    body = [
        [
            r["scenario"],
            str(r["num_roads"]),
            f"{r['sim_limit_fps']:.1f}",
            f"{r['env_random_fps']:.1f}",
            f"{r['env_rule_fps']:.1f}",
            f"{r['env_random_collector_fps']:.1f}",
            f"{r['random_over_sim']:.3f}",
            f"{r['rule_over_sim']:.3f}",
            f"{r['collector_over_sim']:.3f}",
            _goal(r),
        ]
        for r in rows
    ]
    widths = [max(len(h), *(len(b[i]) for b in body)) if body else len(h) for i, h in enumerate(header)]
    left = {0}  # scenario left-aligned, numbers right-aligned
    fmt = lambda cells: "  ".join(
        c.ljust(w) if i in left else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))
    )
    lines = [fmt(header), "  ".join("-" * w for w in widths)] + [fmt(b) for b in body]
    return "\n".join(lines)


# -------------------------------------------------------------------------------------------- main
def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--roads", type=int, nargs="+", default=[1, 8, 32], help="road counts K (default: 1 8 32)")
    p.add_argument(
        "--scenarios", nargs="+", default=["baseline", "congested"], help="scenario names (default: baseline congested)"
    )
    p.add_argument(
        "--frames",
        type=int,
        default=2000,
        help="timed env steps per measurement; ego-frames = frames x K (default: 2000)",
    )
    p.add_argument("--warmup", type=int, default=20, help="untimed steps before each measurement (default: 20)")
    p.add_argument("--repeats", type=int, default=1, help="repeats per measurement, median reported (default: 1)")
    p.add_argument("--seed", type=int, default=0, help="seed shared by the three measurements of a setting")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"JSON output (default: {DEFAULT_OUT})")
    args = p.parse_args(argv)
    if any(k < 1 for k in args.roads):
        p.error("--roads: every K must be >= 1")
    if args.frames < 1 or args.repeats < 1 or args.warmup < 0:
        p.error("--frames and --repeats must be >= 1, --warmup >= 0")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    torch.set_num_threads(1)  # single-threaded env: avoid thread oversubscription (see module docstring)
    info = machine_info()
    arguments = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    rows: list[dict] = []
    settings = [(s, k) for s in args.scenarios for k in args.roads]
    failed = False

    bar = tqdm(settings, desc="env throughput", unit="setting")
    for scenario, k in bar:
        row = {"scenario": scenario, "num_roads": k, "frames": args.frames}
        errors = {}
        for name, fn in MEASUREMENTS.items():
            bar.set_postfix_str(f"{scenario} K={k} {name}")
            values, episodes = [], []
            for _ in range(args.repeats):
                try:
                    fps, n_episodes = fn(scenario, k, args.seed, args.frames, args.warmup)
                    values.append(fps)
                    episodes.append(n_episodes)
                except Exception as err:  # keep going: record the failure, report it at the end
                    errors[name] = f"{type(err).__name__}: {err}"
                    tqdm.write(f"[{scenario} K={k}] {name} failed:\n{traceback.format_exc()}")
                    failed = True
                    break
            row[name] = statistics.median(values) if values and name not in errors else float("nan")
            # diagnostic: episodes ended in the timed part (incl. the initial reset); resets cost time
            row[name.replace("_fps", "_episodes")] = statistics.median_low(episodes) if episodes else None
            if args.repeats > 1 and values:
                row[f"{name}_all"] = values
        row["random_over_sim"] = _ratio(row["env_random_fps"], row["sim_limit_fps"])
        row["rule_over_sim"] = _ratio(row["env_rule_fps"], row["sim_limit_fps"])
        row["collector_over_sim"] = _ratio(row["env_random_collector_fps"], row["sim_limit_fps"])
        row["goal"] = _goal(row)
        if errors:
            row["errors"] = errors
        rows.append(row)
        tqdm.write(
            f"{scenario} K={k}: sim {row['sim_limit_fps']:.1f}  random {row['env_random_fps']:.1f}  "
            f"rule {row['env_rule_fps']:.1f} ego-frames/s"
        )
        write_json(
            args.out,
            {
                "machine": info,
                "arguments": arguments,
                "goal": f"env_random_fps / sim_limit_fps >= {GOAL_RATIO} at K >= {GOAL_MIN_K}",
                "unit": "ego-frames per second (frames x K / wall seconds)",
                "rows": rows,
            },
        )
    bar.close()

    print()
    print(
        f"Ego-frames per second (frames x K / wall s), {args.frames} frames, {args.repeats} repeat(s), "
        f"seed {args.seed}; torch {info['torch']}, torchrl {info['torchrl']}, libsumo {info['libsumo']}"
    )
    print(format_table(rows))
    goal_rows = [r for r in rows if r["num_roads"] >= GOAL_MIN_K]
    if goal_rows:
        verdicts = ", ".join(f"{r['scenario']} K={r['num_roads']}: {r['goal']}" for r in goal_rows)
        print(f"goal (b)/(a) >= {GOAL_RATIO} at K >= {GOAL_MIN_K}: {verdicts}")
    else:
        print(f"goal (b)/(a) >= {GOAL_RATIO} at K >= {GOAL_MIN_K}: no row with K >= {GOAL_MIN_K}")
    print(f"results written to {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
