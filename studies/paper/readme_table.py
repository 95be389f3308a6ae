"""The README's short verdict table: eleven of the study's claims, read from ``studies/paper/report.json``.
    python studies/paper/readme_table.py [report.json]  ->  the Markdown table on standard output
A − b is the claim's first system minus its second (``report.json``'s ``difference``), over the paired seeds; speeds in
km/h, collision rates in percentage points; ``paper``: the same difference in the paper's tables. A claim with fewer
than 5 paired seeds is refused: the table stands for the finished study."""

from __future__ import annotations

import json
import sys
from pathlib import Path

#: (paper table, the claim as the README words it, the claim's name in report.json)
ROWS = (
    ("II, baseline", "KDDRL drives faster than Ni", "Table II: kddrl drives faster than ni"),
    ("II, baseline", "KDDRL drives faster than Peng et al.", "Table II: kddrl drives faster than peng"),
    (
        "II, baseline",
        "unified D3QN drives slower than KDDRL",
        "Table II (unified slower): d3qn_unified drives slower than kddrl",
    ),
    (
        "II, baseline",
        "unified PASAC drives slower than KDDRL",
        "Table II (unified slower): pasac_unified drives slower than kddrl",
    ),
    ("III, congested", "KDDRL drives faster than Ni", "Table III: kddrl drives faster than ni"),
    ("IV, braking", "KDDRL drives faster than Ni", "Table IV: kddrl drives faster than ni"),
    ("IV, braking", "KDDRL collides less than Ni", "Table IV: kddrl collides less than ni"),
    ("V, baseline", "+LG collides less than D3QN+TD3", "Table V (+LG): d3qn_td3_lg collides less than d3qn_td3"),
    ("V, baseline", "+TG (KDDRL) collides less than +LG", "Table V (+TG): kddrl collides less than d3qn_td3_lg"),
    (
        "V, baseline",
        "two clocks drive faster than one",
        "Table V (two clocks): kddrl drives faster than kddrl_same_clock",
    ),
    (
        "V, baseline",
        "IDM+MOBIL drives slower than KDDRL",
        "Table V (rules slowest): idm_mobil drives slower than kddrl",
    ),
)


def table(report: dict) -> str:
    claims = {c["claim"]: c for c in report["claims"]}
    lines = [
        "| table | the paper's claim | ours: a − b [95 % CI] | paper | p (Holm) | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for where, label, name in ROWS:
        if name not in claims:
            raise KeyError(f"report.json has no claim {name!r}")
        c = claims[name]
        if len(c["seeds"]) < 5:
            raise ValueError(f"{name!r}: {len(c['seeds'])} paired seeds, the table needs 5")
        points = c["metric"] == "collision_rate"
        scale, unit = (100.0, "pts") if points else (1.0, "km/h")
        lo, hi = (scale * v for v in c["ci"])
        paper = "-" if c["paper"] is None else f"{scale * c['paper']:+.1f}"
        p = "1" if c["p_holm"] >= 1 else f"{c['p_holm']:.2g}"
        lines.append(
            f"| {where} | {label} | {scale * c['difference']:+.1f} {unit} [{lo:+.1f}, {hi:+.1f}] | {paper} | {p} "
            f"| {c['verdict']} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("report.json")
    print(table(json.loads(path.read_text())))
