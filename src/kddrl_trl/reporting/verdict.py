"""The paper's verdict: each comparative claim of Tables II-V tested on paired seeds.

The same seed gives every system the same evaluation traffic (``eval_seed`` = seed + 1,000,000,
:mod:`kddrl_trl.eval.protocol`), so two systems are compared seed by seed: ``d_i = x_i - y_i`` over the seeds both
have. A claim's ``difference`` is the mean of ``d``, its ``ci`` the 95 % Student-t interval over seeds (with 5 seeds
a percentile bootstrap would cover far less than 95 %), its ``p`` the two-sided paired t-test, and ``p_holm`` that
p-value adjusted by Holm-Bonferroni over the whole family of claims. The verdict:

* ``holds``: ``p_holm`` < 0.05 and ``d`` in the claimed direction;
* ``contradicted``: ``p_holm`` < 0.05 and ``d`` against it;
* ``inconclusive``: otherwise, or with fewer than :data:`MIN_PAIRS` paired seeds.

Collision rates are also given as exact binomial (Clopper-Pearson) intervals over a row's pooled episodes, so that
0 collisions in 5000 episodes reads [0, 0.074 %], and mean speeds as ratios to IDM+MOBIL on the same seeds, the
comparison that transfers from the paper's traffic to ours.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..eval.paper import paper_value

ALPHA = 0.05
#: fewer paired seeds than this: no test (``inconclusive``)
MIN_PAIRS = 3
RULES = "idm_mobil"


@dataclass(frozen=True)
class Claim:
    """``a``'s ``metric`` is ``direction`` (``"greater"`` or ``"less"``) than ``b``'s on ``scenario``."""

    claim: str
    table: str
    scenario: str
    metric: str
    a: str
    b: str
    direction: str


def _pairs(
    table: str, scenario: str, metric: str, a: str, others: tuple[str, ...], direction: str, text: str
) -> list[Claim]:
    return [Claim(text.format(a=a, b=b), table, scenario, metric, a, b, direction) for b in others]


SPEED, COLL, LC = "mean_speed_kmh", "collision_rate", "lane_changes_per_episode"
_II = ("ni", "peng", "d3qn_unified", "pasac_unified")
_V = ("kddrl", "d3qn_td3", "d3qn_td3_lg", "kddrl_same_clock")

#: the paper's comparative claims (§IV.D and Tables II-V), each as one paired comparison
CLAIMS: tuple[Claim, ...] = tuple(
    # Table II: "KDDRL achieves ... the highest average speed alongside the lowest collision rate"
    _pairs("II", "baseline", SPEED, "kddrl", _II, "greater", "Table II: {a} drives faster than {b}")
    + _pairs("II", "baseline", COLL, "kddrl", _II, "less", "Table II: {a} collides less than {b}")
    # "Peng et al. shows more frequent lane changes and a higher conflict rate than ... Ni et al."
    + _pairs("II", "baseline", LC, "peng", ("ni",), "greater", "Table II: {a} changes lanes more often than {b}")
    + _pairs("II", "baseline", COLL, "peng", ("ni",), "greater", "Table II: {a} collides more than {b}")
    # "the unified framework ... yield a much lower average speed while inducing excessive lane changes"
    + [
        c
        for u in ("d3qn_unified", "pasac_unified")
        for c in _pairs(
            "II", "baseline", SPEED, u, ("kddrl",), "less", "Table II (unified slower): {a} drives slower than {b}"
        )
        + _pairs(
            "II",
            "baseline",
            LC,
            u,
            ("kddrl",),
            "greater",
            "Table II (unified changes lanes more): {a} changes lanes more often than {b}",
        )
    ]
    # Tables III and IV: KDDRL fastest and safest
    + [
        c
        for s, t in (("congested", "III"), ("braking", "IV"))
        for c in _pairs(t, s, SPEED, "kddrl", ("ni", "peng"), "greater", f"Table {t}: {{a}} drives faster than {{b}}")
        + _pairs(t, s, COLL, "kddrl", ("ni", "peng"), "less", f"Table {t}: {{a}} collides less than {{b}}")
    ]
    # Table III: "Ni et al. executes the lowest number of lane changes"
    + _pairs("III", "congested", LC, "ni", ("peng", "kddrl"), "less", "Table III: {a} changes lanes less than {b}")
    # Table IV: "Ni et al. records the lowest average speed"
    + _pairs("IV", "braking", SPEED, "ni", ("peng", "kddrl"), "less", "Table IV: {a} drives slower than {b}")
    # Table V: "+LG lowers collisions against D3QN+TD3", "+TG lowers them further", "two clocks beat one clock"
    + _pairs("V", "baseline", COLL, "d3qn_td3_lg", ("d3qn_td3",), "less", "Table V (+LG): {a} collides less than {b}")
    + _pairs("V", "baseline", COLL, "kddrl", ("d3qn_td3_lg",), "less", "Table V (+TG): {a} collides less than {b}")
    + _pairs(
        "V",
        "baseline",
        COLL,
        "kddrl",
        ("kddrl_same_clock",),
        "less",
        "Table V (two clocks): {a} collides less than {b}",
    )
    + _pairs(
        "V",
        "baseline",
        SPEED,
        "kddrl",
        ("kddrl_same_clock",),
        "greater",
        "Table V (two clocks): {a} drives faster than {b}",
    )
    # "IDM+MOBIL is the slowest and the safest" (Table V)
    + _pairs("V", "baseline", SPEED, RULES, _V, "less", "Table V (rules slowest): {a} drives slower than {b}")
    + _pairs("V", "baseline", COLL, RULES, _V, "less", "Table V (rules safest): {a} collides less than {b}")
)


def t_interval(d, confidence: float = 1 - ALPHA) -> tuple[float, float, float]:
    """(low, high, two-sided p of mean 0) of the Student-t interval of the mean of ``d`` (n >= 2). Identical values:
    the interval is that value, p is 1 when it is 0 and 0 otherwise."""
    from scipy import stats

    d = np.asarray(d, dtype=float)
    mean = float(d.mean())
    if np.ptp(d) == 0:
        return mean, mean, 1.0 if mean == 0 else 0.0
    se = float(d.std(ddof=1) / np.sqrt(d.size))
    half = float(stats.t.ppf(0.5 + confidence / 2, d.size - 1)) * se
    p = float(2 * stats.t.sf(abs(mean) / se, d.size - 1))
    return mean - half, mean + half, p


def holm(pvalues) -> list[float]:
    """Holm-Bonferroni adjusted p-values (step-down, monotone, capped at 1), in the input's order."""
    p = np.asarray(pvalues, dtype=float)
    order = np.argsort(p)
    adjusted = np.empty_like(p)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, (p.size - rank) * p[i])
        adjusted[i] = min(1.0, running)
    return adjusted.tolist()


