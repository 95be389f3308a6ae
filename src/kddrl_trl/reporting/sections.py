"""The report's sections in markdown, each a function of the :class:`~kddrl_trl.reporting.contents.Report` (or of
what it holds) returning its lines: the paper's Tables II-V with across-seed 95 % CIs (:func:`tables`), the claims
of a claims file (:func:`claims`), the comparisons with KDDRL and with the rule baseline, the collision breakdown, the
figures, the runs and a footer saying what produced them.

A policy evaluated on another scenario than it was trained on (``+scenario=mixed`` with ``eval_scenarios``, or
``kddrl_trl.evaluate``) is its own row, ``"<algo> (trained on <scenario>)"``
(:func:`~kddrl_trl.reporting.records.algo_label`), compared with the reference trained on the scenario evaluated.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from .. import keys as K
from ..envs.fault import FAULTS
from ..eval.paper import PAPER_NAMES, TABLES, paper_value
from ..provenance import commit, machine, versions
from .claims import NOUN
from .contents import REFERENCE, RULE_REFERENCE, Report, groups, shielded
from .figures import Drawn, seed_count
from .markdown import section, table
from .metrics import METRICS, TABLE_METRICS, fmt
from .records import RunRecord
from .stats import difference_ci, ratio_ci

#: fewer seeds than this on a side: no reading of a difference (a t interval over 2 seeds is all but unbounded)
MIN_SEEDS_FOR_VERDICT = 3
#: the claims' summary table's words, by (metric, direction)
SHORT_VERB = {
    ("mean_speed_kmh", "greater"): "faster than",
    ("mean_speed_kmh", "less"): "slower than",
    ("collision_rate", "less"): "collides less than",
}


def header(report: Report) -> list[str]:
    return [
        f"# {report.title}",
        "",
        f"{len(report.runs)} runs: "
        + ", ".join(f"{r['algo']} on {r['scenario']} ({seed_count(len(r['seeds']))})" for r in report.rows)
        + ".",
        "",
        "## Tables II-V: driving metrics in evaluation",
        "",
    ]


def _cell(metric: str, stats: dict) -> str:
    mean = fmt(metric, stats["mean"])
    if stats["ci_low"] is None:
        return f"{mean} (1 seed)"
    return f"{mean} [{fmt(metric, stats['ci_low'])}, {fmt(metric, stats['ci_high'])}]"


def _paper_cell(scenario: str, algo: str, metric: str) -> str:
    if metric == "lane_changes_per_episode":
        value = paper_value(scenario, algo, "lane_changes_per_1000_episodes")
        return "" if value is None else fmt(metric, value[0] / 1000.0) + " (its total ÷ 1000)"
    value = paper_value(scenario, algo, metric)
    if value is None:
        return ""
    mean, sd = value
    return fmt(metric, mean) + ("" if sd is None else f" ± {fmt(metric, sd)}")


def scenario_table(scenario: str, table_rows: list[dict]) -> list[str]:
    """One scenario's table (the paper's Table II, III or IV): each row's metrics over seeds, the paper's below."""
    shown = TABLE_METRICS + (("shield_rate",) if shielded(table_rows) else ())  # a column once a row has a shield
    head = ["algo (paper's name)", "seeds × episodes"] + [
        METRICS[m][0] + (f" ({METRICS[m][1]})" if METRICS[m][1] else "") for m in shown
    ]
    cells = []
    for row in table_rows:
        n = row["episodes_per_seed"]
        line = [
            f"**{row['algo']}** ({PAPER_NAMES.get(row['algo'], 'not in the paper')})",
            f"{len(row['seeds'])} × {n[0] if len(n) == 1 else n}",
        ]
        for m in shown:
            paper = _paper_cell(scenario, row["algo"], m)
            line.append(_cell(m, row["metrics"][m]) + (f"<br>paper: {paper}" if paper else ""))
        cells.append(line)
    text = (
        "Each cell: the mean over seeds [95 % Student-t CI over seeds: each seed, one trained policy, is one "
        "observation, collision rates included]; below it, the paper's value (mean ± its unexplained ±) where it "
        "published one."
    )
    return section(f"### {scenario} (paper {TABLES.get(scenario, 'no table')})", text, table(head, cells))


def tables(report: Report) -> list[str]:
    return [line for s in report.scenarios for line in scenario_table(s, report.rows_of(s)) + [""]]


def _verdict(diff: dict, algo: str, n: tuple[int, int]) -> str:
    if diff["ci_low"] is None:
        return "one seed on a side: no interval"
    if min(n) < MIN_SEEDS_FOR_VERDICT:
        return f"too few seeds for a reading ({n[0]} vs {n[1]})"
    if diff["ci_low"] > 0:
        return f"{algo} is higher"
    if diff["ci_high"] < 0:
        return f"{algo} is lower"
    return f"no clear difference at {n[0]} vs {n[1]} seeds (the CI holds 0)"


def _comparisons(scenario: str, table_rows: list[dict]) -> list[str]:
    ref = next((r for r in table_rows if r["algo"] == REFERENCE), None)
    others = [r for r in table_rows if r["algo"] != REFERENCE]
    if ref is None or not others:
        return []
    lines = []
    for row in others:
        for m in TABLE_METRICS:
            d = difference_ci(row["per_seed"][m], ref["per_seed"][m])
            ci = "n/a" if d["ci_low"] is None else f"[{fmt(m, d['ci_low'])}, {fmt(m, d['ci_high'])}]"
            n = (len(row["seeds"]), len(ref["seeds"]))
            sign = "+" if d["mean"] > 0 else ""
            lines.append(
                [row["algo"], METRICS[m][0], f"{sign}{fmt(m, d['mean'])}", ci, f"{d['p_greater']:.2f}"]
                + [_verdict(d, row["algo"], n)]
            )
    text = (
        "Difference of the across-seed means, Welch's 95 % CI (the verdict's test, unadjusted here), and the "
        f"probability of improvement P(algo > {REFERENCE}) over all pairs of seeds."
    )
    return section(
        f"### {scenario}: each algo minus {REFERENCE}",
        text,
        table(["algo", "metric", "difference", "95 % CI", "P(algo > kddrl)", "reading"], lines),
    )


def comparisons(report: Report) -> list[str]:
    """Each algo against KDDRL, per scenario; nothing for a report of KDDRL alone, or without it."""
    per = [_comparisons(s, report.rows_of(s)) for s in report.scenarios]
    if not any(per):
        return []
    return ["## Comparison with KDDRL", ""] + [line for lines in per for line in lines + [""]]


def _against_rules(scenario: str, table_rows: list[dict]) -> list[str]:
    """Each other row against :data:`RULE_REFERENCE` on one scenario: its mean speed as a ratio of the rule
    baseline's and its collision rate minus the rule baseline's, with Welch's CIs over seeds (the safety goals:
    speed >= 1.05 x, collisions <= + 0.5 points on baseline, <= 2 % on braking)."""
    ref = next((r for r in table_rows if r["algo"] == RULE_REFERENCE), None)
    others = [r for r in table_rows if r["algo"] != RULE_REFERENCE]
    if ref is None or not others:
        return []
    shield = shielded(table_rows)
    head = ["algo", "seeds", "speed ratio", "95 % CI", "collision rate", "collisions − rules", "95 % CI"]
    cells = []
    for row in others:
        speed = ratio_ci(row["per_seed"]["mean_speed_kmh"], ref["per_seed"]["mean_speed_kmh"])
        hits = difference_ci(
            100.0 * np.asarray(row["per_seed"]["collision_rate"]), 100.0 * np.asarray(ref["per_seed"]["collision_rate"])
        )
        ci = [
            "n/a" if d["ci_low"] is None else f"[{d['ci_low']:{f}}, {d['ci_high']:{f}}]"
            for d, f in ((speed, ".3f"), (hits, "+.1f"))
        ]
        rate = fmt("collision_rate", row["metrics"]["collision_rate"]["mean"])
        line = [row["algo"], str(len(row["seeds"])), f"{speed['mean']:.3f}", ci[0], rate, f"{hits['mean']:+.1f}", ci[1]]
        cells.append(line + ([fmt("shield_rate", row["metrics"]["shield_rate"]["mean"])] if shield else []))
    text = (
        f"Mean speed ÷ {RULE_REFERENCE}'s and collision rate − {RULE_REFERENCE}'s (percentage points), "
        "Welch's 95 % CI over seeds (of the log-ratio for the speed)."
    )
    return section(
        f"### {scenario}: each algo against {RULE_REFERENCE} ({seed_count(len(ref['seeds']))})",
        text,
        table(head + (["shield interventions"] if shield else []), cells),
    )


def against_rules(report: Report) -> list[str]:
    against = [line for s in report.scenarios for line in _against_rules(s, report.rows_of(s)) + [""]]
    return [f"## Against the rule baseline ({RULE_REFERENCE})", ""] + against if any(against) else []


def collision_breakdown(runs: list[RunRecord]) -> list[str]:
    """Per (scenario, algo): collisions by kind, by the other vehicle's role, during the ego's lane change, by who
    is at fault under RSS (:mod:`kddrl_trl.envs.fault`; "n/a" for records made before the class), and how the other
    episodes ended."""
    head = ["scenario", "algo", "episodes", "collisions", *K.COLLISION_KINDS[1:], "with a leader (a/b/c)"]
    head += ["with a follower (d/e/f)", "other vehicle unknown", "ego changing lane"]
    head += [f"fault: {f}" for f in FAULTS] + ["other endings"]
    cells = []
    for (scenario, algo), group in groups(runs).items():
        eps = [e for r in group for e in r.episodes.to_dict("records")]
        hits = [e for e in eps if e["collision"]]
        kinds = Counter(e["collision_kind"] for e in hits)
        roles = Counter(
            "leader" if e["collision_with"] in K.LEADER_SLOTS else "follower" if e["collision_with"] else "unknown"
            for e in hits
        )
        changing = (
            sum(bool(e.get("ended_changing_lane", False)) for e in hits)
            if "ended_changing_lane" in group[0].episodes.columns
            else "n/a"
        )
        endings = Counter(e["outcome"] for e in eps if not e["collision"])
        classed = all("collision_fault" in r.episodes.columns for r in group)
        faults = Counter(e["collision_fault"] for e in hits) if classed else None
        cells.append(
            [scenario, algo, str(len(eps)), str(len(hits)), *(str(kinds.get(k, 0)) for k in K.COLLISION_KINDS[1:])]
            + [str(roles["leader"]), str(roles["follower"]), str(roles["unknown"]), str(changing)]
            + [str(faults.get(f, 0)) if faults is not None else "n/a" for f in FAULTS]
            + [", ".join(f"{k} {v}" for k, v in sorted(endings.items()))]
        )
    return table(head, cells)


def collisions(report: Report) -> list[str]:
    return [
        "## Collisions by kind",
        "",
        "Kinds (`kddrl_trl/keys.py`): `rear_end`, the ego ran into a vehicle ahead; `hit_from_behind`, a vehicle "
        "behind ran into the ego; `side`, any contact while the ego's lane change was under way. The other "
        "vehicle's role is its neighbour slot in the last observation before the contact. Episodes pooled over "
        "seeds.",
        "",
        *collision_breakdown(report.runs),
        "",
    ]


def figures(drawn: list[Drawn]) -> list[str]:
    md = ["## Figures", ""]
    for fig in drawn:
        body = f"![{fig.title}]({Path(fig.path).name})" if fig.path else f"Not drawn: {fig.missing}"
        md += [f"### {fig.title}", "", body, ""]
    return md


def runs_table(report: Report) -> list[str]:
    cells = []
    for r in report.runs:
        m = r.metrics()
        wall = r.summary.get("wall_s")
        # one of a run's final evaluations (kddrl_trl.train eval_scenarios=...) is named with its run's folder; its
        # summary has no wall time of its own (the run's summary.json has the run's)
        folder = r.path.name if r.trained == r.path else f"{r.trained.name}/{r.path.name}"
        cells.append(
            [r.scenario, r.algo, str(r.seed), str(m["episodes"]), f"{m['mean_speed_kmh']:.1f}"]
            + [f"{m['collision_rate']:.1%}", "—" if wall is None else f"{wall:.0f}", f"`{folder}`"]
        )
    head = ["scenario", "algo", "seed", "episodes", "mean speed (km/h)", "collision rate", "wall time (s)", "folder"]
    return ["## Runs", ""] + table(head, cells) + [""]


def footer(report: Report) -> list[str]:
    runs = report.runs
    protocols = Counter(_protocol(r) for r in runs)
    training, wall = zip(*_run_times(runs)) if runs else ((), ())
    machines = Counter(r.summary.get("machine", "not recorded") for r in runs)
    commits = Counter(r.commit for r in runs)
    packages = Counter(
        ", ".join(f"{k} {v}" for k, v in r.summary["packages"].items()) if "packages" in r.summary else "not recorded"
        for r in runs
    )
    lines = [
        "---",
        "",
        f"* **Command:** `{report.command}`",
        f"* **Report made at commit** {commit()} on {machine()}; **packages:** "
        + ", ".join(f"{k} {v}" for k, v in versions().items()),
        "* **Runs made at commits:** "
        + "; ".join(f"{c} ({n} runs)" for c, n in commits.items())
        + ". **On machines:** "
        + "; ".join(f"{m} ({n} runs)" for m, n in machines.items())
        + ". **With packages:** "
        + "; ".join(f"{p} ({n} runs)" for p, n in packages.items()),
        f"* **Runs:** {len(runs)}; seeds per (algo, scenario) in the tables. **Evaluation protocol:** greedy policy "
        "(exploration off), the first N episodes to *start* (unbiased by episode length), env seed "
        + "; ".join(f"{k} ({n} runs)" for k, n in protocols.items())
        + " — never a training seed (`kddrl_trl/protocol.py`). Training seeds: seed, seed + 1, ...",
        f"* **Wall time:** training {sum(t for t in training if t) / 3600:.2f} h over all runs (`training.elapsed_s` "
        f"of each `summary.json`, every session of a resumed run counted); the last session of each run, training "
        f"included, {sum(w for w in wall if w) / 3600:.2f} h (`wall_s`)"
        + ("" if all(wall) else f"; {sum(1 for w in wall if not w)} runs did not record it")
        + ".",
    ]
    if report.plan is not None:
        lines.append(f"* **Analysis plan:** `{report.plan.plan}`, fixed at commit {report.plan.plan_commit}")
    return lines


def _protocol(r: RunRecord) -> str:
    p = r.summary.get("protocol")
    if not p:
        return "not recorded (run made before the protocol)"
    return "seed + 1,000,000" if p["eval_seed"] == r.seed + 1_000_000 else f"eval seed {p['eval_seed']}"


def _run_times(runs: list[RunRecord]) -> list[tuple[float | None, float | None]]:
    """``(training.elapsed_s, wall_s)`` of each training run behind ``runs``, once per run (a run's final
    evaluations, ``eval_scenarios=``, share their run's times: :attr:`RunRecord.trained_summary`), a seed of a
    batch with its share of the batch's (:attr:`RunRecord.seed_share`)."""

    def share(t: float | None, r: RunRecord) -> float | None:
        return None if t is None else t * r.seed_share

    times = {
        r.trained: (
            share((r.trained_summary.get("training") or {}).get("elapsed_s"), r),
            share(r.trained_summary.get("wall_s"), r),
        )
        for r in runs
    }
    return list(times.values())


# ------------------------------------------------------------------------------------------------- the claims
def _num(metric: str, v, unit: bool = True) -> str:
    """A difference in the claims' units: collision rates in percentage points, the rest as they are."""
    if v is None:
        return "—"
    return (f"{100 * v:+.2f}" + (" pts" if unit else "")) if metric == "collision_rate" else f"{v:+.2f}"


def _interval(metric: str, ci) -> str:
    return "" if ci is None else f"[{_num(metric, ci[0], False)}, {_num(metric, ci[1], False)}]"


def _estimate(metric: str, value, ci) -> str:
    return "—" if value is None else f"{_num(metric, value)} {_interval(metric, ci)}".strip()


def _p(p) -> str:
    return "—" if p is None else ("1" if p >= 1 else f"{p:.2g}")


def _sensitivity(c: dict) -> str:
    """The size reading with the paper's difference read as a 1-run and a 3-run estimate: ``excluded / compatible``."""
    rows = c.get("size_if_estimate")
    if not rows:
        return "—"
    return " / ".join(r["size"] or "—" for r in rows.values())


def _power_cell(c: dict) -> str:
    power = c.get("power")
    if not power or power["family"] is None:
        return "—"
    return f"{power['family']:.2f} / {power['alpha']:.2f}"


def span(seeds) -> str:
    """``5-14`` for a run of consecutive seeds, else the seeds listed."""
    seeds = sorted(seeds)
    if seeds and seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}" if len(seeds) > 1 else str(seeds[0])
    return ", ".join(map(str, seeds))


