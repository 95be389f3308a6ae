"""A job beside another: the smoke job alone and beside a copy of itself (both started together), at
``torch_threads=auto`` (the default) and at torch's own default of one thread per core (``torch_threads=<cores>``),
as the slowdown ratios beside / alone measured in one run.

    python -m benchmarks.threads [--episodes 20] [--eval-episodes 10] [overrides ...]

Each job is ``python -m kddrl_trl.train episodes=.. eval_episodes=.. torch_threads=..`` in a fresh folder, without
``OMP_NUM_THREADS`` (which ``auto`` would take as it is). A pair's time is each job's wall time from the common
start; the ratio is their mean over the alone job's. Run it alone on the machine: any other work is part of what it
measures. Prints a table and writes ``benchmarks/results/threads.json`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.jobs import started_train_jobs
from kddrl_trl.threads import cores

ROOT = Path(__file__).resolve().parents[1]


def arms() -> list[tuple[str, str]]:
    """(name, torch_threads) of the two arms: the default, and torch's own default of a thread per core."""
    n = cores()
    return [("auto", "auto"), (f"{n} threads (torch's default)", str(n))]


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "threads.json")
    parser.add_argument("--note", default="")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args(argv)
    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}
    base = [f"episodes={args.episodes}", f"eval_episodes={args.eval_episodes}", *args.overrides]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, setting in arms():
            overrides = [*base, f"torch_threads={setting}"]
            folder = Path(tmp) / setting
            folder.mkdir()
            (alone,) = started_train_jobs([folder / "alone"], overrides, env)
            pair = started_train_jobs([folder / "a", folder / "b"], overrides, env)
            beside = statistics.mean(p["process_s"] for p in pair)
            rows.append(
                {
                    "arm": name,
                    "torch_threads": setting,
                    "alone_s": alone["process_s"],
                    "beside_s": [p["process_s"] for p in pair],
                    "slowdown": beside / alone["process_s"],
                    "threads_chosen": {
                        "alone": alone["summary"].get("torch_threads"),
                        "beside": [p["summary"].get("torch_threads") for p in pair],
                    },
                    "update_s": {
                        "alone": alone["summary"]["training"]["update_s"],
                        "beside": [p["summary"]["training"]["update_s"] for p in pair],
                    },
                }
            )
    print("| arm | alone (s) | beside a copy (s) | slowdown | update_s alone / beside |")
    print("|---|---|---|---|---|")
    for r in rows:
        beside = " / ".join(f"{t:.1f}" for t in r["beside_s"])
        updates = f"{r['update_s']['alone']:.1f} / " + " / ".join(f"{u:.1f}" for u in r["update_s"]["beside"])
        print(f"| {r['arm']} | {r['alone_s']:.1f} | {beside} | {r['slowdown']:.2f} | {updates} |")
    result = {
        "command": "python -m benchmarks.threads " + " ".join(argv if argv is not None else sys.argv[1:]),
        "job": "python -m kddrl_trl.train " + " ".join(base),
        "machine": machine_info(),
        "note": args.note,
        "runs": rows,
        "ratios": {r["arm"]: r["slowdown"] for r in rows},
    }
    write_json(args.out, result)
    return result


if __name__ == "__main__":
    main()
