"""The HighwayEnv reuse measurement (studies/reuse/README.md): every arm's greedy mean speed and collision rate with
95 % intervals over seeds, and the paired differences that answer "do the predictive states help?".

    python studies/reuse/report.py [studies/reuse/runs] [--out studies/reuse]

Reads the runs of ``python -m kddrl_trl.train`` (``summary.json``) and the example's JSON results under the runs
folder, and writes ``results.json`` and ``results.md``. Per arm: the mean over seeds of each seed's evaluation
value with its Student-t interval over seeds (``kddrl_trl.reporting.stats.mean_test``; a collision rate's cut to
[0, 1], the range of a rate), and for the collision rate also the exact (Clopper-Pearson) interval over the pooled
episodes. Paired differences (the same seed gives every arm the same evaluation traffic) with their Student-t
interval over the seeds both arms have (a difference of collision rates cut to [-1, 1], the range it can take).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from kddrl_trl.atomic_files import write_json_atomic, write_text_atomic
from kddrl_trl.reporting.markdown import estimate
from kddrl_trl.reporting.records import find_runs
from kddrl_trl.reporting.stats import clopper_pearson, mean_test

HERE = Path(__file__).resolve().parent
#: arm -> its description
ARMS = {
    "a": "example TD3 with the transforms (HighwayEnv GANs)",
    "b": "example TD3 without the transforms",
    "c": "kddrl, SUMO GANs",
    "d": "kddrl, HighwayEnv GANs",
    "e": "d3qn_td3 (no predictive states)",
    "f": "idm_mobil",
    "g": "HighwayEnv's own IDM/MOBIL as the ego",
    "h": "example TD3 with the transforms, safe reward",
    "i": "example TD3 without the transforms, safe reward",
    "j": "HighwayEnv's IDM as the ego, lane kept (the example's reference)",
    "k": "example TD3 with the transforms, its default budget (1000 episodes, 8 roads), a 100k-frame buffer",
    "l": "example TD3 without the transforms, its default budget, a 100k-frame buffer",
    "m": "HighwayEnv's IDM as the ego, lane kept, on (k)'s evaluation traffic",
    "n": "example TD3 with the transforms, its default budget and 1M-frame buffer",
    "o": "example TD3 without the transforms, its default budget and 1M-frame buffer",
    "p": "HighwayEnv's IDM as the ego, lane kept, on (n)'s evaluation traffic",
    "q": "example TD3 with the transforms, its default budget, the best validated policy kept",
    "r": "example TD3 without the transforms, its default budget, the best validated policy kept",
    "s": "HighwayEnv's IDM as the ego, lane kept, on (q)'s evaluation traffic",
    "t": "the last policy of (q)'s runs",
    "u": "the last policy of (r)'s runs",
    "v": "example TD3 with the transforms, its default budget, the best validated policy, fixed observation scales",
    "w": "example TD3 without the transforms, its default budget, the best validated policy, fixed observation scales",
    "x": "HighwayEnv's IDM as the ego, lane kept, on (v)'s evaluation traffic",
    "y": "the last policy of (v)'s runs",
    "z": "the last policy of (w)'s runs",
}
#: the paired comparisons: (arm, reference arm, what a positive speed difference would mean)
PAIRS = [
    ("a", "b", "the transforms, in a plain TorchRL TD3"),
    ("d", "c", "HighwayEnv GANs instead of SUMO's"),
    ("d", "e", "KDDRL's predictive states and priors"),
    ("c", "e", "KDDRL with the SUMO GANs"),
    ("g", "f", "HighwayEnv's own driver against our IDM+MOBIL policy"),
    ("h", "i", "the transforms, in the example's TD3 with the safe reward"),
    ("h", "j", "the example with the transforms against its reference"),
    ("i", "j", "the example without the transforms against its reference"),
    ("k", "l", "the transforms, in the example at its default budget, a 100k-frame buffer"),
    ("k", "m", "the example at its default budget, a 100k-frame buffer, with the transforms, against its reference"),
    ("l", "m", "the example at its default budget, a 100k-frame buffer, without the transforms, against its reference"),
    ("n", "o", "the transforms, in the example at its default budget and buffer"),
    ("n", "p", "the example at its default budget and buffer, with the transforms, against its reference"),
    ("o", "p", "the example at its default budget and buffer, without the transforms, against its reference"),
    ("q", "r", "the transforms, in the example keeping its best validated policy"),
    ("q", "s", "the example keeping its best validated policy, with the transforms, against its reference"),
    ("r", "s", "the example keeping its best validated policy, without the transforms, against its reference"),
    ("q", "t", "keeping the best validated policy instead of the last, with the transforms (the same runs)"),
    ("r", "u", "keeping the best validated policy instead of the last, without the transforms (the same runs)"),
    ("v", "w", "the transforms, in the example with fixed observation scales, its best validated policy kept"),
    ("v", "x", "the example with fixed observation scales, with the transforms, against its reference"),
    ("w", "x", "the example with fixed observation scales, without the transforms, against its reference"),
    ("v", "q", "fixed observation scales instead of raw SI values, with the transforms (best policies kept)"),
    ("w", "r", "fixed observation scales instead of raw SI values, without the transforms (best policies kept)"),
    ("v", "y", "keeping the best validated policy instead of the last, with the transforms, fixed scales"),
    ("w", "z", "keeping the best validated policy instead of the last, without the transforms, fixed scales"),
]
#: folder of the example's results (under the runs folder) -> (arm with the transforms, without, the reference)
EXAMPLE_ARMS = {
    "example": ("a", "b", None),
    "example_safe": ("h", "i", "j"),
    "example_default_100k": ("k", "l", "m"),
    "example_default": ("n", "o", "p"),
    "example_best": ("q", "r", "s"),
    "example_scaled": ("v", "w", "x"),
}
#: folder of results that keep the best validated policy -> (arm of the last policy with the transforms, without):
#: the ``"last"`` evaluation each such JSON holds beside the kept one's
LAST_ARMS = {"example_best": ("t", "u"), "example_scaled": ("y", "z")}
METRICS = ("mean_speed_kmh", "collision_rate")


#: (scenario, the package's row label of a run, :func:`kddrl_trl.reporting.records.algo_label`) -> arm: the options that
#: tell the arms apart are the report's own (``algo.transforms.weights``, ``env.highwayenv.ego_driver``)
ARM_OF_ROW = {
    ("highwayenv", "kddrl [algo.transforms.weights=sumo]"): "c",
    ("highwayenv", "kddrl"): "d",
    ("highwayenv", "d3qn_td3"): "e",
    ("highwayenv", "idm_mobil"): "f",
    ("highwayenv", "idm_mobil [env.highwayenv.ego_driver=highwayenv]"): "g",
}


def read_results(runs: Path) -> dict[str, dict[int, dict]]:
    """arm -> seed -> {metric: value, "episodes", "collisions", "commit"}: the training runs as the package's report
    reads them (:func:`kddrl_trl.reporting.records.find_runs`), the example's JSON results under the folders of
    :data:`EXAMPLE_ARMS`."""
    out: dict[str, dict[int, dict]] = {arm: {} for arm in ARMS}
    records = find_runs([runs]) if any(runs.rglob("summary.json")) else []
    for rec in records:
        arm = ARM_OF_ROW.get((rec.scenario, rec.algo))
        if arm is not None:
            s = rec.summary
            out[arm][rec.seed] = {
                **{m: float(s[m]) for m in METRICS},
                "episodes": int(s["episodes"]),
                "collisions": int(s["outcomes"].get("collision", 0)),
                "commit": s.get("commit"),
            }
    for folder, (with_, without, reference) in EXAMPLE_ARMS.items():
        for path in sorted((runs / folder).glob("*.json")):
            r = json.loads(path.read_text())
            arm = reference if r["args"].get("reference") else with_ if r["args"]["transforms"] else without
            if arm is None:
                raise ValueError(f"{path}: a reference result in {folder}/, which holds none")
            out[arm][int(r["args"]["seed"])] = _example_result(r, r.get("commit"))
            if folder in LAST_ARMS and not r["args"].get("reference"):
                if "last" not in r:
                    raise ValueError(f'{path}: no "last" evaluation beside the kept policy\'s (--validate-every)')
                last = LAST_ARMS[folder][0 if r["args"]["transforms"] else 1]
                out[last][int(r["args"]["seed"])] = _example_result(r["last"], r.get("commit"))
    return out


def _example_result(r: dict, commit) -> dict:
    """An evaluation of the example's JSON (its own result or its ``"last"``) as :func:`read_results` holds it."""
    return {
        **{m: float(r[m]) for m in METRICS},
        "episodes": int(r["episodes"]),
        "collisions": round(r["collision_rate"] * r["episodes"]),
        "commit": commit,
    }


