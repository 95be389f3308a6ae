"""An arm of the braking study against its control, seed by seed (sections 2, 3 and 5 of studies/braking/README.md).

    python studies/braking/paired.py <arm sweep folder> <control sweep folder>... [--out paired.json]
    python studies/braking/paired.py ... --validation 3   # each run's last 3 validations instead of its test


Each run folder (``summary.json``) of the arm is paired with the controls' run of the same scenario, algo and
seed (several control folders may hold the controls of different algos, never one run twice): the same commit, training seed and test traffic, so that the per-seed differences remove what the seeds
share. Per algo, for the test collision rate (points) and mean speed (km/h): each side's mean over seeds with its
95 % t interval, and the paired difference arm - control with its paired t interval and p-value
(:func:`kddrl_trl.reporting.stats.difference_test`, the same code as the reports). A run of the arm without its
control is an error naming it; the controls' other runs are left out. ``--validation K``: each run's value is the
mean of its last K periodic validations (``validation.csv``, the validation traffic, seed + 500,000) instead of its
final test evaluation: a check that a result selected on test traffic holds on validation traffic too.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

from kddrl_trl.reporting import markdown
from kddrl_trl.reporting.markdown import estimate
from kddrl_trl.reporting.stats import difference_test, mean_ci
from kddrl_trl.run_folder import RunFolder

#: metric -> (label, scale, the scaled values' possible range: each side's interval is cut to it, as the reports do)
METRICS = {
    "collision_rate": ("test collisions (points)", 100.0, (0.0, 100.0)),
    "mean_speed_kmh": ("test mean speed (km/h)", 1.0, None),
}


def _last_validations(run: RunFolder, k: int) -> dict:
    """The mean of each metric over the run's last ``k`` validations."""
    path = next((p for p in (run.validation, run.validation.with_suffix(".csv.xz")) if p.is_file()), None)
    if path is None:
        raise SystemExit(f"paired.py: {run.path} has no validation.csv (restore the study's records first)")
    table = pd.read_csv(path)
    if len(table) < k:
        raise SystemExit(f"paired.py: {path} holds {len(table)} validations, --validation asks for {k}")
    return {metric: float(table[metric].tail(k).mean()) for metric in METRICS}


def runs(*sweeps: Path, validation: int = 0) -> dict:
    """``{(scenario, algo, seed): summary}`` of every finished run folder (:class:`RunFolder`) directly under the
    ``sweeps``; ``validation`` > 0: the metrics those runs' last ``validation`` validations averaged."""
    out, where = {}, {}
    for sweep in sweeps:
        found = [run for run in map(RunFolder, sorted(sweep.iterdir())) if run.is_finished()] if sweep.is_dir() else []
        if not found:
            raise SystemExit(f"paired.py: no finished run folder (with a summary.json) under {sweep}")
        for run in found:
            s = run.read_summary()
            if validation:
                s = s | _last_validations(run, validation)
            try:
                key = (s["scenario"], s["algo"], int(s["seed"]))
            except KeyError as err:
                raise SystemExit(f"paired.py: {run.summary} lacks the key {err}") from err
            if key in out:
                raise SystemExit(f"paired.py: {key} twice, in {where[key]} and {run.path}")
            out[key], where[key] = s, run.path
    return out


def paired(arm: dict, control: dict) -> dict:
    """``{"<scenario>/<algo>": {"seeds", metric: {"arm", "control", "difference"}}}`` over the runs both hold."""
    lone = sorted(set(arm) - set(control))
    if lone:
        raise SystemExit(f"paired.py: runs of the arm without their control (scenario, algo, seed): {lone}")
    out = {}
    for scenario, algo in sorted({k[:2] for k in arm}):
        seeds = sorted(k[2] for k in arm if k[:2] == (scenario, algo))
        row = {"seeds": seeds}
        for metric, (_, scale, within) in METRICS.items():
            a = [scale * arm[(scenario, algo, s)][metric] for s in seeds]
            c = [scale * control[(scenario, algo, s)][metric] for s in seeds]
            row[metric] = {
                "arm": mean_ci(a, within=within),
                "control": mean_ci(c, within=within),
                "difference": difference_test(a, c, paired=True),
                "per_seed": {"arm": a, "control": c},
            }
        out[f"{scenario}/{algo}"] = row
    return out


ONE = " (one seed)"  # an estimate without an interval


def table(result: dict, source: str = "test") -> str:
    """The markdown table of :func:`paired`: one row per algo and metric (``source``: the traffic the values are
    from, ``test`` or ``validation``)."""
    cells = []
    for name, row in result.items():
        for metric, (label, *_) in METRICS.items():
            m = row[metric]
            p = m["difference"]["p"]
            p = "" if p is None else "< 0.001" if p < 0.001 else f"{p:.3f}"
            seeds = ",".join(map(str, row["seeds"]))
            cells.append(
                [name, seeds, label.replace("test", source, 1), estimate(m["arm"], alone=ONE)]
                + [estimate(m["control"], alone=ONE), estimate(m["difference"], "+.1f", alone=ONE), p]
            )
    lines = markdown.table(["runs", "seeds", "metric", "arm", "control", "arm − control (paired)", "p"], cells)
    return "\n".join(lines)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("arm", type=Path)
    p.add_argument("control", type=Path, nargs="+")
    p.add_argument("--out", type=Path, help="also write the result as JSON")
    p.add_argument("--validation", type=int, default=0, metavar="K", help="the runs' last K validations, not the test")
    args = p.parse_args(argv)
    result = paired(runs(args.arm, validation=args.validation), runs(*args.control, validation=args.validation))
    print(table(result, "validation" if args.validation else "test"))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main(sys.argv[1:])
