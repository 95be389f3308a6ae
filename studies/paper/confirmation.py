"""The preset's confirmation beside its selection: ``+preset=plus`` (``algo.shield=idm``) for KDDRL and D3QN+TD3.

The selection rows are the runs the preset was chosen on (``studies/ablation/runs``: ``plus`` and ``shield_idm``, the
same configuration, for KDDRL; ``d3qn_plus`` for D3QN+TD3), measured against the IDM+MOBIL runs that study used
(``studies/reproduction/runs``). The confirmation rows are this study's runs on fresh seeds 5-9 (``studies/paper/runs``,
its pinned commit), measured against IDM+MOBIL on the same seeds. Both phases use the ablation study's measures
(:mod:`kddrl_trl.reporting.stats`: the ratio of the across-seed mean speeds and the difference of the across-seed mean
collision rates, each seed one observation, with Welch's intervals) and its three goals for the preset:

- mean speed >= 1.05 x IDM+MOBIL's, in both scenarios;
- braking: collisions <= 2 %;
- baseline: collisions <= IDM+MOBIL's + 0.5 percentage points.

A goal reads ``met`` when the whole 95 % interval is inside its bound, ``mean only`` when the mean is and the
interval crosses it, ``missed`` when the mean is outside. Collisions are also given pooled over the episodes, with an
exact (Clopper-Pearson) interval: a description of those trained policies, not an interval for the method.

    python studies/paper/confirmation.py  ->  the Markdown table on standard output
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np

from kddrl_trl.reporting import markdown
from kddrl_trl.reporting.markdown import estimate
from kddrl_trl.reporting.records import find_runs
from kddrl_trl.reporting.stats import difference_ci, mean_ci, ratio_ci
from kddrl_trl.reporting.verdict import exact_collisions

DOCS = Path(__file__).resolve().parents[1]
SYSTEMS = {  # the report's row name -> the selection study's folders
    "kddrl [algo.shield=idm]": ("plus", "shield_idm"),
    "d3qn_td3 [algo.shield=idm]": ("d3qn_plus",),
}
CONFIRMATION_SEEDS = range(5, 10)
SPEED_RATIO, BRAKING_COLLISIONS, BASELINE_MARGIN = 1.05, 0.02, 0.005


@cache
def _found(folders: tuple[Path, ...]) -> list:
    return find_runs(folders)


def _runs(folders, algo: str, scenario: str, seeds=None) -> list:
    runs = [r for r in _found(tuple(folders)) if r.algo == algo and r.scenario == scenario]
    return [r for r in runs if seeds is None or r.seed in seeds]


def _goal(value: dict, bound: float, at_least: bool) -> str:
    inside = (lambda v: v >= bound) if at_least else (lambda v: v <= bound)
    if not inside(value["mean"]):
        return "missed"
    edge = value["ci_low"] if at_least else value["ci_high"]
    return "met" if edge is not None and inside(edge) else "mean only"


def _pooled(runs: list) -> str:
    """Collisions pooled over the runs' episodes (one row's runs: :func:`~kddrl_trl.reporting.verdict.exact_collisions`):
    ``k / n = rate [exact 95 % CI]``."""
    (pooled,) = exact_collisions(runs).values()
    k, n, (lo, hi) = pooled["collisions"], pooled["episodes"], pooled["ci"]
    return f"{k} / {n} = {100 * k / n:.2f} % [{100 * lo:.2f}, {100 * hi:.2f}]"


def row(system: str, scenario: str, phase: str, runs: list, reference: list) -> list[str]:
    if not runs or not reference:
        raise ValueError(f"{system}, {scenario}, {phase}: {len(runs)} runs, {len(reference)} IDM+MOBIL runs")
    speed = [r.summary["mean_speed_kmh"] for r in runs]
    ref_speed = [r.summary["mean_speed_kmh"] for r in reference]
    rate = [r.summary["collision_rate"] for r in runs]
    ref_rate = [r.summary["collision_rate"] for r in reference]
    ratio, extra = ratio_ci(speed, ref_speed), difference_ci(rate, ref_rate)
    goals = [f"speed {_goal(ratio, SPEED_RATIO, True)}"]
    if scenario == "braking":
        goals.append(f"collisions {_goal(mean_ci(rate, within=(0.0, 1.0)), BRAKING_COLLISIONS, False)}")
    else:
        goals.append(f"collisions {_goal(extra, BASELINE_MARGIN, False)}")
    seeds = ",".join(str(r.seed) for r in runs)
    commits = ", ".join(sorted({r.commit for r in runs}))
    shield = float(np.mean([r.summary.get("shield_rate", 0.0) for r in runs]))
    speed_ratio, extra_rate = estimate(ratio, ".3f", alone=" [—]"), estimate(extra, "+.2f", 100, alone=" [—]")
    cells = [system, scenario, phase, seeds, commits, speed_ratio, _pooled(runs), extra_rate]
    return cells + [f"{100 * shield:.0f} %", "; ".join(goals)]


def table(docs: Path = DOCS) -> str:
    head = ["system", "scenario", "phase", "seeds", "commits", "speed ÷ IDM+MOBIL's [95 % CI]"]
    head += ["collisions, pooled [exact 95 % CI]", "− IDM+MOBIL's (points) [95 % CI]", "shield rate", "goals"]
    lines = []
    for system, folders in SYSTEMS.items():
        for scenario in ("baseline", "braking"):
            selection = _runs([docs / "ablation" / "runs" / f for f in folders], system, scenario)
            old_rules = _runs([docs / "reproduction" / "runs"], "idm_mobil", scenario)
            lines.append(row(system, scenario, "selection", selection, old_rules))
            study = [docs / "paper" / "runs"]
            fresh = _runs(study, system, scenario, CONFIRMATION_SEEDS)
            rules = _runs(study, "idm_mobil", scenario, {r.seed for r in fresh})
            lines.append(row(system, scenario, "confirmation", fresh, rules))
    return "\n".join(markdown.table(head, lines))


#: the README's safety rows: (label, the report's row name, the study's records folder, seeds); every row on the
#: same seeds 5-9, so that the rows compare the same traffic (the paper's method there: the confirmatory runs)
SAFETY_ROWS = (
    ("KDDRL, the paper's method", "kddrl", "runs_5-14", CONFIRMATION_SEEDS),
    ("KDDRL + shield (`+preset=plus`)", "kddrl [algo.shield=idm]", "runs", CONFIRMATION_SEEDS),
    ("IDM+MOBIL", "idm_mobil", "runs", CONFIRMATION_SEEDS),
)


def safety_table(docs: Path = DOCS) -> str:
    """The README's short safety table, from the study's runs alone (one commit): each row's mean speed and
    collision rate over seeds [95 % t CI, each seed one observation] and, as a description of those five policies,
    its collisions pooled over the episodes [exact 95 % CI]. A row short of 5 seeds is refused: the table stands for
    the finished confirmation."""
    lines = []
    for scenario in ("baseline", "braking"):
        for label, algo, folder, seeds in SAFETY_ROWS:
            runs = _runs([docs / "paper" / folder], algo, scenario, seeds)
            if len(runs) < 5:
                raise ValueError(f"{algo}, {scenario}: {len(runs)} of seeds {list(seeds)}, the table needs 5")
            speed = estimate(mean_ci([r.summary["mean_speed_kmh"] for r in runs]), ".1f", alone=" [—]")
            rate = estimate(
                mean_ci([r.summary["collision_rate"] for r in runs], within=(0.0, 1.0)), ".2f", 100, alone=" [—]"
            )
            (pooled,) = exact_collisions(runs).values()
            k, n, (lo, hi) = pooled["collisions"], pooled["episodes"], pooled["ci"]
            pooled = f"{k} / {n} [{100 * lo:.2f}, {100 * hi:.2f}]"
            lines.append([scenario, label, f"{min(seeds)}-{max(seeds)}", speed, rate, pooled])
    head = ["scenario", "system", "seeds", "speed (km/h)", "collisions (%)", "pooled [exact CI, %]"]
    return "\n".join(markdown.table(head, lines))


if __name__ == "__main__":
    print(table())
    print()
    print(safety_table())
