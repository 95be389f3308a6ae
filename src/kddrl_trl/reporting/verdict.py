"""A study's verdict: its planned claims (a claims file, :mod:`kddrl_trl.reporting.claims`; the verdict study's is
``studies/paper/claims.yaml``) tested on the per-seed values of a report's rows.

* **Primary family** (the file's ``primary``): each claim is tested once, on the plan's confirmatory seeds
  (``test_seeds``) only, by Welch's t-test, or the paired t-test where the plan pairs seeds,
  :mod:`kddrl_trl.reporting.stats`. Two questions, each Holm-corrected over the family:

  - *direction* (H0: Δ = 0): ``holds`` (adjusted p < 0.05, our Δ in the claimed direction), ``contradicted``
    (adjusted p < 0.05, against it) or ``inconclusive``;
  - *size* (H0: Δ = the paper's Δ, the same test on values shifted by it): ``excluded, smaller`` (ours is nearer
    zero than the paper's, or beyond zero, in the claimed direction), ``excluded, larger`` or ``compatible``.
    ``compatible`` is a failure to reject the paper's value, not a finding of equivalence.

  Beside each verdict, the interval that agrees with it (``ci_direction``, ``ci_size``): the test's interval at the
  level at which Holm's step-down decides the claim, 1 − α·p / p_Holm, which excludes 0 (the paper's Δ) exactly when
  the adjusted p is below α. The unadjusted 95 % interval (``ci``) and the Bonferroni one (``ci_simultaneous``, at
  1 − α / m for a family of m, which can disagree with a Holm verdict decided at a later step) stay beside them.
  Every primary claim also carries:

  - ``p_permutation`` and its Holm adjustment: a sensitivity check, which decides nothing
    (:func:`~kddrl_trl.reporting.stats.permutation_p`);
  - ``power`` on the paper's Δ at n = the confirmatory seeds, at 0.05 / m and at 0.05, and ``seeds_needed`` for 80 %
    power at each level, at the spread of all seeds. An inconclusive direction that n could not decide
    (``seeds_needed`` above it) has a ``reading`` naming that basis;
  - ``size_if_estimate``: the size question again with the paper's Δ read as a study of 1 and of 3 runs per
    system (the file's ``paper_runs``) with our spread, not as an exact constant (Holm over the family each;
    :func:`~kddrl_trl.reporting.stats.noisy_reference_test`).

  Until every cell of the family has all its confirmatory seeds, every verdict reads ``pending``: the test runs
  once, over the whole family. Every claim also carries its ``description``: the estimate and 95 % interval over all
  its seeds, the pilot's included.
* **Secondary claims** (the file's ``secondary``): exploratory: the estimate over all seeds, its unadjusted 95 %
  interval and p-value, no verdict.
"""

from __future__ import annotations

import numpy as np

from ..eval.paper import paper_value
from .claims import Claim
from .stats import (
    clopper_pearson,
    difference_test,
    holm,
    mean_ci,
    noisy_reference_test,
    permutation_p,
    seeds_for_power,
    t_power,
)

ALPHA = 0.05
RULES = "idm_mobil"
SPEED, COLL, LC, ACCEL_SD = "mean_speed_kmh", "collision_rate", "lane_changes_per_episode", "frame_accel_sd"
MEAN_ACCEL = "mean_accel"


def paper_difference(c: Claim) -> float | None:
    """The paper's ``a`` minus ``b`` on the claim's metric, in our units (lane changes per episode: its totals per
    1000 episodes ÷ 1000; the acceleration spread: its ``±`` of the mean acceleration)."""
    metric = {LC: "lane_changes_per_1000_episodes", ACCEL_SD: MEAN_ACCEL}.get(c.metric, c.metric)
    a, b = paper_value(c.scenario, c.a, metric), paper_value(c.scenario, c.b, metric)
    k = 1 if c.metric == ACCEL_SD else 0
    if a is None or b is None or a[k] is None or b[k] is None:
        return None
    return (a[k] - b[k]) * (1e-3 if c.metric == LC else 1.0)


def _by_seed(rows: list[dict], scenario: str, algo: str, metric: str) -> dict[int, float]:
    row = next((r for r in rows if r["scenario"] == scenario and r["algo"] == algo), None)
    return {} if row is None else dict(zip(row["seeds"], row["per_seed"][metric], strict=True))


def _sides(c: Claim, a: dict[int, float], b: dict[int, float], seeds) -> tuple[list[float], list[float]]:
    """Each side's values on ``seeds`` (each side's own seeds among them; paired: the seeds both have, in order)."""
    if c.paired:
        common = sorted(set(a) & set(b) & set(seeds))
        return [a[s] for s in common], [b[s] for s in common]
    return [a[s] for s in sorted(set(a) & set(seeds))], [b[s] for s in sorted(set(b) & set(seeds))]


