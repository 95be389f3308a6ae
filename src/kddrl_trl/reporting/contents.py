"""What a report holds, computed before any of it is written (:class:`Report`): the rows of ``report.json`` (one per
(algo, scenario), every metric over seeds), the claims tested where a claims file is given, and the pooled
collisions and speed ratios beside them. :mod:`~kddrl_trl.reporting.sections` turns it into markdown,
:func:`~kddrl_trl.reporting.builder.build_report` writes it.

The seed (run) is the unit of evidence: each run's evaluation episodes give one value per metric
(:meth:`~kddrl_trl.reporting.records.RunRecord.metrics`), and a row's value is the mean over its seeds with a
Student-t CI over seeds (:mod:`kddrl_trl.reporting.stats`).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, replace

from ..eval.paper import paper_value
from .claims import ClaimPlan
from .metrics import METRICS, RANGES
from .records import RunRecord
from .stats import mean_ci
from .verdict import exact_collisions, judge, speed_vs_rules

REFERENCE = "kddrl"
#: the rule-based reference of the safety comparison (the safety goals are read against it)
RULE_REFERENCE = "idm_mobil"
#: scenario order of the paper's tables
SCENARIO_ORDER = ("baseline", "congested", "congested_text", "braking", "mixed")


@dataclass
class Report:
    """A report's content. ``rows``: the ``report.json`` rows (with ``runs`` and ``per_seed``, which the JSON keeps
    per seed only); ``claims``: the judged claims (:func:`~kddrl_trl.reporting.verdict.judge`) when ``plan`` is
    given, else empty."""

    title: str
    command: str
    runs: list[RunRecord]
    rows: list[dict]
    plan: ClaimPlan | None = None
    claims: list[dict] | None = None

    @property
    def scenarios(self) -> list[str]:
        return list(dict.fromkeys(r["scenario"] for r in self.rows))

    def rows_of(self, scenario: str) -> list[dict]:
        return [r for r in self.rows if r["scenario"] == scenario]

    def json(self) -> dict:
        """``report.json``: ``{"rows", "claims", "commits", "plan_commit"}``, one shape for every report."""
        rows = [
            {k: v for k, v in row.items() if k not in ("runs", "per_seed")} | {"per_seed": row["per_seed"]}
            for row in self.rows
        ]
        return {
            "rows": rows,
            "claims": self.claims or [],
            "commits": dict(Counter(r.commit for r in self.runs)),
            "plan_commit": self.plan.plan_commit if self.plan else None,
        }


def compute_report(runs: list[RunRecord], command: str, title: str | None = None, plan: ClaimPlan | None = None):
    """The :class:`Report` of ``runs``. With ``plan``, runs of other commits are rows of their own
    (:func:`split_commits`), the plan's claims are judged, and each row gets its pooled collisions
    (``collisions_exact``) and its speed over IDM+MOBIL's (``speed_vs_idm_mobil``)."""
    if not runs:
        raise ValueError("build_report: no runs")
    if plan is not None:
        runs = split_commits(runs)
    report = Report(title or "kddrl_trl report", command, runs, rows(runs), plan)
    if plan is not None:
        report.claims = judge(plan.claims, report.rows, plan.test_seeds, plan.paper_runs)
        exact, ratios = exact_collisions(runs), speed_vs_rules(report.rows)
        for row in report.rows:
            row["collisions_exact"] = exact[(row["scenario"], row["algo"])]
            row["speed_vs_idm_mobil"] = ratios.get((row["scenario"], row["algo"]))
    return report


def groups(runs: list[RunRecord]) -> dict[tuple[str, str], list[RunRecord]]:
    """The runs by (scenario, algo), in the paper's scenario order, KDDRL first within a scenario."""
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
    for (scenario, algo), group in groups(runs).items():
        per_seed = [r.metrics() for r in group]
        out.append(
            {
                "algo": algo,
                "scenario": scenario,
                "commits": sorted({r.commit for r in group}),
                "trained_on": str(group[0].summary.get("trained_on", scenario)),  # algo: "<name> (trained on ...)"
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


def split_commits(runs: list[RunRecord]) -> list[RunRecord]:
    """The runs, those made at a commit other than the most common one renamed ``"<algo> @<commit>"``: a row of
    their own, never pooled with the study's runs."""
    commits = Counter(r.commit for r in runs)
    main = commits.most_common(1)[0][0]
    return [
        r if r.commit == main else replace(r, algo=f"{r.algo} @{r.summary.get('commit', 'not recorded')}") for r in runs
    ]


def shielded(table_rows: list[dict]) -> bool:
    """Whether a row of ``table_rows`` drove with a shield (its column is shown then)."""
    return any(row["metrics"]["shield_rate"]["mean"] > 0 for row in table_rows)
