"""Scale-out on one machine: the same sweep run sequentially and on a local Ray, measured in one run (issue 16).

``sweep``: a sweep of ``len(algos) x len(seeds)`` runs (default 2 algos x 2 seeds, small budgets), as a user types
it (``python -m kddrl_trl.train -m ...``), timed from the command's start to its end: first with Hydra's basic
launcher (one run after the other), then with ``hydra/launcher=ray`` on a local Ray of ``--ray-cpus`` CPUs (one run
per CPU at once, each holding a worker process to itself). ``sweep_time_ratio`` = Ray sweep wall time / sequential
(issue 16's goal on a 2-core machine: <= 0.6). Both include each launcher's own start (Hydra, and ``ray.init`` for Ray),
as a user pays them, and each process's first-run costs (``compile=auto``: TorchDynamo traces the transform stack and
the losses once per process, ~20 s for KDDRL; a basic-launcher sweep pays it once, every Ray worker once more): the
sweep's wall time is about ``fixed + runs' work / P``, and ``outside_runs_s`` (wall time - sum of the runs' own
``wall_s`` / P) is that fixed part. The default budget, 150 training + 20 evaluation episodes (about a minute of
work a run), keeps the ratio about parallel runs: 20 training episodes, the budget this goal was first measured
with, took 50-100 s a run then and 6-14 s now (learner and compile speed-ups), which leaves a sweep of 4 such runs
timing almost nothing but those fixed costs (ratio 0.92, one run at 20 episodes). Every run's ``summary.json`` is
checked and its own ``wall_s`` kept beside the sweep's. Both
sweeps run each run with the same torch threads (``--threads``, default 1: ``OMP_NUM_THREADS``, which Ray also sets
to a task's CPUs where it is unset), so that the ratio measures runs side by side, not a thread count: a smoke run on
a busy 2-core machine took ~5x longer per run sequentially with torch's default threads (one per core) than on Ray
with one (the machine's other load changing too: not isolated).

``collect``: the training collection (SUMO, the KDDRL transform stack, both policies, both buffers, the learner's
weights synced to the workers after every batch) on Ray actors (``collector.backend=ray``), ``--collect-roads`` K = 8
roads each, with 1 and with 2 actors, in wall time (``collect_speed.measure_collect_workers``).
``collect_scaling`` = 2-actor frames/s / 1-actor frames/s (issue 16's goal on a 2-core machine: >= 1.6).

Each measurement is one entry of :data:`MEASUREMENTS`: name -> (a function of the parsed arguments returning its
details and its ratios, a function printing its table); ``--measure`` picks some.

``--repeats N`` runs every measurement N times, interleaved (sweep, collect, sweep, collect, ...), and writes each
ratio as the median of its repeats beside every repeat's value (``<ratio>_repeats``) and details: on a 2-core VM
single runs of the same code spread from 0.52 to 0.62 (``sweep_time_ratio``) and 1.54 to 2.18 (``collect_scaling``).

Prints a table and writes ``benchmarks/results/scale_out.json`` (after each repeat). Needs the extra ``.[ray]``.
Measure on an idle machine: a busy one shares its cores with the sweep.

    python -m benchmarks.scale_out                       # 2 algos x 2 seeds, 150 training + 20 evaluation episodes
    python -m benchmarks.scale_out --repeats 3           # the figures of docs/scaling.md
    python -m benchmarks.scale_out --episodes 2 --eval-episodes 2 --set env.num_roads=2 compile=false \
        train.eval_every=0 train.warmup_frames=50 env.max_steps=120 --out /tmp/scale_out.json    # a smoke run
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Callable

from benchmarks.env_throughput import machine_info, write_json

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "scale_out.json"


def sweep_command(args, launcher: list[str], sweep_dir: Path) -> list[str]:
    """The sweep as a user types it, with ``launcher``'s overrides."""
    return [
        sys.executable,
        "-m",
        "kddrl_trl.train",
        "-m",
        f"algo={','.join(args.algos)}",
        f"seed={','.join(map(str, args.seeds))}",
        f"episodes={args.episodes}",
        f"eval_episodes={args.eval_episodes}",
        "progress=false",
        *args.set,
        *launcher,
        f"hydra.sweep.dir={sweep_dir}",
    ]


def timed_sweep(args, name: str, launcher: list[str], root: Path, parallel: int) -> dict:
    """Runs the sweep with ``launcher`` (``parallel`` runs at once) into ``root/name``; its wall time, every run's
    own ``wall_s`` and the time outside them."""
    sweep_dir = root / name
    cmd = sweep_command(args, launcher, sweep_dir)
    t0 = time.perf_counter()
    env = {**os.environ, "OMP_NUM_THREADS": str(args.threads)} if args.threads else None
    done = subprocess.run(cmd, cwd=root, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"the {name} sweep failed ({' '.join(cmd)}):\n{done.stderr[-4000:]}")
    summaries = sorted(sweep_dir.glob("*/summary.json"))
    expected = len(args.algos) * len(args.seeds)
    if len(summaries) != expected:
        raise SystemExit(f"the {name} sweep left {len(summaries)} finished runs of {expected} in {sweep_dir}")
    runs = {p.parent.name: json.loads(p.read_text())["wall_s"] for p in summaries}
    return {
        "wall_s": wall,
        "run_wall_s": runs,
        "runs_sum_s": sum(runs.values()),
        "outside_runs_s": wall - sum(runs.values()) / parallel,
    }