#: the range a metric can take (a difference of it between two arms: [low - high, high - low]); an interval over
#: seeds is cut to it
RANGE = {"collision_rate": (0.0, 1.0)}


def difference_range(metric: str) -> tuple[float, float] | None:
    """The range a difference of ``metric`` between two arms can take (None: unbounded)."""
    if metric not in RANGE:
        return None
    low, high = RANGE[metric]
    return low - high, high - low


def interval(values, within: tuple[float, float] | None = None) -> dict:
    """Mean over seeds with its Student-t interval, cut to ``within`` (the values' possible range) when given."""
    values = np.asarray(values, dtype=float)
    if values.size < 2:
        return {"mean": float(values.mean()) if values.size else None, "ci_low": None, "ci_high": None}
    t = mean_test(values)
    low, high, p = t["ci_low"], t["ci_high"], t["p"]
    if within is not None:
        low, high = max(low, within[0]), min(high, within[1])
    return {"mean": float(values.mean()), "ci_low": low, "ci_high": high, "p": p}


def summarise(results: dict[str, dict[int, dict]]) -> dict:
    arms = {}
    for arm, by_seed in results.items():
        seeds = sorted(by_seed)
        row = {"arm": arm, "system": ARMS[arm], "seeds": seeds}
        for m in METRICS:
            values = [by_seed[s][m] for s in seeds]
            row[m] = {**interval(values, RANGE.get(m)), "per_seed": values}
        k, n = sum(by_seed[s]["collisions"] for s in seeds), sum(by_seed[s]["episodes"] for s in seeds)
        row["collision_rate"]["pooled"] = {"collisions": k, "episodes": n}
        if n:
            row["collision_rate"]["pooled"]["clopper_pearson"] = list(clopper_pearson(k, n))
        row["commits"] = sorted({str(by_seed[s]["commit"]) for s in seeds})
        arms[arm] = row
    pairs = []
    for a, b, what in PAIRS:
        seeds = sorted(set(results[a]) & set(results[b]))
        pair = {"arm": a, "reference": b, "what": what, "seeds": seeds}
        for m in METRICS:
            pair[m] = interval([results[a][s][m] - results[b][s][m] for s in seeds], difference_range(m))
        pairs.append(pair)
    return {"arms": arms, "paired_differences": pairs}


