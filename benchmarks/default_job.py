"""The README's main job timed from two commits, alternating A B A B on one machine, alone: the ratio B / A.

    python -m benchmarks.default_job --a <commit before> --b <commit after> [--rounds 2] [overrides ...]

Each commit is checked out once into a worktree under ``--work`` (kept: a second call reuses it), and each run is
``python -m kddrl_trl.train <overrides>`` (default: none, the README's main job) in a fresh folder, with that
worktree's ``src`` first on ``PYTHONPATH`` (the same installed dependencies for both). Per run it reads the process's
wall time, and from ``summary.json`` the training time (``training.elapsed_s``), the run's whole time (``wall_s``)
and, where the commit records it, the seconds the job's process spent compiling (``compile_s``). The machine must be
otherwise idle: pause other work (``kill -STOP``) for the window, since these machines are noisy.

Prints a table and writes ``benchmarks/results/default_job.json`` (or ``--out``), with each run and the ratios
B / A of the mean process time and of the mean training time.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.jobs import timed_train_job

ROOT = Path(__file__).resolve().parents[1]


def worktree(commit: str, work: Path) -> tuple[Path, str]:
    """(a worktree of ``commit`` under ``work``, its full hash)."""
    full = subprocess.run(["git", "rev-parse", commit], cwd=ROOT, capture_output=True, text=True, check=True)
    rev = full.stdout.strip()
    path = work / rev[:12]
    if not (path / "src" / "kddrl_trl").is_dir():
        subprocess.run(["git", "worktree", "add", "--detach", str(path), rev], cwd=ROOT, check=True)
    return path, rev


def run_job(tree: Path, out: Path, overrides: list[str]) -> dict:
    """One run of the job from ``tree`` into ``out``: its times, from the process and its ``summary.json``."""
    job = timed_train_job(out, overrides, {"PYTHONPATH": str(tree / "src")})
    summary = job["summary"]
    return {
        "process_s": job["process_s"],
        "training_s": summary["training"]["elapsed_s"],
        "wall_s": summary.get("wall_s"),
        "compile_s": summary.get("compile_s"),
        "collision_rate": summary["collision_rate"],
        "mean_speed_kmh": summary["mean_speed_kmh"],
    }


def _mean(values: list[float]) -> float:
    return sum(values) / len(values)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--a", required=True, help="commit A (before)")
    parser.add_argument("--b", default="HEAD", help="commit B (after), default HEAD")
    parser.add_argument("--rounds", type=int, default=2, help="A B pairs, alternating")
    parser.add_argument("--work", type=Path, default=Path("/tmp/kddrl_trl_default_job"), help="worktrees and runs")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "default_job.json")
    parser.add_argument("--note", default="", help="what the machine was doing, in words")
    args, overrides = parser.parse_known_args(argv)
    if args.rounds < 1:
        parser.error(f"--rounds must be >= 1, got {args.rounds}")
    args.work.mkdir(parents=True, exist_ok=True)
    trees = {label: worktree(commit, args.work) for label, commit in (("A", args.a), ("B", args.b))}
    runs = []
    for round_ in range(args.rounds):
        for label in ("A", "B"):
            tree, rev = trees[label]
            out = args.work / "runs" / f"{label}{round_}_{int(time.time())}"
            out.parent.mkdir(parents=True, exist_ok=True)
            result = {"label": label, "commit": rev, "round": round_, **run_job(tree, out, overrides)}
            runs.append(result)
            print(
                f"{label} {rev[:8]} round {round_}: process {result['process_s']:.1f} s, training "
                f"{result['training_s']:.1f} s, compile {result['compile_s'] or float('nan'):.1f} s",
                flush=True,
            )
    means = {
        label: {key: _mean([r[key] for r in runs if r["label"] == label]) for key in ("process_s", "training_s")}
        for label in ("A", "B")
    }
    result = {
        "command": "python -m benchmarks.default_job " + " ".join(argv if argv is not None else sys.argv[1:]),
        "job": "python -m kddrl_trl.train " + " ".join(overrides),
        "machine": machine_info(),
        "note": args.note,
        "commits": {label: rev for label, (_, rev) in trees.items()},
        "runs": runs,
        "mean": means,
        "ratio_b_over_a": {key: means["B"][key] / means["A"][key] for key in ("process_s", "training_s")},
    }
    print("\n| run | commit | process (s) | training (s) | compile (s) |\n|---|---|---|---|---|")
    for r in runs:
        compile_s = "n/a" if r["compile_s"] is None else f"{r['compile_s']:.1f}"
        print(
            f"| {r['label']}{r['round']} | {r['commit'][:8]} | {r['process_s']:.1f} | {r['training_s']:.1f} | {compile_s} |"
        )
    ratio = result["ratio_b_over_a"]
    print(f"\nB / A: process {ratio['process_s']:.3f}, training {ratio['training_s']:.3f}")
    write_json(args.out, result)
    return result


if __name__ == "__main__":
    main()