def _test(c: Claim, a: dict[int, float], b: dict[int, float], seeds, null: float = 0.0, confidence: float = 0.95):
    """The claim's test on ``seeds`` (:func:`_sides`); None where a side has no value."""
    x, y = _sides(c, a, b, seeds)
    if not x or not y:
        return None
    return difference_test(x, y, null=null, paired=c.paired, confidence=confidence)


def _entry(c: Claim) -> dict:
    return {
        "id": c.id,
        "claim": c.text,
        "family": c.family,
        "table": c.table,
        "scenario": c.scenario,
        "metric": c.metric,
        "a": c.a,
        "b": c.b,
        "claimed": c.claimed,
        "test": "paired" if c.paired else "welch",
        "paper": paper_difference(c),
    }


def _describe(c: Claim, a: dict, b: dict) -> dict | None:
    d = _test(c, a, b, sorted(set(a) | set(b)))
    if d is None:
        return None
    return {"difference": d["mean"], "ci": _interval(d), "n": d["n"], "p": d["p"], "seeds": sorted(set(a) | set(b))}


def _interval(test: dict) -> list[float] | None:
    """``[low, high]`` of a result of :mod:`kddrl_trl.reporting.stats` (``ci_low``, ``ci_high``), None without one."""
    return None if test["ci_low"] is None else [test["ci_low"], test["ci_high"]]


def judge(claims, rows: list[dict], test_seeds, paper_runs=(1, 3)) -> list[dict]:
    """Every claim of ``claims`` on the per-seed values of ``rows`` (``report.json`` rows: ``seeds`` and
    ``per_seed`` in the same order): the primary ones tested on ``test_seeds`` as the plan says (Holm over those that could be
    tested, each question its own family), the secondary ones described (their verdicts and adjusted p-values
    null, so that every claim has the same keys)."""
    out, tested, primary = [], [], [c for c in claims if c.family == "primary"]
    m = len(primary)
    for c in claims:
        a, b = _by_seed(rows, c.scenario, c.a, c.metric), _by_seed(rows, c.scenario, c.b, c.metric)
        entry = _entry(c) | {"description": _describe(c, a, b)}
        desc = entry["description"]
        if c.family != "primary":
            d = desc or {}
            n = min(d["n"]) if desc else None
            entry |= {"difference": d.get("difference"), "ci": d.get("ci"), "n": n, "p": d.get("p")}
            out.append(entry | dict.fromkeys(("direction", "size", "p_direction_adjusted", "p_size_adjusted")))
            continue
        have = (set(a) & set(test_seeds), set(b) & set(test_seeds))
        entry |= {"seeds": sorted(have[0] & have[1]), "n": min(len(have[0]), len(have[1]))}
        complete = all(len(h) == len(test_seeds) for h in have)
        entry |= dict.fromkeys(_PRIMARY_KEYS, None)
        entry |= {} if complete else {"direction": "pending", "size": "pending"}
        if complete:
            t = _test(c, a, b, test_seeds)
            sim = _test(c, a, b, test_seeds, confidence=1 - ALPHA / m)
            entry |= {
                "difference": t["mean"],
                "ci": _interval(t),
                "ci_simultaneous": _interval(sim),
                "p_direction": t["p"],
                "p_permutation": permutation_p(*_sides(c, a, b, test_seeds), paired=c.paired),
            }
            if entry["paper"] is not None:
                entry["p_size"] = _test(c, a, b, test_seeds, null=entry["paper"])["p"]
                entry["size_if_estimate"] = {
                    str(r): {"runs": r, "p": _noisy(c, a, b, test_seeds, entry["paper"], r), "p_adjusted": None}
                    | {"size": None}
                    for r in paper_runs
                }
            if desc is not None and entry["paper"] is not None:
                entry |= _power(c, a, b, entry["paper"], len(test_seeds), m)
            tested.append((entry, c, a, b))
        out.append(entry)
    _adjust(out, paper_runs)
    for entry, c, a, b in tested:  # the intervals that agree with the adjusted verdicts
        for key, p, p_adjusted in (
            ("ci_direction", entry["p_direction"], entry["p_direction_adjusted"]),
            ("ci_size", entry["p_size"], entry["p_size_adjusted"]),
        ):
            if p is not None and p_adjusted is not None and p_adjusted > 0:
                entry[key] = _interval(_test(c, a, b, test_seeds, confidence=1 - ALPHA * p / p_adjusted))
    return out


#: the keys every primary claim has (null until its test runs)
_PRIMARY_KEYS = (
    "difference",
    "ci",
    "ci_simultaneous",
    "ci_direction",
    "ci_size",
    "p_direction",
    "p_size",
    "p_direction_adjusted",
    "p_size_adjusted",
    "p_permutation",
    "p_permutation_adjusted",
    "reading",
    "seeds_needed",
    "seeds_needed_alpha",
    "power",
    "size_if_estimate",
)