def claims_intro(report: Report) -> list[str]:
    """What the claims section reads: the plan's test, its two questions and the columns."""
    plan, m = report.plan, len(report.plan.primary)
    seeds, primary = span(plan.test_seeds), [c for c in report.claims if c["family"] == "primary"]
    paired = sorted({f"{c.scenario} {NOUN.get(c.metric, c.metric)}" for c in plan.primary if c.paired})
    paired_note = f" (the paired t-test for {' and '.join(paired)}, marked *paired*)" if paired else ""
    described = f"{span(plan.pilot_seeds + plan.test_seeds)}, the pilot's included" if plan.pilot_seeds else seeds
    directions, sizes = Counter(c["direction"] for c in primary), Counter(c["size"] for c in primary)
    return [
        f"## {plan.title}",
        "",
        f"The analysis plan (`{plan.plan}`) fixed {m} primary claims from the paper's text, the "
        f"test and n before the confirmatory seeds {seeds} ran. Each primary claim is tested once, on those seeds only, "
        f"by Welch's t-test{paired_note}, with two questions, each "
        f"Holm-corrected over the {m}: **direction** (H0: no difference; *holds* / *contradicted* at an "
        "adjusted p < 0.05 in / against the claimed direction, else *inconclusive*) and **size** (H0: the paper's "
        "difference; *excluded, smaller* or *larger* along the claimed direction, else *compatible*). Until every "
        f"cell of the {m} has all its confirmatory seeds, every verdict reads *pending*: the test runs "
        "once, over the whole family (a pending claim whose cells are in shows its difference on those seeds, "
        "unadjusted). *described* is the estimate over all seeds "
        f"({described}) with its 95 % interval. Collision differences in percentage points, speeds in "
        "km/h, lane changes per episode; `paper`: the same difference in the paper's tables.",
        "",
        "Beside each verdict stands the interval that agrees with it: the test's interval at the level at which "
        "Holm's step-down decides the claim (1 − 0.05 · p / p_Holm), which excludes 0 (for the size, the paper's "
        "difference) exactly when the adjusted p is below 0.05. The unadjusted 95 % interval and the simultaneous "
        f"one (Bonferroni, 1 − 0.05 / {m}) can disagree with a verdict: a claim that Holm decides at a "
        "later step can have a simultaneous interval that holds the null. *compatible* is a failure to reject the "
        "paper's difference, not a finding that ours equals it. *if 1 / 3 runs*: the size question again with the "
        "paper's difference read as one study's estimate from 1 or 3 runs per system at our spread, not as an "
        "exact constant (Holm over the family each). *p perm.*: the plan's permutation check (Welch's statistic "
        "over 99,999 reassignments of the seeds; exact sign flips where paired), Holm-adjusted; it decides nothing. "
        f"*power*: on the paper's difference at n = {len(plan.test_seeds)}, at 0.05 / {m} "
        "and at 0.05, at the spread of all seeds; an inconclusive direction that this n could not decide names the "
        "seeds that 80 % power would need.",
        "",
        "**Direction:** "
        + ", ".join(f"{k} {v}" for k, v in sorted(directions.items()))
        + ". **Size:** "
        + ", ".join(f"{k} {v}" for k, v in sorted(sizes.items(), key=lambda kv: str(kv[0])))
        + f" (of {m} primary claims).",
        "",
    ]


