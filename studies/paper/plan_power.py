"""The power table of the verdict's analysis plan (studies/paper/plan.md), from the pilot seeds 0-4 in report.json.

    python studies/paper/plan_power.py [studies/paper/report.json]

For each primary claim: the pilot's difference, the across-seed standard deviation (pooled over the two systems;
of the paired differences for the claims the plan tests paired), and, at the Bonferroni level over the family
(0.05 / 17, a lower bound on what Holm grants), the power of the confirmatory test on n = 10 new seeds per cell
to find the paper's difference (direction) and to exclude the paper's difference were ours the pilot's (size),
and the seeds per cell that 80 % power on the paper's difference would need.
"""

from __future__ import annotations

import json
import sys

import numpy as np
from statsmodels.stats.power import TTestIndPower, TTestPower

from kddrl_trl.eval.paper import paper_value

SPEED, COLL = "mean_speed_kmh", "collision_rate"
#: (scenario, metric, a, b, claimed direction of a - b, tested paired)
PRIMARY = [
    (sc, m, "kddrl", b, "greater" if m == SPEED else "less", sc == "braking" and m == COLL)
    for sc in ("baseline", "congested", "braking")
    for b in ("ni", "peng")
    for m in (SPEED, COLL)
] + [
    ("baseline", COLL, "d3qn_td3_lg", "d3qn_td3", "less", False),
    ("baseline", COLL, "kddrl", "d3qn_td3_lg", "less", False),
    ("baseline", COLL, "kddrl", "kddrl_same_clock", "less", False),
    ("baseline", SPEED, "idm_mobil", "kddrl", "less", False),
    ("baseline", COLL, "idm_mobil", "d3qn_td3", "less", False),
]
ALPHA = 0.05 / len(PRIMARY)
VERB = {(SPEED, "greater"): "faster", (SPEED, "less"): "slower", (COLL, "less"): "fewer collisions"}
N_TEST = 10
REALISTIC = 50


def _power(effect: float, n: int, paired: bool) -> float:
    """Two-sided power of the t-test at ``ALPHA`` (statsmodels; its noncentral t returns NaN far out, where the
    power is 1 to many digits)."""
    solver = TTestPower() if paired else TTestIndPower()
    power = solver.power(effect, nobs=n, alpha=ALPHA) if paired else solver.power(effect, nobs1=n, alpha=ALPHA)
    return 1.0 if np.isnan(power) and effect > 2 else float(power)


def _n80(effect: float, paired: bool) -> float:
    for n in range(3, 100_000):
        if _power(effect, n, paired) >= 0.8:
            return n
    return float("inf")


def main(path: str = "studies/paper/report.json") -> None:
    rows = {(r["scenario"], r["algo"]): r for r in json.load(open(path))["rows"]}
    print("| claim | pilot a − b | paper | SD | r | power, direction | power, size | n for 80 % | reading |")
    print("|---|---|---|---|---|---|---|---|---|")
    for sc, m, a, b, direction, paired in PRIMARY:
        ra, rb = rows[(sc, a)], rows[(sc, b)]
        va, vb = dict(zip(ra["seeds"], ra["per_seed"][m])), dict(zip(rb["seeds"], rb["per_seed"][m]))
        seeds = [s for s in range(5) if s in va and s in vb]
        scale = 100.0 if m == COLL else 1.0
        x, y = np.array([va[s] for s in seeds]) * scale, np.array([vb[s] for s in seeds]) * scale
        paper = (paper_value(sc, a, m)[0] - paper_value(sc, b, m)[0]) * scale
        ours = float(x.mean() - y.mean())
        sd = float((x - y).std(ddof=1)) if paired else float(np.sqrt((x.var(ddof=1) + y.var(ddof=1)) / 2))
        r = float(np.corrcoef(x, y)[0, 1]) if x.std() > 0 and y.std() > 0 else float("nan")
        n80 = _n80(abs(paper) / sd, paired)
        reading = "not testable at a realistic n" if n80 > REALISTIC else ""
        unit = "pts" if m == COLL else "km/h"
        print(
            f"| {sc}: {a} {VERB[(m, direction)]} than {b}"
            f"{' (paired)' if paired else ''} | {ours:+.2f} {unit} | {paper:+.2f} | {sd:.2f} | {r:+.2f} "
            f"| {_power(abs(paper) / sd, N_TEST, paired):.2f} | {_power(abs(ours - paper) / sd, N_TEST, paired):.2f} "
            f"| {n80} | {reading} |"
        )


if __name__ == "__main__":
    main(*sys.argv[1:])
