"""TF32 (``matmul_precision=high``) against IEEE float32 (``highest``) in training on a GPU: the paired differences.

Reads ``runs/<precision>_<seed>/`` (``run.sh``'s records: ``summary.json``, ``train_episodes.csv.xz``,
``eval_episodes.csv.xz``), prints a table and writes ``summary.json`` beside this file. Each difference is
high − highest for the same seed (the same training and evaluation traffic), with its Student-t 95 % interval
over the seeds (:func:`kddrl_trl.eval.verdict.t_interval`). A seed whose run lacks a record is left out of that
measure and named.

    python studies/performance/log/gpu_tf32_2026-11-27/summarize.py
"""

from __future__ import annotations

import json
import lzma
from pathlib import Path

import numpy as np
import pandas as pd

from kddrl_trl.eval.verdict import t_interval

HERE = Path(__file__).resolve().parent
PRECISIONS = ("highest", "high")


def load(seed: int, precision: str) -> dict:
    run = HERE / "runs" / f"{precision}_{seed}"
    summary = run / "summary.json"
    return {
        "summary": json.loads(summary.read_text()) if summary.is_file() else None,
        "train": pd.read_csv(run / "train_episodes.csv.xz"),
    }


def first_difference(seed: int) -> int | None:
    """Index of the first training episode whose record (its CSV line, as written) differs between the two
    precisions (None: identical)."""
    a, b = (
        lzma.open(HERE / "runs" / f"{p}_{seed}" / "train_episodes.csv.xz", "rt").read().splitlines()[1:]
        for p in PRECISIONS
    )
    return next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), None)


def paired(name: str, values: dict[int, tuple[float, float]], unit: str) -> dict:
    seeds = sorted(values)
    d = np.array([values[s][1] - values[s][0] for s in seeds])
    low, high, p = t_interval(d)
    return {
        "measure": name,
        "unit": unit,
        "seeds": seeds,
        "highest": [values[s][0] for s in seeds],
        "high": [values[s][1] for s in seeds],
        "difference": float(d.mean()),
        "ci": [low, high],
        "p": p,
    }


def main() -> dict:
    seeds = sorted({int(p.name.split("_")[1]) for p in (HERE / "runs").iterdir() if p.is_dir()})
    runs = {(s, p): load(s, p) for s in seeds for p in PRECISIONS}
    complete = [s for s in seeds if all(runs[s, p]["summary"] for p in PRECISIONS)]
    measures = []
    evaluation = {s: [runs[s, p]["summary"] for p in PRECISIONS] for s in complete}
    measures.append(
        paired(
            "evaluation mean speed", {s: tuple(r["mean_speed_kmh"] for r in v) for s, v in evaluation.items()}, "km/h"
        )
    )
    measures.append(
        paired(
            "evaluation collision rate",
            {s: tuple(100 * r["collision_rate"] for r in v) for s, v in evaluation.items()},
            "points",
        )
    )
    last = {s: [runs[s, p]["train"].tail(100) for p in PRECISIONS] for s in seeds}
    measures.append(
        paired(
            "training mean speed, last 100 episodes",
            {s: tuple(float(t["mean_speed_kmh"].mean()) for t in v) for s, v in last.items()},
            "km/h",
        )
    )
    measures.append(
        paired(
            "training collision rate, last 100 episodes",
            {s: tuple(100 * float(t["collision"].mean()) for t in v) for s, v in last.items()},
            "points",
        )
    )
    per_frame = {
        s: tuple(1e3 * r["training"]["update_s"] / r["training"]["frames"] for r in v) for s, v in evaluation.items()
    }
    measures.append(paired("learner update time per collected frame (8 runs sharing the GPU)", per_frame, "ms"))
    out = {
        "how": "run.sh: braking, 300 training and 200 evaluation episodes per run, device=cuda, matmul_precision "
        "highest and high for each seed, 8 runs at once on a lent H200 (2 cores each, sharing the GPU); "
        "differences are high - highest per seed, Student-t 95 % intervals over the seeds",
        "seeds": seeds,
        "complete_seeds": complete,
        "incomplete": {s: [p for p in PRECISIONS if not runs[s, p]["summary"]] for s in seeds if s not in complete},
        "first_differing_training_episode": {s: first_difference(s) for s in seeds},
        "measures": measures,
    }
    print(f"{'measure':<70} {'seeds':>5} {'high - highest [95 % CI]':>32} {'p':>6}")
    for m in measures:
        ci = f"{m['difference']:+.2f} [{m['ci'][0]:+.2f}, {m['ci'][1]:+.2f}] {m['unit']}"
        print(f"{m['measure']:<70} {len(m['seeds']):>5} {ci:>32} {m['p']:>6.2f}")
    print("first differing training episode per seed:", out["first_differing_training_episode"])
    (HERE / "summary.json").write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
