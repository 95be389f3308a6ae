"""The report: the paper's Tables II-V with across-seed 95 % CIs, comparisons with KDDRL, the
collision breakdown, the figures and a footer saying what produced them (``python -m kddrl_trl.report``).

The seed (run) is the unit of evidence: each run's evaluation episodes give one value per metric
(:meth:`~kddrl_trl.reporting.records.RunRecord.metrics`), and a row's value is the mean over its seeds with a
Student-t CI over seeds; every interval of the report, the verdict's included, comes from
:mod:`kddrl_trl.reporting.stats`. ``report.json`` is the machine-readable form, one shape for every report:
``{"rows", "claims", "commits", "plan_commit"}``, each row ``{"algo", "scenario", "seeds", "episodes", "metrics":
{name: {"mean", "ci_low", "ci_high"}}}``. A policy
evaluated on another scenario than it was trained on (``+scenario=mixed`` with ``eval_scenarios``, or
``kddrl_trl.evaluate``) is its own row, ``"<algo> (trained on <scenario>)"``
(:func:`~kddrl_trl.reporting.records.algo_label`), compared with the reference trained on the scenario evaluated.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import keys as K
from ..envs.fault import FAULTS
from ..eval.paper import PAPER_NAMES, TABLES, paper_value
from ..provenance import commit, machine, versions
from . import figures
from .records import RunRecord
from .stats import difference_ci, mean_ci, ratio_ci
from .verdict import CLAIMS, PLAN_COMMIT, TEST_SEEDS, exact_collisions, judge, speed_vs_rules

#: metric name -> (column title, unit, format); the first four are the paper's table columns
METRICS = {
    "mean_speed_kmh": ("mean speed", "km/h", "{:.1f}"),
    "mean_accel": ("mean acceleration", "m/s²", "{:.2f}"),
    "lane_changes_per_episode": ("lane changes per episode", "", "{:.2f}"),
    "lane_changes_per_1000_episodes": ("lane changes per 1000 episodes", "", "{:.0f}"),
    "collision_rate": ("collision rate", "", "{:.1%}"),
    "mean_abs_accel": ("mean |acceleration|", "m/s²", "{:.2f}"),
    "frame_speed_kmh_sd": ("sd of speed over frames", "km/h", "{:.1f}"),
    "frame_accel_sd": ("sd of acceleration over frames", "m/s²", "{:.2f}"),
    "return_lc": ("lane-change return", "", "{:.1f}"),
    "return_cf": ("car-following return", "", "{:.1f}"),
    "shield_rate": ("shield interventions (fraction of frames)", "", "{:.2%}"),  # algo.shield; 0 without one
}
TABLE_METRICS = (
    "mean_speed_kmh",
    "mean_accel",
    "lane_changes_per_episode",
    "lane_changes_per_1000_episodes",
    "collision_rate",
)
#: the metrics' possible ranges: their intervals are cut to them
RANGES = {"collision_rate": (0.0, 1.0), "shield_rate": (0.0, 1.0)}
REFERENCE = "kddrl"
#: the rule-based reference of the safety comparison (the safety goals are read against it)
RULE_REFERENCE = "idm_mobil"
#: fewer seeds than this on a side: no reading of a difference (a t interval over 2 seeds is all but unbounded)
MIN_SEEDS_FOR_VERDICT = 3
#: scenario order of the paper's tables
SCENARIO_ORDER = ("baseline", "congested", "congested_text", "braking", "mixed")


def _fmt(metric: str, value) -> str:
    return "n/a" if value is None else METRICS[metric][2].format(value)


def _cell(metric: str, stats: dict) -> str:
    mean = _fmt(metric, stats["mean"])
    if stats["ci_low"] is None:
        return f"{mean} (1 seed)"
    return f"{mean} [{_fmt(metric, stats['ci_low'])}, {_fmt(metric, stats['ci_high'])}]"


def _paper_cell(scenario: str, algo: str, metric: str) -> str:
    if metric == "lane_changes_per_episode":
        value = paper_value(scenario, algo, "lane_changes_per_1000_episodes")
        return "" if value is None else _fmt(metric, value[0] / 1000.0) + " (its total ÷ 1000)"
    value = paper_value(scenario, algo, metric)
    if value is None:
        return ""
    mean, sd = value
    return _fmt(metric, mean) + ("" if sd is None else f" ± {_fmt(metric, sd)}")


def _groups(runs: list[RunRecord]) -> dict[tuple[str, str], list[RunRecord]]:
    out: dict[tuple[str, str], list[RunRecord]] = {}
    for r in runs:
        out.setdefault((r.scenario, r.algo), []).append(r)
    order = {s: i for i, s in enumerate(SCENARIO_ORDER)}
    return dict(
        sorted(out.items(), key=lambda kv: (order.get(kv[0][0], 99), kv[0][0], kv[0][1] != REFERENCE, kv[0][1]))
    )


def rows(runs: list[RunRecord]) -> list[dict]:
    """The ``report.json`` rows: one per (algo, scenario), every metric of :data:`METRICS` over seeds."""
    out = []
    for (scenario, algo), group in _groups(runs).items():
        per_seed = [r.metrics() for r in group]
        out.append(
            {
                "algo": algo,
                "scenario": scenario,
                "commits": sorted({r.commit for r in group}),
                "trained_on": str(
                    group[0].summary.get("trained_on", scenario)
                ),  # algo: "<name> (trained on ...)" if not
                "seeds": sorted(r.seed for r in group),
                "episodes": int(sum(m["episodes"] for m in per_seed)),
                "episodes_per_seed": sorted({int(m["episodes"]) for m in per_seed}),
                "metrics": {
                    name: {
                        k: v
                        for k, v in mean_ci([m[name] for m in per_seed], within=RANGES.get(name)).items()
                        if k != "n"
                    }
                    for name in METRICS
                },
                "per_seed": {name: [m[name] for m in per_seed] for name in METRICS},
                "paper": {
                    name: paper_value(scenario, algo, name)
                    for name in METRICS
                    if paper_value(scenario, algo, name) is not None
                },
                "runs": [str(r.path) for r in group],
            }
        )
    return out


def _shielded(table_rows: list[dict]) -> bool:
    return any(row["metrics"]["shield_rate"]["mean"] > 0 for row in table_rows)


def _table(scenario: str, table_rows: list[dict]) -> list[str]:
    shown = TABLE_METRICS + (("shield_rate",) if _shielded(table_rows) else ())  # a column once a row has a shield
    head = ["algo (paper's name)", "seeds × episodes"] + [
        METRICS[m][0] + (f" ({METRICS[m][1]})" if METRICS[m][1] else "") for m in shown
    ]
    lines = [
        f"### {scenario} (paper {TABLES.get(scenario, 'no table')})",
        "",
        "Each cell: the mean over seeds [95 % Student-t CI over seeds: each seed, one trained policy, is one "
        "observation, collision rates included]; below it, the paper's value (mean ± its unexplained ±) where it "
        "published one.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for row in table_rows:
        n = row["episodes_per_seed"]
        cells = [
            f"**{row['algo']}** ({PAPER_NAMES.get(row['algo'], 'not in the paper')})",
            f"{len(row['seeds'])} × {n[0] if len(n) == 1 else n}",
        ]
        for m in shown:
            paper = _paper_cell(scenario, row["algo"], m)
            cells.append(_cell(m, row["metrics"][m]) + (f"<br>paper: {paper}" if paper else ""))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _verdict(diff: dict, metric: str, algo: str, n: tuple[int, int]) -> str:
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
    lines = [
        f"### {scenario}: each algo minus {REFERENCE}",
        "",
        "Difference of the across-seed means, Welch's 95 % CI (the verdict's test, unadjusted here), and the "
        f"probability of improvement P(algo > {REFERENCE}) over all pairs of seeds.",
        "",
        "| algo | metric | difference | 95 % CI | P(algo > kddrl) | reading |",
        "|---|---|---|---|---|---|",
    ]
    for row in others:
        for m in TABLE_METRICS:
            d = difference_ci(row["per_seed"][m], ref["per_seed"][m])
            ci = "n/a" if d["ci_low"] is None else f"[{_fmt(m, d['ci_low'])}, {_fmt(m, d['ci_high'])}]"
            lines.append(
                f"| {row['algo']} | {METRICS[m][0]} | {'+' if d['mean'] > 0 else ''}{_fmt(m, d['mean'])} | {ci} | {d['p_greater']:.2f} | "
                f"{_verdict(d, m, row['algo'], (len(row['seeds']), len(ref['seeds'])))} |"
            )
    return lines


def _against_rules(scenario: str, table_rows: list[dict]) -> list[str]:
    """Each other row against :data:`RULE_REFERENCE` on one scenario: its mean speed as a ratio of the rule
    baseline's and its collision rate minus the rule baseline's, with Welch's CIs over seeds (the safety goals:
    speed >= 1.05 x, collisions <= + 0.5 points on baseline, <= 2 % on braking)."""
    ref = next((r for r in table_rows if r["algo"] == RULE_REFERENCE), None)
    others = [r for r in table_rows if r["algo"] != RULE_REFERENCE]
    if ref is None or not others:
        return []
    shield = _shielded(table_rows)
    lines = [
        f"### {scenario}: each algo against {RULE_REFERENCE} ({figures.seed_count(len(ref['seeds']))})",
        "",
        f"Mean speed ÷ {RULE_REFERENCE}'s and collision rate − {RULE_REFERENCE}'s (percentage points), "
        "Welch's 95 % CI over seeds (of the log-ratio for the speed).",
        "",
        "| algo | seeds | speed ratio | 95 % CI | collision rate | collisions − rules | 95 % CI |"
        + (" shield interventions |" if shield else ""),
        "|---|---|---|---|---|---|---|" + ("---|" if shield else ""),
    ]
    for row in others:
        speed = ratio_ci(row["per_seed"]["mean_speed_kmh"], ref["per_seed"]["mean_speed_kmh"])
        hits = difference_ci(
            100.0 * np.asarray(row["per_seed"]["collision_rate"]), 100.0 * np.asarray(ref["per_seed"]["collision_rate"])
        )
        ci = [
            "n/a" if d["ci_low"] is None else f"[{d['ci_low']:{f}}, {d['ci_high']:{f}}]"
            for d, f in ((speed, ".3f"), (hits, "+.1f"))
        ]
        cells = [
            row["algo"],
            str(len(row["seeds"])),
            f"{speed['mean']:.3f}",
            ci[0],
            _fmt("collision_rate", row["metrics"]["collision_rate"]["mean"]),
            f"{hits['mean']:+.1f}",
            ci[1],
        ]
        if shield:
            cells.append(_fmt("shield_rate", row["metrics"]["shield_rate"]["mean"]))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def collision_breakdown(runs: list[RunRecord]) -> list[str]:
    """Per (scenario, algo): collisions by kind, by the other vehicle's role, during the ego's lane change, by who
    is at fault under RSS (:mod:`kddrl_trl.envs.fault`; "n/a" for records made before the class), and how the other
    episodes ended."""
    lines = [
        "| scenario | algo | episodes | collisions | "
        + " | ".join(K.COLLISION_KINDS[1:])
        + " | with a leader (a/b/c) | with a follower (d/e/f) | other vehicle unknown | ego changing lane | "
        + " | ".join(f"fault: {f}" for f in FAULTS)
        + " | other endings |",
        "|" + "---|" * (9 + len(K.COLLISION_KINDS) - 1 + len(FAULTS)),
    ]
    for (scenario, algo), group in _groups(runs).items():
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
        lines.append(
            f"| {scenario} | {algo} | {len(eps)} | {len(hits)} | "
            + " | ".join(str(kinds.get(k, 0)) for k in K.COLLISION_KINDS[1:])
            + f" | {roles['leader']} | {roles['follower']} | {roles['unknown']} | {changing} | "
            + " | ".join(str(faults.get(f, 0)) if faults is not None else "n/a" for f in FAULTS)
            + " | "
            + ", ".join(f"{k} {v}" for k, v in sorted(endings.items()))
            + " |"
        )
    return lines


def footer(runs: list[RunRecord], command: str) -> list[str]:
    protocols = Counter()
    for r in runs:
        p = r.summary.get("protocol")
        protocols[
            (
                "seed + 1,000,000"
                if p and p["eval_seed"] == r.seed + 1_000_000
                else f"eval seed {p['eval_seed']}"
                if p
                else "not recorded (run made before the protocol)"
            )
        ] += 1
    training, wall = zip(*_run_times(runs)) if runs else ((), ())
    machines = Counter(r.summary.get("machine", "not recorded") for r in runs)
    commits = Counter(r.commit for r in runs)
    packages = Counter(
        ", ".join(f"{k} {v}" for k, v in r.summary["packages"].items()) if "packages" in r.summary else "not recorded"
        for r in runs
    )
    return [
        "---",
        "",
        f"* **Command:** `{command}`",
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
        + " — never a training seed (`kddrl_trl/eval/protocol.py`). Training seeds: seed, seed + 1, ...",
        f"* **Wall time:** training {sum(t for t in training if t) / 3600:.2f} h over all runs (`training.elapsed_s` "
        f"of each `summary.json`, every session of a resumed run counted); the last session of each run, training "
        f"included, {sum(w for w in wall if w) / 3600:.2f} h (`wall_s`)"
        + ("" if all(wall) else f"; {sum(1 for w in wall if not w)} runs did not record it")
        + ".",
    ]


def _run_times(runs: list[RunRecord]) -> list[tuple[float | None, float | None]]:
    """``(training.elapsed_s, wall_s)`` of each training run behind ``runs``, once per run (a run's final
    evaluations, ``eval_scenarios=``, share their run's times: :attr:`RunRecord.trained_summary`)."""
    times = {
        r.trained: ((r.trained_summary.get("training") or {}).get("elapsed_s"), r.trained_summary.get("wall_s"))
        for r in runs
    }
    return list(times.values())


def split_commits(runs: list[RunRecord]) -> list[RunRecord]:
    """The runs, those made at a commit other than the most common one renamed ``"<algo> @<commit>"``: a row of
    their own, never pooled with the study's runs."""
    commits = Counter(r.commit for r in runs)
    main = commits.most_common(1)[0][0]
    return [
        r if r.commit == main else replace(r, algo=f"{r.algo} @{r.summary.get('commit', 'not recorded')}") for r in runs
    ]


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


def _claims_section(claims: list[dict], table_rows: list[dict], exact: dict, ratios: dict) -> list[str]:
    """The verdict of the analysis plan (``studies/paper/plan.md``): the primary claims with both readings and
    their description over all seeds, the secondary claims as exploratory estimates, and, per row, the pooled
    collision count and the speed ratio to IDM+MOBIL."""
    primary = [c for c in claims if c["family"] == "primary"]
    secondary = [c for c in claims if c["family"] != "primary"]
    seeds = f"{TEST_SEEDS[0]}-{TEST_SEEDS[-1]}"
    directions, sizes = Counter(c["direction"] for c in primary), Counter(c["size"] for c in primary)
    md = [
        "## The paper's claims",
        "",
        f"The analysis plan (`studies/paper/plan.md`) fixed {len(primary)} primary claims from the paper's text, the "
        f"test and n before the confirmatory seeds {seeds} ran. Each primary claim is tested once, on those seeds only, "
        "by Welch's t-test (the paired t-test for braking collisions, marked *paired*), with two questions, each "
        f"Holm-corrected over the {len(primary)}: **direction** (H0: no difference; *holds* / *contradicted* at an "
        "adjusted p < 0.05 in / against the claimed direction, else *inconclusive*) and **size** (H0: the paper's "
        "difference; *excluded, smaller* or *larger* along the claimed direction, else *compatible*). Until every "
        f"cell of the {len(primary)} has all its confirmatory seeds, every verdict reads *pending*: the test runs "
        "once, over the whole family (a pending claim whose cells are in shows its difference on those seeds, "
        "unadjusted). *described* is the estimate over all seeds "
        "(0-14, the pilot's included) with its 95 % interval. Collision differences in percentage points, speeds in "
        "km/h, lane changes per episode; `paper`: the same difference in the paper's tables.",
        "",
        "Beside each verdict stands the interval that agrees with it: the test's interval at the level at which "
        "Holm's step-down decides the claim (1 − 0.05 · p / p_Holm), which excludes 0 (for the size, the paper's "
        "difference) exactly when the adjusted p is below 0.05. The unadjusted 95 % interval and the simultaneous "
        f"one (Bonferroni, 1 − 0.05 / {len(primary)}) can disagree with a verdict: a claim that Holm decides at a "
        "later step can have a simultaneous interval that holds the null. *compatible* is a failure to reject the "
        "paper's difference, not a finding that ours equals it. *if 1 / 3 runs*: the size question again with the "
        "paper's difference read as one study's estimate from 1 or 3 runs per system at our spread, not as an "
        "exact constant (Holm over the family each). *p perm.*: the plan's permutation check (Welch's statistic "
        "over 99,999 reassignments of the seeds; exact sign flips where paired), Holm-adjusted; it decides nothing. "
        f"*power*: on the paper's difference at n = {len(TEST_SEEDS)}, at 0.05 / {len(primary)} "
        "and at 0.05, at the spread of all seeds; an inconclusive direction that this n could not decide names the "
        "seeds that 80 % power would need.",
        "",
        "**Direction:** "
        + ", ".join(f"{k} {v}" for k, v in sorted(directions.items()))
        + ". **Size:** "
        + ", ".join(f"{k} {v}" for k, v in sorted(sizes.items(), key=lambda kv: str(kv[0])))
        + f" (of {len(primary)} primary claims).",
        "",
        f"| # | claim | n ({seeds}) | a − b [95 % CI] | simultaneous CI | paper | p direction (Holm) | p perm. (Holm) "
        "| direction [Holm CI] | p size (Holm) | size [Holm CI] | size if 1 / 3 runs | power | "
        "described: a − b [95 % CI], seeds |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in primary:
        m, d = c["metric"], c["description"]
        direction = f"**{c['direction']}** {_interval(m, c.get('ci_direction'))}".strip()
        direction += "" if c["reading"] is None else f"; {c['reading']}"
        size = "—" if c["size"] is None else f"{c['size']} {_interval(m, c.get('ci_size'))}".strip()
        described = "—" if d is None else f"{_estimate(m, d['difference'], d['ci'])}, {min(d['n'])}"
        md.append(
            f"| {c['id']} | {c['claim']}{' (paired)' if c['test'] == 'paired' else ''} | {c['n']} | "
            f"{_estimate(m, c['difference'], c['ci'])} | {_interval(m, c['ci_simultaneous']) or '—'} | "
            f"{_num(m, c['paper'])} | {_p(c['p_direction_adjusted'])} | {_p(c.get('p_permutation_adjusted'))} | "
            f"{direction} | {_p(c['p_size_adjusted'])} | {size} | {_sensitivity(c)} | {_power_cell(c)} | "
            f"{described} |"
        )
    md += [
        "",
        "### Secondary claims (exploratory)",
        "",
        "Every other comparative statement of the paper, over all the seeds each system has: Welch's difference, "
        "its unadjusted 95 % interval and p-value. No verdict: these were not planned tests.",
        "",
        "| # | claim | seeds (a, b) | a − b [95 % CI] | p (unadjusted) | paper |",
        "|---|---|---|---|---|---|",
    ]
    for c in secondary:
        m, d = c["metric"], c["description"]
        n = "—" if d is None else f"{d['n'][0]}, {d['n'][1]}"
        md.append(
            f"| {c['id']} | {c['claim']} | {n} | {_estimate(m, c['difference'], c['ci'])} | "
            f"{_p(c['p'])} | {_num(m, c['paper'])} |"
        )
    md += [
        "",
        "### Collisions pooled, and speed against IDM+MOBIL",
        "",
        "Collisions pooled over a row's episodes with a Clopper-Pearson 95 % interval: a description of these "
        "trained policies, not an interval for the method (its seeds vary far more than a binomial; the tables' "
        "seed-level intervals are the method's). Speed as the mean of the per-seed ratios to IDM+MOBIL's speed on "
        "the same seeds (t interval), beside the paper's ratio.",
        "",
        "| scenario | algo | collisions / episodes, pooled | rate [exact 95 % CI] | speed ÷ IDM+MOBIL | paper |",
        "|---|---|---|---|---|---|",
    ]
    for row in table_rows:
        key = (row["scenario"], row["algo"])
        e, r = exact[key], ratios.get(key)
        ratio = (
            "—"
            if r is None
            else (f"{r['ratio']:.3f}" + ("" if r["ci"] is None else f" [{r['ci'][0]:.3f}, {r['ci'][1]:.3f}]"))
        )
        paper = "—" if r is None or r["paper"] is None else f"{r['paper']:.3f}"
        md.append(
            f"| {row['scenario']} | {row['algo']} | {e['collisions']} / {e['episodes']} | {e['rate']:.2%} "
            f"[{e['ci'][0]:.3%}, {e['ci'][1]:.3%}] | {ratio} | {paper} |"
        )
    return md + [""]


def build_report(
    runs: list[RunRecord],
    out_dir: str | Path,
    command: str = "python -m kddrl_trl.report",
    lcgan_metrics: dict | None = None,
    verdict: bool = False,
    title: str | None = None,
) -> dict:
    """Write ``report.md`` (headed ``title``, default "kddrl_trl report"), ``report.json`` and the figures into
    ``out_dir``; return the JSON content. ``report.json`` always has one shape: ``{"rows", "claims", "commits",
    "plan_commit"}``. ``verdict``: runs of other commits as rows of their own (:func:`split_commits`) and the paper's
    claims tested (:mod:`~kddrl_trl.reporting.verdict`); without it, ``claims`` is empty and ``plan_commit`` null."""
    from ..atomic_files import write_json_atomic, write_text_atomic

    if not runs:
        raise ValueError("build_report: no runs")
    if verdict:
        runs = split_commits(runs)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    table_rows = rows(runs)
    scenarios = list(dict.fromkeys(r["scenario"] for r in table_rows))
    md = [
        f"# {title or 'kddrl_trl report'}",
        "",
        f"{len(runs)} runs: "
        + ", ".join(f"{r['algo']} on {r['scenario']} ({figures.seed_count(len(r['seeds']))})" for r in table_rows)
        + ".",
        "",
        "## Tables II-V: driving metrics in evaluation",
        "",
    ]
    for s in scenarios:
        md += _table(s, [r for r in table_rows if r["scenario"] == s]) + [""]
    if verdict:
        claims, exact, ratios = judge(CLAIMS, table_rows), exact_collisions(runs), speed_vs_rules(table_rows)
        md += _claims_section(claims, table_rows, exact, ratios)
        for row in table_rows:
            row["collisions_exact"] = exact[(row["scenario"], row["algo"])]
            row["speed_vs_idm_mobil"] = ratios.get((row["scenario"], row["algo"]))
    comparisons = [line for s in scenarios for line in _comparisons(s, [r for r in table_rows if r["scenario"] == s])]
    if comparisons:  # a report of KDDRL alone, or without it, has nothing to compare
        md += ["## Comparison with KDDRL", ""]
        for s in scenarios:
            md += _comparisons(s, [r for r in table_rows if r["scenario"] == s]) + [""]
    against = [
        line for s in scenarios for line in _against_rules(s, [r for r in table_rows if r["scenario"] == s]) + [""]
    ]
    if any(against):
        md += [f"## Against the rule baseline ({RULE_REFERENCE})", ""] + against
    md += (
        [
            "## Collisions by kind",
            "",
            "Kinds (`kddrl_trl/keys.py`): `rear_end`, the ego ran into a vehicle ahead; `hit_from_behind`, a vehicle "
            "behind ran into the ego; `side`, any contact while the ego's lane change was under way. The other "
            "vehicle's role is its neighbour slot in the last observation before the contact. Episodes pooled over "
            "seeds.",
            "",
        ]
        + collision_breakdown(runs)
        + [""]
    )
    figs = {
        "Fig. 8: training curves": figures.training_curves(runs, out_dir / "fig08_training_curves.png"),
        "Figs. 9 / 15: evaluation returns": figures.return_boxes(runs, out_dir / "fig09_returns.png"),
    }
    for s, fig_no in zip(scenarios, ("10", "12", "13")):
        number = {"baseline": "10", "congested": "12", "congested_text": "12", "braking": "13"}.get(s, fig_no)
        figs[f"Fig. {number}: {s}, speed and acceleration"] = figures.distributions(
            runs, s, out_dir / f"fig{number}_distributions_{s}.png"
        )
    figs.update(figures.space_time(runs, out_dir))
    figs.update(figures.lcgan(lcgan_metrics, out_dir))
    md += ["## Figures", ""]
    for title, path in figs.items():
        md += [
            f"### {title}",
            "",
            f"![{title}]({Path(path).name})"
            if path
            else "Not drawn: "
            + (
                "no space-time traces in these runs (record them with `python -m kddrl_trl.evaluate "
                "run=<dir> video=true`)"
                if "14" in title
                else "the shipped lcGAN weights carry no test metrics"
                if "16" in title
                else "nothing to draw"
            ),
            "",
        ]
    md += [
        "## Runs",
        "",
        "| scenario | algo | seed | episodes | mean speed (km/h) | collision rate | wall time (s) | folder |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        m = r.metrics()
        wall = r.summary.get("wall_s")
        # one of a run's final evaluations (kddrl_trl.train eval_scenarios=...) is named with its run's folder; its
        # summary has no wall time of its own (the run's summary.json has the run's)
        folder = r.path.name if r.trained == r.path else f"{r.trained.name}/{r.path.name}"
        md.append(
            f"| {r.scenario} | {r.algo} | {r.seed} | {m['episodes']} | {m['mean_speed_kmh']:.1f} | "
            f"{m['collision_rate']:.1%} | {'—' if wall is None else f'{wall:.0f}'} | `{folder}` |"
        )
    md += [""] + footer(runs, command)
    if verdict:
        md.append(f"* **Analysis plan:** `studies/paper/plan.md`, fixed at commit {PLAN_COMMIT}")
    report = [
        {k: v for k, v in row.items() if k not in ("runs", "per_seed")} | {"per_seed": row["per_seed"]}
        for row in table_rows
    ]
    commits = Counter(r.commit for r in runs)
    write_json_atomic(
        out_dir / "report.json",
        {
            "rows": report,
            "claims": claims if verdict else [],
            "commits": dict(commits),
            "plan_commit": PLAN_COMMIT if verdict else None,
        },
    )
    write_text_atomic(out_dir / "report.md", "\n".join(md) + "\n")
    return {
        "rows": report,
        "figures": {k: str(v) if v else None for k, v in figs.items()},
        **({"claims": claims} if verdict else {}),
    }