def clopper_pearson(k: int, n: int, confidence: float = 1 - ALPHA) -> tuple[float, float]:
    """Exact binomial interval of a rate of ``k`` events in ``n`` trials."""
    from scipy.stats import binomtest

    if n <= 0 or not 0 <= k <= n:
        raise ValueError(f"clopper_pearson: need 0 <= k <= n and n > 0, got k={k}, n={n}")
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=confidence, method="exact")
    return float(ci.low), float(ci.high)


def _by_seed(rows: list[dict], scenario: str, algo: str, metric: str) -> dict[int, float]:
    row = next((r for r in rows if r["scenario"] == scenario and r["algo"] == algo), None)
    return {} if row is None else dict(zip(row["seeds"], row["per_seed"][metric], strict=True))


def judge(claims, rows: list[dict]) -> list[dict]:
    """Every claim tested on the paired seeds of ``rows`` (``report.json`` rows: ``seeds`` and ``per_seed`` in the
    same order), Holm-adjusted over the claims that could be tested."""
    out = []
    for c in claims:
        a, b = _by_seed(rows, c.scenario, c.a, c.metric), _by_seed(rows, c.scenario, c.b, c.metric)
        seeds = sorted(set(a) & set(b))
        entry = {
            "claim": c.claim,
            "table": c.table,
            "scenario": c.scenario,
            "metric": c.metric,
            "a": c.a,
            "b": c.b,
            "direction": c.direction,
            "seeds": seeds,
            "difference": None,
            "ci": None,
            "p": None,
            "p_holm": None,
            "verdict": "inconclusive",
            "paper": _paper_difference(c),
        }
        if len(seeds) >= MIN_PAIRS:
            d = [a[s] - b[s] for s in seeds]
            low, high, p = t_interval(d)
            entry.update(difference=float(np.mean(d)), ci=[low, high], p=p)
        out.append(entry)
    tested = [e for e in out if e["p"] is not None]
    for e, p in zip(tested, holm([e["p"] for e in tested]), strict=True):
        e["p_holm"] = p
        if p < ALPHA:
            claimed = e["difference"] > 0 if e["direction"] == "greater" else e["difference"] < 0
            e["verdict"] = "holds" if claimed else "contradicted"
    return out


def _paper_difference(c: Claim) -> float | None:
    metric = "lane_changes_per_1000_episodes" if c.metric == LC else c.metric
    a, b = paper_value(c.scenario, c.a, metric), paper_value(c.scenario, c.b, metric)
    if a is None or b is None:
        return None
    scale = 1e-3 if c.metric == LC else 1.0  # the paper gives lane changes per 1000 episodes
    return (a[0] - b[0]) * scale


def exact_collisions(runs) -> dict[tuple[str, str], dict]:
    """(scenario, algo) -> ``{"collisions", "episodes", "rate", "ci"}`` pooled over a row's runs (Clopper-Pearson)."""
    pooled: dict[tuple[str, str], list[int]] = {}
    for r in runs:
        k = int(r.episodes["collision"].astype(bool).sum())
        acc = pooled.setdefault((r.scenario, r.algo), [0, 0])
        acc[0] += k
        acc[1] += len(r.episodes)
    return {
        key: {"collisions": k, "episodes": n, "rate": k / n, "ci": list(clopper_pearson(k, n))}
        for key, (k, n) in pooled.items()
    }


def speed_vs_rules(rows: list[dict]) -> dict[tuple[str, str], dict]:
    """(scenario, algo) -> the row's mean speed over IDM+MOBIL's on the same seeds (mean of the per-seed ratios,
    its t interval) and the paper's ratio where it published both speeds."""
    out = {}
    for row in rows:
        if row["algo"] == RULES:
            continue
        rules = _by_seed(rows, row["scenario"], RULES, SPEED)
        ours = dict(zip(row["seeds"], row["per_seed"][SPEED], strict=True))
        seeds = sorted(set(rules) & set(ours))
        if not seeds:
            continue
        ratios = [ours[s] / rules[s] for s in seeds]
        low, high, _ = t_interval(ratios) if len(ratios) >= 2 else (None, None, None)
        a, b = paper_value(row["scenario"], row["algo"], SPEED), paper_value(row["scenario"], RULES, SPEED)
        out[(row["scenario"], row["algo"])] = {
            "ratio": float(np.mean(ratios)),
            "ci": None if low is None else [low, high],
            "seeds": seeds,
            "paper": None if a is None or b is None else a[0] / b[0],
        }
    return out
