"""The paper's verdict (reporting/verdict.py): paired intervals over seeds, Holm's correction, exact collision intervals,
and the report's ``verdict=true`` form (claims, commits as rows of their own)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from testkit import fake_run

from kddrl_trl.reporting.verdict import CLAIMS, Claim, clopper_pearson, holm, judge, t_interval


def test_t_interval_by_hand_and_degenerate_cases():
    low, high, p = t_interval([1.0, 2.0, 3.0])  # mean 2, sd 1, t(0.975, 2) = 4.303
    assert (low, high) == pytest.approx((2 - 4.3027 / np.sqrt(3), 2 + 4.3027 / np.sqrt(3)), abs=1e-3)
    assert p == pytest.approx(0.0742, abs=1e-3)  # t = 3.464 on 2 degrees of freedom
    assert t_interval([0.0, 0.0, 0.0]) == (0.0, 0.0, 1.0)
    assert t_interval([0.5, 0.5]) == (0.5, 0.5, 0.0)


def test_holm_steps_down_and_stays_monotone():
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm([0.5, 0.001]) == pytest.approx([0.5, 0.002])
    assert holm([0.9, 0.8, 0.7]) == pytest.approx([1.0, 1.0, 1.0])


def test_clopper_pearson_reads_zero_in_5000_as_an_interval():
    low, high = clopper_pearson(0, 5000)
    assert low == 0.0 and high == pytest.approx(0.000738, rel=1e-2)  # [0, 0.074 %]
    low, high = clopper_pearson(50, 1000)
    assert low < 0.05 < high
    with pytest.raises(ValueError, match="k=3, n=2"):
        clopper_pearson(3, 2)


def _rows(a_speeds, b_speeds, seeds_a=None, seeds_b=None):
    def row(algo, speeds, seeds):
        return {
            "algo": algo,
            "scenario": "baseline",
            "seeds": seeds or list(range(len(speeds))),
            "per_seed": {"mean_speed_kmh": list(speeds)},
        }

    return [row("kddrl", a_speeds, seeds_a), row("ni", b_speeds, seeds_b)]


CLAIM = Claim("kddrl drives faster than ni", "II", "baseline", "mean_speed_kmh", "kddrl", "ni", "greater")


def test_a_claim_holds_is_contradicted_or_stays_inconclusive():
    holds = judge([CLAIM], _rows([130, 131, 129, 132, 130], [120, 122, 119, 121, 120]))[0]
    assert holds["verdict"] == "holds" and holds["difference"] == pytest.approx(10.0) and holds["ci"][0] > 0
    against = judge([CLAIM], _rows([110, 111, 109, 112, 110], [120, 122, 119, 121, 120]))[0]
    assert against["verdict"] == "contradicted" and against["ci"][1] < 0
    noisy = judge([CLAIM], _rows([130, 110, 125, 112, 121], [120, 122, 119, 121, 120]))[0]
    assert noisy["verdict"] == "inconclusive" and noisy["p_holm"] >= 0.05
    few = judge([CLAIM], _rows([130, 131], [120, 122]))[0]
    assert few["verdict"] == "inconclusive" and few["p"] is None
    # paired on the seeds both ran: seed 9 of kddrl has no partner
    paired = judge([CLAIM], _rows([130, 131, 129, 500], [120, 121, 119], seeds_a=[0, 1, 2, 9]))[0]
    assert paired["seeds"] == [0, 1, 2] and paired["difference"] == pytest.approx(10.0)


def test_holm_is_applied_over_the_family():
    """A claim significant alone (p < 0.05) is not once 20 claims share the correction."""
    rows = _rows([130.0, 133.0, 129.0, 134.0, 131.0], [128.0, 129.0, 128.5, 129.0, 128.0])
    alone = judge([CLAIM], rows)[0]
    assert alone["p"] < 0.05 and alone["verdict"] == "holds"
    family = judge([CLAIM] * 20, rows)
    assert family[0]["p_holm"] == pytest.approx(min(1.0, 20 * alone["p"])) and family[0]["verdict"] == "inconclusive"


def test_the_claims_cover_the_issue_list():
    text = " ".join(c.claim for c in CLAIMS)
    for needle in (
        "(+LG)",
        "(+TG)",
        "(two clocks)",
        "(rules slowest)",
        "(rules safest)",
        "(unified slower)",
        "(unified changes lanes more)",
        "Table III",
        "Table IV",
    ):
        assert needle in text, needle
    assert all(c.direction in ("greater", "less") for c in CLAIMS)


def test_verdict_report_keeps_commits_apart_and_writes_claims(tmp_path):
    from kddrl_trl.reporting.builder import build_report
    from kddrl_trl.reporting.records import find_runs

    for seed in range(3):
        fake_run(
            tmp_path / "runs" / f"k{seed}",
            "kddrl",
            seed,
            speeds=(130.0 + seed, 131.0),
            collisions=(False, False),
            commit="aaaaaaa",
        )
        fake_run(
            tmp_path / "runs" / f"n{seed}",
            "ni",
            seed,
            speeds=(120.0 + seed, 121.0),
            collisions=(True, False),
            commit="aaaaaaa",
        )
        fake_run(
            tmp_path / "runs" / f"i{seed}",
            "idm_mobil",
            seed,
            speeds=(100.0, 100.0),
            collisions=(False, False),
            commit="aaaaaaa",
        )
    fake_run(tmp_path / "runs" / "k3", "kddrl", 3, speeds=(10.0, 10.0), collisions=(True, True), commit="bbbbbbb")
    build_report(find_runs([tmp_path / "runs"]), tmp_path / "rep", verdict=True)
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert set(report) == {"rows", "claims", "commits"} and report["commits"] == {"aaaaaaa": 9, "bbbbbbb": 1}
    rows = {r["algo"]: r for r in report["rows"]}
    assert rows["kddrl"]["seeds"] == [0, 1, 2] and rows["kddrl"]["commits"] == ["aaaaaaa"]
    assert rows["kddrl @bbbbbbb"]["seeds"] == [3]  # never pooled with the study's commit
    assert rows["ni"]["collisions_exact"]["collisions"] == 3 and rows["ni"]["collisions_exact"]["episodes"] == 6
    assert rows["kddrl"]["speed_vs_idm_mobil"]["ratio"] == pytest.approx(np.mean([1.305, 1.31, 1.315]))
    faster = next(c for c in report["claims"] if c["claim"] == "Table II: kddrl drives faster than ni")
    assert faster["seeds"] == [0, 1, 2] and faster["difference"] == pytest.approx(10.0)
    assert {"claim", "table", "verdict", "difference", "ci", "p_holm"} <= set(faster)
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## The paper's claims" in md and "| baseline | ni | 3 / 6 | 50.00% [" in md
