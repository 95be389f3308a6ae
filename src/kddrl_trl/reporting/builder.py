"""The report (``python -m kddrl_trl.report``): computed (:func:`~kddrl_trl.reporting.contents.compute_report`),
drawn (:func:`~kddrl_trl.reporting.figures.draw_all`), written in markdown section by section
(:mod:`~kddrl_trl.reporting.sections`) beside ``report.json`` (:meth:`~kddrl_trl.reporting.contents.Report.json`).

``report.json`` has one shape for every report: ``{"rows", "claims", "commits", "plan_commit"}``, each row
``{"algo", "scenario", "seeds", "episodes", "metrics": {name: {"mean", "ci_low", "ci_high"}}, ...}``.
"""

from __future__ import annotations

from pathlib import Path

from . import sections
from .claims import ClaimPlan
from .contents import compute_report
from .figures import draw_all
from .records import RunRecord


def build_report(
    runs: list[RunRecord],
    out_dir: str | Path,
    command: str = "python -m kddrl_trl.report",
    lcgan_metrics: dict | bool | None = None,
    claims: ClaimPlan | None = None,
    title: str | None = None,
    space_time_figures: bool = True,
) -> dict:
    """Write ``report.md`` (headed ``title``, default "kddrl_trl report"), ``report.json`` and the figures into
    ``out_dir``; return the JSON's rows, the figures and the judged claims. ``lcgan_metrics``: the lcGAN's test metrics
    for Figs. 16 / 17 (None: there are none; False: not asked for). ``claims``: a claims file read
    (:func:`~kddrl_trl.reporting.claims.load_claims`): runs of other commits are rows of their own and its claims are
    tested (:mod:`~kddrl_trl.reporting.verdict`); without it, ``claims`` is empty and ``plan_commit`` null.
    ``space_time_figures``: false leaves Fig. 14 to another report of the same runs."""
    from ..atomic_files import write_json_atomic, write_text_atomic

    report = compute_report(runs, command, title, claims)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    drawn = draw_all(report.runs, report.scenarios, out_dir, lcgan_metrics, space_time_figures)
    md = sections.header(report) + sections.tables(report) + sections.claims(report) + sections.comparisons(report)
    md += sections.against_rules(report) + sections.collisions(report) + sections.figures(drawn)
    md += sections.runs_table(report) + sections.footer(report)
    data = report.json()
    write_json_atomic(out_dir / "report.json", data)
    write_text_atomic(out_dir / "report.md", "\n".join(md) + "\n")
    figures = {fig.title: str(fig.path) if fig.path else None for fig in drawn}
    return {"rows": data["rows"], "figures": figures, **({"claims": report.claims} if claims else {})}
