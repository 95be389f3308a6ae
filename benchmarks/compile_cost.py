"""What compiling costs a job's process: the same job eager, compiled with empty compile caches, and compiled again
with the caches the first compiled run filled (TorchInductor's FX-graph cache and AOTAutograd's cache, on disk,
shared by every process that points at them).

    python -m benchmarks.compile_cost [--runs 1] [--episodes 20 100 300] [overrides ...]   # eval_episodes=10

With several ``--episodes``, the arms run at each training length (the cold arm at the first only: it fills the
cache the others read), and ``crossover_episodes`` says from which length on the compiled job, with warm or cold
caches, takes less process time than the eager one (linear between the measured lengths; None where it never does
within them, or always does).

Each run is ``python -m kddrl_trl.train <overrides> compile=...`` in a fresh folder, one torch thread, with
``TORCHINDUCTOR_CACHE_DIR`` pointing at a cache folder made empty for the cold run. From ``summary.json`` it reads
the training time, the process's compile seconds (``compile_s``) and what it compiled and what the caches served
(``compile_counts``). Alone on the machine: pause other work (``kill -STOP``) for the window.

Prints a table and writes ``benchmarks/results/compile_cost.json`` (or ``--out``), with the ratios cold / warm of the
compile seconds and compiled (warm) / eager of the process time at the first length.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.jobs import timed_train_job

ROOT = Path(__file__).resolve().parents[1]
ARMS = (("eager", "false", False), ("cold", "true", True), ("warm", "true", False))  # name, compile, empty the cache


def run_job(out: Path, cache: Path, compile_: str, overrides: list[str]) -> dict:
    job = timed_train_job(out, [f"compile={compile_}", *overrides], {"TORCHINDUCTOR_CACHE_DIR": str(cache)})
    summary = job["summary"]
    return {
        "process_s": job["process_s"],
        "training_s": summary["training"]["elapsed_s"],
        "compile_s": summary.get("compile_s"),
        "compile_counts": summary.get("compile_counts"),
    }


def crossover(points: list[tuple[int, float, float]]) -> float | None:
    """The training length from which the second time is below the first, linear between measured lengths
    (``points``: (episodes, eager seconds, compiled seconds), sorted); None if it is not crossed within them."""
    for (n0, e0, c0), (n1, e1, c1) in zip(points, points[1:]):
        d0, d1 = c0 - e0, c1 - e1
        if d0 > 0 >= d1:
            return n0 + (n1 - n0) * d0 / (d0 - d1)
    return None


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=1, help="rounds of the three arms")
    parser.add_argument("--episodes", type=int, nargs="+", default=[20], help="training lengths, each a set of arms")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "compile_cost.json")
    parser.add_argument("--note", default="", help="what the machine was doing, in words")
    args, overrides = parser.parse_known_args(argv)
    overrides = overrides or ["eval_episodes=10"]
    if args.runs < 1 or min(args.episodes) < 1:
        parser.error(f"--runs and --episodes must be >= 1, got {args.runs} and {args.episodes}")
    lengths = sorted(set(args.episodes))
    work = Path(tempfile.mkdtemp(prefix="kddrl_trl_compile_cost_"))
    cache = work / "inductor_cache"
    runs = []
    try:
        for i, episodes in enumerate(lengths):
            for round_ in range(args.runs):
                for name, compile_, empty in ARMS:
                    if empty and i > 0:  # the cold arm once, at the first length
                        continue
                    if empty:
                        shutil.rmtree(cache, ignore_errors=True)
                    cache.mkdir(exist_ok=True)
                    folder = work / f"{name}{round_}_{episodes}"
                    job = run_job(folder, cache, compile_, [f"episodes={episodes}", *overrides])
                    result = {"arm": name, "round": round_, "episodes": episodes, **job}
                    runs.append(result)
                    print(
                        f"{name} round {round_}, {episodes} episodes: process {result['process_s']:.1f} s, "
                        f"compile {result['compile_s']:.1f} s",
                        flush=True,
                    )
    finally:
        shutil.rmtree(work, ignore_errors=True)

    def mean(arm: str, key: str, episodes: int) -> float:
        values = [r[key] for r in runs if r["arm"] == arm and r["episodes"] == episodes]
        return sum(values) / len(values)

    first = lengths[0]
    cold_extra = mean("cold", "process_s", first) - mean("warm", "process_s", first)  # the cold compile's extra cost
    warm = [(n, mean("eager", "process_s", n), mean("warm", "process_s", n)) for n in lengths]
    result = {
        "command": "python -m benchmarks.compile_cost " + " ".join(argv if argv is not None else sys.argv[1:]),
        "job": "python -m kddrl_trl.train " + " ".join(overrides) + " episodes=" + ",".join(map(str, lengths)),
        "machine": machine_info(),
        "note": args.note,
        "runs": runs,
        "ratios": {
            "compile_s_cold_over_warm": mean("cold", "compile_s", first) / mean("warm", "compile_s", first),
            "process_s_warm_over_eager": mean("warm", "process_s", first) / mean("eager", "process_s", first),
            "process_s_cold_over_eager": mean("cold", "process_s", first) / mean("eager", "process_s", first),
        },
        "process_s_compiled_over_eager_by_episodes": {str(n): c / e for n, e, c in warm},
        "crossover_episodes": {
            "warm": crossover(warm),
            "cold": crossover([(n, e, c + cold_extra) for n, e, c in warm]),
        },
    }
    print(
        "\n| arm | episodes | process (s) | training (s) | compile (s) | graphs | FX-graph cache hit / miss |"
        "\n|---|---|---|---|---|---|---|"
    )
    for r in runs:
        c = r["compile_counts"] or {}
        print(
            f"| {r['arm']}{r['round']} | {r['episodes']} | {r['process_s']:.1f} | {r['training_s']:.1f} | "
            f"{r['compile_s']:.1f} | {c.get('graphs', 0)} | {c.get('fxgraph_cache_hit', 0)} / "
            f"{c.get('fxgraph_cache_miss', 0)} |"
        )
    print("\n" + ", ".join(f"{k} {v:.2f}" for k, v in result["ratios"].items()))
    print(f"compiled (warm) / eager by episodes: {result['process_s_compiled_over_eager_by_episodes']}")
    print(f"the compiled job pays from: {result['crossover_episodes']} episodes")
    write_json(args.out, result)
    return result


if __name__ == "__main__":
    main()
