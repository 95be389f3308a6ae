"""A study's claims file (kddrl_trl.reporting.claims): the verdict study's reads as its plan fixed it, a second study
declares its own claims with no library change, and a malformed file is refused naming the file and the key."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from testkit import fake_run

from kddrl_trl.reporting.builder import build_report
from kddrl_trl.reporting.claims import load_claims
from kddrl_trl.reporting.records import find_runs

ROOT = Path(__file__).resolve().parents[2]

OWN = """title: The safety goals
plan: studies/x/plan.md
plan_commit: "0123456"
test_seeds: [0, 1, 2]
names: {kddrl: KDDRL, idm_mobil: IDM+MOBIL}
primary:
  - {id: G1, table: II, scenario: baseline, metric: mean_speed_kmh, a: kddrl, b: idm_mobil, claimed: greater}
  - {id: G2, table: II, scenario: baseline, metric: shield_rate, a: kddrl, b: idm_mobil, claimed: less}
"""


def test_the_verdict_studys_claims_file_reads_as_its_plan_fixed_it():
    plan = load_claims(ROOT / "studies" / "paper" / "claims.yaml")
    assert (plan.plan, plan.plan_commit, plan.title) == ("studies/paper/plan.md", "b80dd04", "The paper's claims")
    assert plan.pilot_seeds == (0, 1, 2, 3, 4) and plan.paper_runs == (1, 3)
    assert plan.primary[0].text == "Table II: kddrl drives faster than ni"
    assert plan.primary[9].paired and plan.primary[9].scenario == "braking"
    assert [c.id for c in plan.secondary] == [f"S{i}" for i in range(1, 38)]


def test_a_second_study_declares_its_own_claims_and_the_report_tests_them(tmp_path):
    (tmp_path / "claims.yaml").write_text(OWN)
    plan = load_claims(tmp_path / "claims.yaml")
    assert (
        plan.primary[1].text == "Table II: kddrl has a lower shield interventions (fraction of frames) than idm_mobil"
    )
    for seed in range(3):
        fake_run(tmp_path / "runs" / f"k{seed}", "kddrl", seed, speeds=(130.0 + seed, 131.0), commit="aaaaaaa")
        fake_run(tmp_path / "runs" / f"i{seed}", "idm_mobil", seed, speeds=(100.0, 101.0 + seed), commit="aaaaaaa")
    build_report(find_runs([tmp_path / "runs"]), tmp_path / "rep", claims=plan)
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    g1 = next(c for c in report["claims"] if c["id"] == "G1")
    assert report["plan_commit"] == "0123456" and g1["n"] == 3 and g1["direction"] == "holds"
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## The safety goals" in md and "confirmatory seeds 0-2 ran" in md
    assert "| G1 | baseline: KDDRL faster than IDM+MOBIL |" in md  # the summary, with the file's names
    assert "* **Analysis plan:** `studies/x/plan.md`, fixed at commit 0123456" in md


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (('plan_commit: "0123456"\n', ""), r"claims.yaml: key 'plan_commit' missing"),
        (("title:", "titel:"), r"claims.yaml: unknown key 'titel'"),
        (("test_seeds: [0, 1, 2]", "test_seeds: [0, 1, 1]"), r"claims.yaml: test_seeds repeats a value"),
        (("test_seeds: [0, 1, 2]", "test_seeds: 0-2"), r"claims.yaml: test_seeds must be a list of integers"),
        (("metric: shield_rate", "metric: speed"), r"claims.yaml: primary\[1\]: metric 'speed' is not a report metric"),
        (("claimed: less", "claimed: lower"), r"claims.yaml: primary\[1\]: claimed 'lower', not one of greater, less"),
        (("id: G2", "id: G1"), r"claims.yaml: claim id 'G1' given twice"),
        (("a: kddrl, b: idm_mobil, claimed: less", "b: idm_mobil, claimed: less"), r"primary\[1\]: key 'a' missing"),
    ],
)
def test_a_malformed_claims_file_is_refused_naming_the_file_and_the_key(tmp_path, change, message):
    (tmp_path / "claims.yaml").write_text(OWN.replace(*change))
    with pytest.raises(SystemExit, match=message):
        load_claims(tmp_path / "claims.yaml")


def test_a_missing_claims_file_is_named(tmp_path):
    with pytest.raises(SystemExit, match=r"claims=.*nowhere.yaml: no such file"):
        load_claims(tmp_path / "nowhere.yaml")