def claims_summary(claims: list[dict], names: dict[str, str]) -> str:
    """The primary claims in short, from judged claims (``report.json``'s ``claims``): the difference on the confirmatory seeds (or over the
    seeds so far while pending) in km/h or points, the paper's, the direction (with the seeds 80 % power would
    need where underpowered) and the size. ``names``: the systems' short names (the claims file's)."""

    def diff(c: dict, value, ci) -> str:
        scale = 100.0 if c["metric"] == "collision_rate" else 1.0
        if value is None:
            return "—"
        return f"{scale * value:+.1f}" + ("" if ci is None else f" [{scale * ci[0]:+.1f}, {scale * ci[1]:+.1f}]")

    cells = []
    for c in (c for c in claims if c.get("family") == "primary"):
        scale = 100.0 if c["metric"] == "collision_rate" else 1.0
        verb = SHORT_VERB.get((c["metric"], c["claimed"]), f"{c['claimed']} {c['metric']} than")
        claim = f"{c['scenario']}: {names.get(c['a'], c['a'])} {verb} {names.get(c['b'], c['b'])}"
        if c["direction"] == "pending":
            d = c["description"]
            ours = "—" if d is None else f"{diff(c, d['difference'], d['ci'])}, n={min(d['n'])} so far"
        else:
            ours = diff(c, c["difference"], c["ci"])
        direction = c["direction"] + (f" ({c['seeds_needed']:.0f})" if c.get("reading") else "")
        paper = "—" if c["paper"] is None else f"{scale * c['paper']:+.1f}"
        cells.append([c["id"], claim, ours, paper, direction, c["size"] or "—"])
    head = ["#", "claim", "ours: a − b [95 % CI]", "paper", "direction (seeds needed)", "size"]
    return "\n".join(table(head, cells))


