"""The short verdict table: the analysis plan's 17 primary claims (``studies/paper/plan.md``), read from a verdict
report's ``report.json`` (:mod:`kddrl_trl.reporting.verdict`).

    python -m kddrl_trl.report <runs> verdict=true verdict_table=[docs/index.md]  # the table replaced there

a − b is the claim's first system minus its second; speeds in km/h, collision rates in percentage points; ``paper``:
the same difference in the paper's tables. "ours" is the confirmatory test's estimate on seeds 5-14 once every cell
has them; until then the verdicts read pending and "ours" is the estimate over all the seeds run so far (the pilot's
0-4 included), marked "so far". An inconclusive direction that the study's 10 seeds could not decide reads
"inconclusive (N)": N is the number of seeds per system that 80 % power on the paper's difference would need at the
family's level 0.05 / 17. The p-values, the intervals that agree with each verdict and the power are in the
report."""

from __future__ import annotations

from pathlib import Path

#: the README's words for the systems
NAMES = {
    "kddrl": "KDDRL",
    "ni": "Ni",
    "peng": "Peng",
    "d3qn_td3": "D3QN+TD3",
    "d3qn_td3_lg": "+LG",
    "kddrl_same_clock": "one clock",
    "idm_mobil": "IDM+MOBIL",
}
VERBS = {("mean_speed_kmh", "greater"): "faster than", ("mean_speed_kmh", "less"): "slower than"}
VERBS |= {("collision_rate", "less"): "collides less than"}


def _estimate(c: dict, value, ci) -> str:
    """The difference and its interval in the claim's unit (km/h or points, as the paper's column), unit unnamed: the
    claim's verb says which, and the rows stay within the README's 120 characters."""
    scale = 100.0 if c["metric"] == "collision_rate" else 1.0
    if value is None:
        return "—"
    return f"{scale * value:+.1f}" + ("" if ci is None else f" [{scale * ci[0]:+.1f}, {scale * ci[1]:+.1f}]")


def table(report: dict) -> str:
    primary = [c for c in report["claims"] if c.get("family") == "primary"]
    if len(primary) != 17:
        raise ValueError(f"report.json holds {len(primary)} primary claims, the plan has 17")
    lines = [
        "| # | claim | ours: a − b [95 % CI] | paper | direction (seeds needed) | size |",
        "|---|---|---|---|---|---|",
    ]
    for c in primary:
        scale = 100.0 if c["metric"] == "collision_rate" else 1.0
        claim = f"{c['scenario']}: {NAMES[c['a']]} {VERBS[(c['metric'], c['claimed'])]} {NAMES[c['b']]}"
        if c["direction"] == "pending":
            d = c["description"]
            ours = "—" if d is None else f"{_estimate(c, d['difference'], d['ci'])}, n={min(d['n'])} so far"
        else:
            ours = _estimate(c, c["difference"], c["ci"])
        direction = c["direction"] + (f" ({c['seeds_needed']:.0f})" if c.get("reading") else "")
        lines.append(f"| {c['id']} | {claim} | {ours} | {scale * c['paper']:+.1f} | {direction} | {c['size'] or '—'} |")
    return "\n".join(lines)


def write_table(report: dict, pages: list[Path]) -> None:
    """Replace the verdict table (its header line to the next blank line) in each page; a page without one is an
    error naming it."""
    new = table(report)
    head = new.split("\n", 1)[0]
    for page in pages:
        text = page.read_text()
        start = text.find(head)
        if start < 0:
            raise SystemExit(f"verdict_table={page}: it holds no verdict table (its header: {head})")
        end = text.find("\n\n", start)
        page.write_text(text[:start] + new + text[end:])