def _noisy(c: Claim, a: dict, b: dict, seeds, paper: float, runs: int) -> float | None:
    return noisy_reference_test(*_sides(c, a, b, seeds), paper, runs, c.paired)


def _power(c: Claim, a: dict, b: dict, paper: float, n: int, m: int) -> dict:
    """The power on the paper's difference at ``n`` seeds per system, at α / ``m`` (the family's first Holm step, a
    lower bound on Holm's power) and at α, and the seeds per system for 80 % power at each, at the spread of all
    seeds."""
    if c.paired:
        common = sorted(set(a) & set(b))
        sd = float(np.std([a[s] - b[s] for s in common], ddof=1)) if len(common) > 1 else 0.0
    else:
        x, y = np.array(list(a.values())), np.array(list(b.values()))
        sd = float(np.sqrt((x.var(ddof=1) + y.var(ddof=1)) / 2)) if min(x.size, y.size) > 1 else 0.0
    levels = {"family": ALPHA / m, "alpha": ALPHA}
    return {
        "seeds_needed": seeds_for_power(paper, sd, ALPHA / m, c.paired),
        "seeds_needed_alpha": seeds_for_power(paper, sd, ALPHA, c.paired),
        "power": {
            "n": n,
            "sd": sd,
            **{k: (t_power(paper, sd, n, v, c.paired) if sd > 0 else None) for k, v in levels.items()},
        },
    }


def _holm_into(entries: list[dict], get, put) -> None:
    """Holm over the entries whose ``get(entry)`` p-value exists; ``put(entry, adjusted)`` for each."""
    have = [e for e in entries if get(e) is not None]
    for e, p in zip(have, holm([get(e) for e in have]), strict=True):
        put(e, p)


def _adjust(entries: list[dict], paper_runs) -> None:
    """Holm over the primary family, the direction and the size each a family (and the permutation check, and each
    sensitivity row of the size, each its own); the verdicts. The test runs once, on the whole family: while any
    primary claim waits for its confirmatory seeds, every primary claim reads pending (Holm over the claims that are
    in would be a smaller family than the plan's, and its verdicts could not stand)."""
    primary = [e for e in entries if e["family"] == "primary"]
    if any(e.get("direction") == "pending" for e in primary):
        for e in primary:
            e["direction"] = e["size"] = "pending"
        return
    tested = [e for e in primary if e["p_direction"] is not None]
    for e, p in zip(tested, holm([e["p_direction"] for e in tested]), strict=True):
        e["p_direction_adjusted"] = p
        toward = e["difference"] > 0 if e["claimed"] == "greater" else e["difference"] < 0
        e["direction"] = ("holds" if toward else "contradicted") if p < ALPHA else "inconclusive"
        needed, n = e["seeds_needed"], e["n"]
        if e["direction"] == "inconclusive" and needed is not None and needed > n:
            e["reading"] = (
                f"underpowered: needs {needed:.0f} seeds per system for 80 % power on the paper's difference at "
                f"0.05/{len(primary)} ({e['seeds_needed_alpha']:.0f} at 0.05)"
            )
    _holm_into(tested, lambda e: e["p_permutation"], lambda e, p: e.update(p_permutation_adjusted=p))
    _holm_into(tested, lambda e: e["p_size"], lambda e, p: e.update(p_size_adjusted=p, size=_size_claim(e, p)))
    estimated = [e for e in tested if e["size_if_estimate"] is not None]
    for r in map(str, paper_runs):  # each sensitivity row its own family (the lambdas run within the iteration)
        _holm_into(
            estimated,
            lambda e: e["size_if_estimate"][r]["p"],
            lambda e, p: e["size_if_estimate"][r].update(p_adjusted=p, size=_size_claim(e, p)),
        )
    for e in tested:
        if e["p_size"] is None:
            e["size"] = None


def _size_claim(e: dict, p: float) -> str:
    if p >= ALPHA:
        return "compatible"
    sign = 1.0 if e["claimed"] == "greater" else -1.0
    return "excluded, larger" if sign * e["difference"] > sign * e["paper"] else "excluded, smaller"


def exact_collisions(runs) -> dict[tuple[str, str], dict]:
    """(scenario, algo) -> ``{"collisions", "episodes", "rate", "ci"}`` pooled over a row's runs (Clopper-Pearson):
    a description of those trained policies, not an interval for the method (its seeds vary more than a binomial)."""
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
        ratio = mean_ci([ours[s] / rules[s] for s in seeds])
        a, b = paper_value(row["scenario"], row["algo"], SPEED), paper_value(row["scenario"], RULES, SPEED)
        out[(row["scenario"], row["algo"])] = {
            "ratio": ratio["mean"],
            "ci": _interval(ratio),
            "seeds": seeds,
            "paper": None if a is None or b is None else a[0] / b[0],
        }
    return out