def primary_claims(report: Report) -> list[str]:
    seeds = span(report.plan.test_seeds)
    head = ["#", "claim", f"n ({seeds})", "a − b [95 % CI]", "simultaneous CI", "paper", "p direction (Holm)"]
    head += ["p perm. (Holm)", "direction [Holm CI]", "p size (Holm)", "size [Holm CI]", "size if 1 / 3 runs"]
    head += ["power", "described: a − b [95 % CI], seeds"]
    cells = []
    for c in (c for c in report.claims if c["family"] == "primary"):
        m, d = c["metric"], c["description"]
        direction = f"**{c['direction']}** {_interval(m, c.get('ci_direction'))}".strip()
        direction += "" if c["reading"] is None else f"; {c['reading']}"
        size = "—" if c["size"] is None else f"{c['size']} {_interval(m, c.get('ci_size'))}".strip()
        described = "—" if d is None else f"{_estimate(m, d['difference'], d['ci'])}, {min(d['n'])}"
        cells.append(
            [c["id"], c["claim"] + (" (paired)" if c["test"] == "paired" else ""), str(c["n"])]
            + [_estimate(m, c["difference"], c["ci"]), _interval(m, c["ci_simultaneous"]) or "—", _num(m, c["paper"])]
            + [_p(c["p_direction_adjusted"]), _p(c.get("p_permutation_adjusted")), direction]
            + [_p(c["p_size_adjusted"]), size, _sensitivity(c), _power_cell(c), described]
        )
    return table(head, cells)


