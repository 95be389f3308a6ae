"""Per-seed cost of the whole training job when N seeds train as one batch (``seeds=[0,...,N-1]``) against one seed's
job alone (``seed=0``), measured in one run on one machine, alone: the whole-job series beside the update's own
(``seed_batch.py``).

    python -m benchmarks.seed_batch_job [--seeds 1 2 4 8] [--rounds 1] [overrides ...]

Each arm is ``python -m kddrl_trl.train <overrides>`` as a user runs it, in a fresh folder, one torch thread unless
``OMP_NUM_THREADS`` says otherwise; the arms take turns, ``--rounds`` times (N = 1 is the single run, not a batch of
one). Per run it reads the process's wall time and, from a seed's ``summary.json``, the training time
(``training.elapsed_s``: a batch's seeds share one wall clock, so each records the batch's). The per-seed time of a
batch is its time over N; the ratio is that over the single run's time, means over the rounds. Extra overrides
(``episodes=300`` for a shorter series, ``+scenario=braking``) go to every arm alike. The machine must be otherwise
idle: pause other work (``kill -STOP``) for the window.

``--cores C`` compares the machine's throughput on C cores instead: the single arm is C copies of the single run at
once, one torch thread each (as a sweep of single runs fills the cores), whose per-seed time is the time until all
have ended (process) or their mean training time, over C; a batch runs with C torch threads. C = 1 (the default) is
the series above.

Prints a table and writes ``benchmarks/results/seed_batch_job.json`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.jobs import started_train_jobs

ROOT = Path(__file__).resolve().parents[1]


def seed_overrides(n: int) -> list[str]:
    """The job's seed key for ``n`` seeds: the single run for one, a batch of seeds 0..n-1 otherwise."""
    return ["seed=0"] if n == 1 else [f"seeds=[{','.join(str(s) for s in range(n))}]"]


def run_arm(out: Path, n: int, overrides: list[str], env: dict[str, str], cores: int = 1) -> dict:
    """One arm into ``out``: its process time, its training time and each seed's test results; the single run
    (``n`` 1) as ``cores`` copies at once into ``out/copy<i>`` (the time until the last ends; the mean training
    time), a batch with ``cores`` torch threads."""
    if n == 1:
        outs = [out / f"copy{i}" for i in range(cores)] if cores > 1 else [out]
        env = {**env, "OMP_NUM_THREADS": "1"} if cores > 1 else env
    else:
        outs = [out]
        env = {**env, "OMP_NUM_THREADS": str(cores)} if cores > 1 else env
    for folder in outs:
        folder.parent.mkdir(parents=True, exist_ok=True)
    jobs = started_train_jobs(outs, [*seed_overrides(n), *overrides], env)
    summaries = [s for job in jobs for s in job["summaries"]]
    return {
        "process_s": max(job["process_s"] for job in jobs),
        "training_s": _mean([job["summaries"][0]["training"]["elapsed_s"] for job in jobs]),
        "jobs": len(jobs),
        "seeds": [s["seed"] for s in summaries],
        "mean_speed_kmh": [s["mean_speed_kmh"] for s in summaries],
        "collision_rate": [s["collision_rate"] for s in summaries],
    }


def _mean(values: list[float]) -> float:
    return sum(values) / len(values)


def main(argv: list[str] | None = None) -> dict:
    import os

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 4, 8], help="batch sizes N (1: the single run)")
    parser.add_argument("--rounds", type=int, default=1, help="turns of the arms")
    parser.add_argument("--cores", type=int, default=1, help="the machine's cores in use (module docstring)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/kddrl_trl_seed_batch_job"), help="the runs' folder")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "seed_batch_job.json")
    parser.add_argument("--note", default="", help="what the machine was doing, in words")
    argv = sys.argv[1:] if argv is None else argv
    overrides = [a for a in argv if "=" in a and not a.startswith("-")]  # Hydra's key=value, anywhere in the line
    args = parser.parse_args([a for a in argv if a not in overrides])
    if args.rounds < 1 or 1 not in args.seeds or min(args.seeds) < 1 or args.cores < 1:
        parser.error(
            f"--rounds and --cores must be >= 1 and --seeds must hold 1 (the single run), got {args.rounds}, "
            f"{args.cores}, {args.seeds}"
        )
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    runs = []
    for round_ in range(args.rounds):
        for n in args.seeds:
            out = args.work / f"n{n}_round{round_}_{int(time.time())}"
            out.parent.mkdir(parents=True, exist_ok=True)
            runs.append({"n": n, "round": round_, **run_arm(out, n, overrides, env, args.cores)})
            r = runs[-1]
            print(f"N={n} round {round_}: process {r['process_s']:.1f} s, training {r['training_s']:.1f} s", flush=True)
    keys = ("process_s", "training_s")
    mean = {n: {k: _mean([r[k] for r in runs if r["n"] == n]) for k in keys} for n in args.seeds}
    per_seed = {n: {k: mean[n][k] / n / (mean[1][k] / args.cores) for k in keys} for n in args.seeds}
    result = {
        "command": "python -m benchmarks.seed_batch_job " + " ".join(argv),
        "job": "python -m kddrl_trl.train " + " ".join(overrides),
        "machine": machine_info(),
        "note": args.note,
        "cores": args.cores,
        "runs": runs,
        "mean": {str(n): v for n, v in mean.items()},
        "per_seed_over_alone": {str(n): v for n, v in per_seed.items()},
    }
    print("\n| N | process (s) | training (s) | per seed / alone, process | per seed / alone, training |")
    print("|---|---|---|---|---|")
    for n in args.seeds:
        m, p = mean[n], per_seed[n]
        print(f"| {n} | {m['process_s']:.1f} | {m['training_s']:.1f} | {p['process_s']:.3f} | {p['training_s']:.3f} |")
    write_json(args.out, result)
    return result


if __name__ == "__main__":
    main()
