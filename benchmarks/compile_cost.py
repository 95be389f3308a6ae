"""What compiling costs a job's process: the same job eager, compiled with empty compile caches, and compiled again
with the caches the first compiled run filled (TorchInductor's FX-graph cache and AOTAutograd's cache, on disk,
shared by every process that points at them).

    python -m benchmarks.compile_cost [--runs 1] [overrides ...]      # default job: episodes=20 eval_episodes=10

Each run is ``python -m kddrl_trl.train <overrides> compile=...`` in a fresh folder, one torch thread, with
``TORCHINDUCTOR_CACHE_DIR`` pointing at a cache folder made empty for the cold run. From ``summary.json`` it reads
the training time, the process's compile seconds (``compile_s``) and what it compiled and what the caches served
(``compile_counts``). Alone on the machine: pause other work (``kill -STOP``) for the window.

Prints a table and writes ``benchmarks/results/compile_cost.json`` (or ``--out``), with the ratios cold / warm of the
compile seconds and compiled (warm) / eager of the process time.
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


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=1, help="rounds of the three arms")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "compile_cost.json")
    parser.add_argument("--note", default="", help="what the machine was doing, in words")
    args, overrides = parser.parse_known_args(argv)
    overrides = overrides or ["episodes=20", "eval_episodes=10"]
    if args.runs < 1:
        parser.error(f"--runs must be >= 1, got {args.runs}")
    work = Path(tempfile.mkdtemp(prefix="kddrl_trl_compile_cost_"))
    cache = work / "inductor_cache"
    runs = []
    try:
        for round_ in range(args.runs):
            for name, compile_, empty in ARMS:
                if empty:
                    shutil.rmtree(cache, ignore_errors=True)
                cache.mkdir(exist_ok=True)
                result = {"arm": name, "round": round_, **run_job(work / f"{name}{round_}", cache, compile_, overrides)}
                runs.append(result)
                print(
                    f"{name} round {round_}: process {result['process_s']:.1f} s, compile {result['compile_s']:.1f} s",
                    flush=True,
                )
    finally:
        shutil.rmtree(work, ignore_errors=True)

    def mean(arm: str, key: str) -> float:
        values = [r[key] for r in runs if r["arm"] == arm]
        return sum(values) / len(values)

    result = {
        "command": "python -m benchmarks.compile_cost " + " ".join(argv if argv is not None else sys.argv[1:]),
        "job": "python -m kddrl_trl.train " + " ".join(overrides),
        "machine": machine_info(),
        "note": args.note,
        "runs": runs,
        "ratios": {
            "compile_s_cold_over_warm": mean("cold", "compile_s") / mean("warm", "compile_s"),
            "process_s_warm_over_eager": mean("warm", "process_s") / mean("eager", "process_s"),
            "process_s_cold_over_eager": mean("cold", "process_s") / mean("eager", "process_s"),
        },
    }
    print(
        "\n| arm | process (s) | training (s) | compile (s) | graphs | FX-graph cache hit / miss |\n|---|---|---|---|---|---|"
    )
    for r in runs:
        c = r["compile_counts"] or {}
        print(
            f"| {r['arm']}{r['round']} | {r['process_s']:.1f} | {r['training_s']:.1f} | {r['compile_s']:.1f} | "
            f"{c.get('graphs', 0)} | {c.get('fxgraph_cache_hit', 0)} / {c.get('fxgraph_cache_miss', 0)} |"
        )
    print("\n" + ", ".join(f"{k} {v:.2f}" for k, v in result["ratios"].items()))
    write_json(args.out, result)
    return result


if __name__ == "__main__":
    main()