def secondary_claims(report: Report) -> list[str]:
    cells = []
    for c in (c for c in report.claims if c["family"] != "primary"):
        m, d = c["metric"], c["description"]
        n = "—" if d is None else f"{d['n'][0]}, {d['n'][1]}"
        cells.append([c["id"], c["claim"], n, _estimate(m, c["difference"], c["ci"]), _p(c["p"]), _num(m, c["paper"])])
    text = (
        "Every other comparative statement of the paper, over all the seeds each system has: Welch's difference, "
        "its unadjusted 95 % interval and p-value. No verdict: these were not planned tests."
    )
    return section(
        "### Secondary claims (exploratory)",
        text,
        table(["#", "claim", "seeds (a, b)", "a − b [95 % CI]", "p (unadjusted)", "paper"], cells),
    )


def pooled_collisions(report: Report) -> list[str]:
    cells = []
    for row in report.rows:
        e, r = row["collisions_exact"], row["speed_vs_idm_mobil"]
        ratio = (
            "—"
            if r is None
            else (f"{r['ratio']:.3f}" + ("" if r["ci"] is None else f" [{r['ci'][0]:.3f}, {r['ci'][1]:.3f}]"))
        )
        paper = "—" if r is None or r["paper"] is None else f"{r['paper']:.3f}"
        rate = f"{e['rate']:.2%} [{e['ci'][0]:.3%}, {e['ci'][1]:.3%}]"
        cells.append([row["scenario"], row["algo"], f"{e['collisions']} / {e['episodes']}", rate, ratio, paper])
    head = ["scenario", "algo", "collisions / episodes, pooled", "rate [exact 95 % CI]", "speed ÷ IDM+MOBIL", "paper"]
    text = (
        "Collisions pooled over a row's episodes with a Clopper-Pearson 95 % interval: a description of these "
        "trained policies, not an interval for the method (its seeds vary far more than a binomial; the tables' "
        "seed-level intervals are the method's). Speed as the mean of the per-seed ratios to IDM+MOBIL's speed on "
        "the same seeds (t interval), beside the paper's ratio."
    )
    return section("### Collisions pooled, and speed against IDM+MOBIL", text, table(head, cells))


def claims(report: Report) -> list[str]:
    """The plan's claims (a claims file): the primary ones in short and with both readings, the secondary ones as
    exploratory estimates, and the pooled collisions and speed ratios; nothing without a plan."""
    if report.plan is None:
        return []
    short = ["### In short", "", claims_summary(report.claims, report.plan.names), ""]
    return (
        claims_intro(report)
        + short
        + ["### The primary claims, both readings", ""]
        + primary_claims(report)
        + [""]
        + secondary_claims(report)
        + [""]
        + pooled_collisions(report)
        + [""]
    )