def measure_sweep(args) -> tuple[dict, dict]:
    """The sweep sequentially (Hydra's basic launcher), then on a local Ray of ``args.ray_cpus`` CPUs."""
    with tempfile.TemporaryDirectory(prefix="scale_out_") as tmp:
        root = Path(tmp)
        sequential = timed_sweep(args, "sequential", ["hydra/launcher=basic"], root, parallel=1)
        ray = timed_sweep(
            args,
            "ray",
            ["hydra/launcher=ray", f"+hydra.launcher.init.num_cpus={args.ray_cpus}"],
            root,
            parallel=args.ray_cpus,
        )
    details = {
        "runs": len(args.algos) * len(args.seeds),
        "algos": args.algos,
        "seeds": args.seeds,
        "ray_cpus": args.ray_cpus,
        "sequential": sequential,
        "ray": ray,
    }
    return details, {"sweep_time_ratio": ray["wall_s"] / sequential["wall_s"]}


def print_sweep(details: dict, ratios: dict) -> None:
    seeds = " ".join(map(str, details["seeds"]))
    title = f"sweep of {details['runs']} runs ({', '.join(details['algos'])} x seeds {seeds})"
    print(f"\n{title:<52}{'wall s':>9}{'sum of runs s':>15}{'outside runs s':>16}{'ratio':>8}")
    for label, key, ratio in (
        ("sequential (Hydra's basic launcher)", "sequential", 1.0),
        (f"local Ray, {details['ray_cpus']} CPUs (hydra/launcher=ray)", "ray", ratios["sweep_time_ratio"]),
    ):
        r = details[key]
        print(f"{label:<52}{r['wall_s']:>9.1f}{r['runs_sum_s']:>15.1f}{r['outside_runs_s']:>16.1f}{ratio:>8.2f}")


def measure_collect(args) -> tuple[dict, dict]:
    """Collection frames/s on 1 and on 2 Ray actors of ``args.collect_roads`` roads each."""
    from benchmarks.collect_speed import measure_collect_workers

    os.environ.setdefault("OMP_NUM_THREADS", str(args.threads or 1))
    from kddrl_trl.compiling import resolve_compile

    compile = resolve_compile(args.compile)
    details = measure_collect_workers(
        args.collect_roads, [1, 2], args.collect_frames, seed=0, compile=compile, backend="ray"
    )
    fps = {r["workers"]: r["collect_fps"] for r in details["runs"]}
    return details, {"collect_scaling": fps[2] / fps[1]}


def print_collect(details: dict, ratios: dict) -> None:
    print(f"\n{'collection on Ray actors':<52}{'frames/s':>9}{'ratio':>8}")
    one = next(r["collect_fps"] for r in details["runs"] if r["workers"] == 1)
    for r in details["runs"]:
        label = f"{r['workers']} actor(s) x K={r['num_roads']} roads"
        print(f"{label:<52}{r['collect_fps']:>9.0f}{r['collect_fps'] / one:>8.2f}")


def medians(per_ratio: dict[str, list[float]]) -> dict:
    """Each ratio as the median of its repeats (the figure the issue's goal reads), and every repeat's value."""
    return {
        **{key: statistics.median(values) for key, values in per_ratio.items()},
        **{f"{key}_repeats": values for key, values in per_ratio.items()},
    }


#: name -> (measure: args -> (details, ratios), print: (details, ratios) -> None)
MEASUREMENTS: dict[str, tuple[Callable, Callable]] = {
    "sweep": (measure_sweep, print_sweep),
    "collect": (measure_collect, print_collect),
}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--measure", nargs="+", choices=sorted(MEASUREMENTS), default=sorted(MEASUREMENTS))
    p.add_argument("--algos", nargs="+", default=["kddrl", "d3qn_td3"])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--episodes", type=int, default=150, help="training episodes per run")
    p.add_argument("--eval-episodes", type=int, default=20, help="final evaluation episodes per run")
    p.add_argument("--ray-cpus", type=int, default=2, help="CPUs of the local Ray (runs at once)")
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch threads of every run, both sweeps (OMP_NUM_THREADS); 0: each launcher's default",
    )
    p.add_argument(
        "--set",
        nargs="*",
        default=["train.eval_every=0"],
        metavar="KEY=VALUE",
        help="further overrides of every run (default: no periodic evaluation)",
    )
    p.add_argument("--collect-roads", type=int, default=8, help="collect: roads K of each Ray actor's env")
    p.add_argument("--collect-frames", type=int, default=4000, help="collect: frames timed per arm")
    p.add_argument(
        "--compile",
        default="false",
        choices=["auto", "true", "false"],
        help="collect: torch.compile the transform stack in each actor",
    )
    p.add_argument(
        "--repeats",
        type=int,
        default=1,
        help="every measurement this many times, interleaved; the ratios written are the medians",
    )
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = p.parse_args(argv)
    if args.repeats < 1:
        p.error(f"--repeats {args.repeats}: at least 1")
    try:
        ray_version = version("ray")
    except PackageNotFoundError:
        raise SystemExit("benchmarks/scale_out.py needs Ray: python -m pip install '.[ray]'") from None

    result = {"args": {k: str(v) for k, v in vars(args).items()}, "machine": {**machine_info(), "ray": ray_version}}
    per_ratio: dict[str, list[float]] = {}
    for repeat in range(args.repeats):  # the measurements interleaved, so a slow spell of the machine hits all
        for name in args.measure:
            measure, show = MEASUREMENTS[name]
            details, ratios = measure(args)
            result.setdefault(name, {"repeats": []})["repeats"].append(details)
            for key, value in ratios.items():
                per_ratio.setdefault(key, []).append(value)
            print(f"\n(repeat {repeat + 1} of {args.repeats})", end="")
            show(details, ratios)
            write_json(args.out, {**result, **medians(per_ratio)})  # each finished repeat kept
    print(
        "\n"
        + "  ".join(
            f"{key} = {statistics.median(values):.2f} (median of {', '.join(f'{v:.2f}' for v in values)})"
            for key, values in per_ratio.items()
        )
    )
    print(f"\nwritten {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