def markdown(report: dict) -> str:
    lines = [
        "# HighwayEnv reuse measurement: results",
        "",
        "Made by `python studies/reuse/report.py` from `studies/reuse/runs/` (protocol: `studies/reuse/README.md`). Means over"
        " seeds with 95 % Student-t intervals over seeds (a collision rate's cut to [0, 100] %, a difference of two to"
        " [-100, 100] points); collisions also pooled over episodes (Clopper-Pearson).",
        "",
        "| arm | system | seeds | mean speed (km/h) | collision rate (%) | pooled collisions (95 % CI, %) |",
        "|---|---|---|---|---|---|",
    ]
    for arm, row in report["arms"].items():
        if not row["seeds"]:  # an arm not run yet
            continue
        pooled = row["collision_rate"]["pooled"]
        cp = pooled.get("clopper_pearson")
        pooled_s = f"{pooled['collisions']} / {pooled['episodes']}" + (
            f" [{100 * cp[0]:.1f}, {100 * cp[1]:.1f}]" if cp else ""
        )
        lines.append(
            f"| ({arm}) | {row['system']} | {len(row['seeds'])} | {estimate(row['mean_speed_kmh'], missing='–')} | "
            f"{estimate(row['collision_rate'], scale=100.0, missing='–')} | {pooled_s} |"
        )
    lines += [
        "",
        "Paired differences (same seeds, same evaluation traffic):",
        "",
        "| difference | what it measures | seeds | speed (km/h) | collision rate (points) |",
        "|---|---|---|---|---|",
    ]
    for p in report["paired_differences"]:
        if not p["seeds"]:
            continue
        lines.append(
            f"| ({p['arm']}) − ({p['reference']}) | {p['what']} | {len(p['seeds'])} | {estimate(p['mean_speed_kmh'], missing='–')} | "
            f"{estimate(p['collision_rate'], scale=100.0, missing='–')} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="?", default=str(HERE / "runs"))
    p.add_argument("--out", default=str(HERE))
    args = p.parse_args(argv)
    report = summarise(read_results(Path(args.runs)))
    out = Path(args.out)
    write_json_atomic(out / "results.json", report)
    write_text_atomic(out / "results.md", markdown(report))
    print(markdown(report))
    return report


if __name__ == "__main__":
    main()
