"""The verdict of the analysis plan (kddrl_trl.reporting.verdict) and the statistics behind every interval of the
reports (kddrl_trl.reporting.stats): known inputs give each reading, and the library calls give the textbook
numbers."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as sps
from testkit import fake_run

from kddrl_trl.reporting.claims import Claim, load_claims
from kddrl_trl.reporting.stats import (
    clopper_pearson,
    difference_test,
    holm,
    mean_ci,
    mean_test,
    noisy_reference_test,
    permutation_p,
    ratio_ci,
    seeds_for_power,
    t_power,
)
from kddrl_trl.reporting.verdict import judge as judge_on
from kddrl_trl.reporting.verdict import paper_difference

ROOT = Path(__file__).resolve().parents[2]
PAPER = load_claims(ROOT / "studies" / "paper" / "claims.yaml")
SEEDS = list(PAPER.test_seeds)


def judge(claims, rows):
    """The verdict on the paper study's confirmatory seeds."""
    return judge_on(claims, rows, PAPER.test_seeds, PAPER.paper_runs)


def test_mean_interval_by_hand_and_degenerate_cases():
    t = mean_test([1.0, 2.0, 3.0])  # mean 2, sd 1, t(0.975, 2) = 4.303
    assert (t["ci_low"], t["ci_high"]) == pytest.approx((2 - 4.303 / np.sqrt(3), 2 + 4.303 / np.sqrt(3)), abs=1e-3)
    assert t["p"] == pytest.approx(2 * sps.t.sf(2 / (1 / np.sqrt(3)), 2))
    assert mean_test([0.5, 0.5]) == {"mean": 0.5, "ci_low": 0.5, "ci_high": 0.5, "p": 1.0, "n": 2}  # no spread: p 1
    assert mean_ci([2.0]) == {"mean": 2.0, "ci_low": None, "ci_high": None, "n": 1}
    with pytest.raises(ValueError, match="finite"):
        mean_ci([1.0, float("nan")])


def test_welch_and_paired_differences_and_a_null_other_than_zero():
    x, y = [10.0, 12.0, 11.0, 13.0], [5.0, 9.0, 4.0, 8.0, 6.0]
    w = difference_test(x, y)
    ref = sps.ttest_ind(x, y, equal_var=False)
    assert w["test"] == "welch" and w["p"] == pytest.approx(ref.pvalue)
    assert (w["ci_low"], w["ci_high"]) == pytest.approx(tuple(ref.confidence_interval()))
    shifted = difference_test(x, y, null=w["mean"])  # H0 at our own estimate: nothing to reject
    assert shifted["p"] == pytest.approx(1.0) and shifted["ci_low"] == pytest.approx(w["ci_low"])
    p = difference_test([1.0, 2.0, 3.0, 4.0], [0.9, 2.1, 2.8, 3.9], paired=True)
    assert p["test"] == "paired" and p["p"] == pytest.approx(sps.ttest_rel([1, 2, 3, 4], [0.9, 2.1, 2.8, 3.9]).pvalue)
    with pytest.raises(ValueError, match="same seeds"):
        difference_test([1.0, 2.0], [1.0], paired=True)


def test_a_side_without_spread_against_a_nonzero_null_is_welch_on_the_other_side_without_a_warning():
    # the rule baseline's collision rate is 0 at every seed; the size test shifts it by the paper's difference
    zero, y = [0.0] * 10, [0.012, 0.009, 0.028, 0.012, 0.016, 0.017, 0.003, 0.011, 0.015, 0.002]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = difference_test(zero, y, null=-0.034)
    assert d["p"] == pytest.approx(sps.ttest_1samp(y, 0.034).pvalue, rel=1e-9)


def test_ratio_interval_stays_positive_and_holds_the_ratio():
    r = ratio_ci([110.0, 112.0, 108.0], [100.0, 101.0, 99.0])
    assert r["mean"] == pytest.approx(1.1) and 1.0 < r["ci_low"] < 1.1 < r["ci_high"]
    wide = ratio_ci([1.0, 50.0, 3.0], [10.0, 11.0, 9.0])
    assert wide["ci_low"] > 0
    with pytest.raises(ValueError, match="> 0"):
        ratio_ci([1.0], [0.0])


def test_holm_binomial_and_power_come_from_the_libraries():
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm([]) == []
    low, high = clopper_pearson(0, 5000)
    assert low == 0.0 and high == pytest.approx(0.000737, abs=1e-5)
    # 80 % power for an effect of one SD at 0.05, two-sided, two samples: 17 per group (textbook)
    assert seeds_for_power(1.0, 1.0, 0.05, paired=False) == 17
    assert seeds_for_power(0.0, 1.0, 0.05, paired=False) == float("inf")


def _rows(a, b, metric="mean_speed_kmh", scenario="baseline", algo_a="kddrl", algo_b="ni"):
    """Two report rows holding per-seed values ``a`` and ``b`` on the given seeds ({seed: value})."""

    def row(algo, values):
        return {"algo": algo, "scenario": scenario, "seeds": list(values), "per_seed": {metric: list(values.values())}}

    return [row(algo_a, a), row(algo_b, b)]


P = Claim("P1", "II", "baseline", "mean_speed_kmh", "kddrl", "ni", "greater", "primary")  # the paper: +1.7 km/h
RNG = np.random.default_rng(0)
NOISE = RNG.normal(0.0, 1.0, size=len(SEEDS))


def _judge(a_mean: float, b_mean: float, sd: float = 1.0, claims=(P,)):
    a = {s: a_mean + sd * e for s, e in zip(SEEDS, NOISE, strict=True)}
    b = {s: b_mean + sd * e for s, e in zip(SEEDS, NOISE[::-1], strict=True)}
    return judge(list(claims), _rows(a, b))


def test_direction_holds_is_contradicted_or_stays_inconclusive():
    assert _judge(140, 120)[0]["direction"] == "holds"
    assert _judge(120, 140)[0]["direction"] == "contradicted"
    noisy = _judge(121, 120, sd=10)[0]
    assert noisy["direction"] == "inconclusive" and noisy["p_direction_adjusted"] >= 0.05


def test_size_excluded_smaller_larger_or_compatible():
    assert _judge(120.0, 120.0)[0]["size"] == "excluded, smaller"  # ours 0 against the paper's +1.7, tight
    assert _judge(140.0, 120.0)[0]["size"] == "excluded, larger"  # +20 against +1.7
    compatible = _judge(121.7, 120.0, sd=3)[0]
    assert compatible["size"] == "compatible" and compatible["ci"][0] < paper_difference(P) < compatible["ci"][1]
    # a claim the other way round: further below zero than the paper's -12.8 is larger
    slower = Claim("P16", "V", "baseline", "mean_speed_kmh", "idm_mobil", "kddrl", "less", "primary")
    rules = dict.fromkeys(SEEDS, 100.0) | {5: 101.0}
    learner = {s: 140.0 + e for s, e in zip(SEEDS, NOISE, strict=True)}
    far = judge([slower], _rows(rules, learner, algo_a="idm_mobil", algo_b="kddrl"))[0]
    assert far["direction"] == "holds" and far["size"] == "excluded, larger"


def test_an_underpowered_direction_names_the_seeds_it_would_need():
    entry = _judge(120.2, 120.0, sd=4, claims=[P] * 17)[0]  # the paper's +1.7 km/h at an SD of 4, in a family of 17
    assert entry["direction"] == "inconclusive" and entry["seeds_needed"] > 50
    assert entry["reading"].startswith(f"underpowered: needs {entry['seeds_needed']:.0f} seeds per system")
    assert entry["reading"].endswith(f"at 0.05/17 ({entry['seeds_needed_alpha']:.0f} at 0.05)")
    assert entry["seeds_needed_alpha"] < entry["seeds_needed"]  # at 0.05 rather than 0.05 / 17
    assert 0 < entry["power"]["family"] < entry["power"]["alpha"] < 0.8 and entry["power"]["n"] == 10
    decided = _judge(140, 120)[0]
    assert decided["reading"] is None and decided["power"]["family"] > 0.99


def _simulated_power(d: float, n: int, alpha: float, paired: bool, draws: int = 40_000) -> float:
    """The share of simulated studies whose two-sided t-test rejects at ``alpha`` (normal values, SD 1)."""
    rng = np.random.default_rng(n)
    if paired:
        p = sps.ttest_1samp(rng.normal(d, 1.0, (draws, n)), 0.0, axis=1).pvalue
    else:
        p = sps.ttest_ind(rng.normal(d, 1.0, (draws, n)), rng.normal(0.0, 1.0, (draws, n)), axis=1).pvalue
    return float((p < alpha).mean())


@pytest.mark.parametrize(
    ("d", "alpha", "paired"),
    [(7.6, 0.05 / 17, True), (4.0, 0.05 / 17, True), (2.5, 0.05 / 17, False), (1.5, 0.05, True), (1.0, 0.05, False)],
)
def test_seeds_for_power_matches_simulation_at_small_n(d, alpha, paired):
    # at n of 3-6 statsmodels' noncentral t returns NaN, which the power code once read as power 1
    n = seeds_for_power(d, 1.0, alpha, paired)
    simulated = next(k for k in range(2, 60) if _simulated_power(d, k, alpha, paired) >= 0.8)
    assert abs(n - simulated) <= 1, (n, simulated)
    assert t_power(d, 1.0, int(n), alpha, paired) >= 0.8 > t_power(d, 1.0, int(n) - 1, alpha, paired)


def test_power_is_a_number_where_the_noncentral_t_gives_nan():
    from statsmodels.stats.power import TTestPower

    assert np.isnan(TTestPower().power(7.6, nobs=4, alpha=0.05 / 17))  # the library's NaN, far out
    assert t_power(7.6, 1.0, 4, 0.05 / 17, paired=True) == pytest.approx(
        _simulated_power(7.6, 4, 0.05 / 17, True), abs=0.01
    )
    assert t_power(1.0, 1.0, 10, 0.05, paired=False) == pytest.approx(0.5620, abs=1e-3)  # textbook: d = 1, n = 10


def test_permutation_check_exact_where_paired_and_resampled_otherwise():
    up = [1.0 + 0.1 * i for i in range(10)]
    assert permutation_p(up, [0.0] * 10, paired=True) == pytest.approx(2 / 1024)  # all signs up: 2 of 1024
    x, y = RNG.normal(1.0, 1.0, 10), RNG.normal(0.0, 1.0, 10)
    assert permutation_p(x, y, paired=False) == permutation_p(x, y, paired=False)  # seeded: a report regenerates
    assert permutation_p(x, y, paired=False) == pytest.approx(difference_test(x, y)["p"], abs=0.03)
    assert permutation_p([1.0, 1.0], [1.0, 1.0], paired=False) is None


def test_the_paper_difference_read_as_an_estimate_widens_the_size_test():
    x, y = RNG.normal(5.0, 3.0, 10), RNG.normal(0.0, 3.0, 10)
    exact = difference_test(x, y, null=15.0)["p"]
    one, three = (noisy_reference_test(x, y, 15.0, runs, paired=False) for runs in (1, 3))
    assert exact < three < one  # a noisier reference is harder to exclude
    assert noisy_reference_test(x, y, 15.0, 10**9, paired=False) == pytest.approx(exact, rel=1e-3)
    d = RNG.normal(1.0, 1.0, 10)
    assert noisy_reference_test(d, np.zeros(10), 4.0, 10**9, paired=True) == pytest.approx(
        difference_test(d, np.zeros(10), null=4.0, paired=True)["p"], rel=1e-6
    )


def test_the_interval_beside_each_verdict_agrees_with_it():
    # a family where Holm decides some claims only at later steps: there the Bonferroni interval holds the null
    claims, rows = [], []
    cells = [(sc, b) for sc in ("baseline", "congested", "braking") for b in ("ni", "peng")]
    for i, ((scenario, other), gap) in enumerate(zip(cells, (6.0, 2.0, 1.9, 1.6, 1.0, 0.2), strict=True)):
        claims.append(Claim(f"P{i + 1}", "II", scenario, "mean_speed_kmh", "kddrl", other, "greater", "primary"))
        a = {s: 120.0 + gap + e for s, e in zip(SEEDS, NOISE, strict=True)}
        b = {s: 120.0 + e for s, e in zip(SEEDS, NOISE[::-1], strict=True)}
        rows += _rows(a, b, scenario=scenario, algo_b=other)
    entries = judge(claims, rows)
    step_down = 0
    for e in entries:
        assert (e["ci_direction"][0] > 0 or e["ci_direction"][1] < 0) == (e["p_direction_adjusted"] < 0.05)
        assert (e["ci_size"][0] > e["paper"] or e["ci_size"][1] < e["paper"]) == (e["p_size_adjusted"] < 0.05)
        sim_excludes = e["ci_simultaneous"][0] > 0 or e["ci_simultaneous"][1] < 0
        step_down += e["p_direction_adjusted"] < 0.05 and not sim_excludes
    assert step_down >= 1  # the case the interval mends: decided by the step-down, not by Bonferroni


def test_the_test_reads_the_confirmatory_seeds_only_and_waits_for_all_of_them():
    a = {s: 140.0 + e for s, e in zip(SEEDS, NOISE)} | {0: 1000.0}  # a pilot seed far off: not in the test
    b = {s: 120.0 + e for s, e in zip(SEEDS, NOISE[::-1])} | {0: 120.0}
    entry = judge([P], _rows(a, b))[0]
    assert entry["seeds"] == SEEDS and entry["n"] == 10 and entry["difference"] == pytest.approx(20.0, abs=1.0)
    assert entry["description"]["n"] == [11, 11] and entry["description"]["difference"] > 90  # all seeds described
    del a[14]
    pending = judge([P], _rows(a, b))[0]
    assert pending["direction"] == "pending" and pending["size"] == "pending" and pending["p_direction"] is None
    assert pending["description"] is not None


def test_no_verdict_until_the_whole_primary_family_is_in():
    a = {s: 140.0 + e for s, e in zip(SEEDS, NOISE)}
    b = {s: 120.0 + e for s, e in zip(SEEDS, NOISE[::-1])}
    braking = Claim("P9", "IV", "braking", "mean_speed_kmh", "kddrl", "ni", "greater", "primary")
    ready, waiting = judge([P, braking], _rows(a, b) + _rows({5: 130.0}, {5: 120.0}, scenario="braking"))
    assert waiting["direction"] == "pending" and waiting["p_direction"] is None
    # P's cells are all in, and its test on them would hold alone, but Holm's family is the plan's whole family
    assert ready["direction"] == "pending" and ready["size"] == "pending" and ready["p_direction_adjusted"] is None
    assert ready["n"] == 10 and ready["p_direction"] < 0.05 and ready["difference"] == pytest.approx(20.0, abs=1.0)
    assert judge([P], _rows(a, b))[0]["direction"] == "holds"


def test_holm_is_applied_over_the_primary_family_only():
    one = _judge(121.2, 120.0)[0]
    assert one["p_direction"] < 0.05
    explored = Claim("S1", "II", "baseline", "mean_speed_kmh", "kddrl", "ni", "greater")
    many = _judge(121.2, 120.0, claims=[P] * 17 + [explored] * 3)
    assert many[0]["p_direction_adjusted"] == pytest.approx(min(1.0, 17 * one["p_direction"]))
    assert all(e["family"] == "secondary" and e["direction"] is None for e in many[17:])


def test_the_plan_family_has_17_distinct_claims_and_no_mirror_image():
    assert len(PAPER.primary) == 17 and [c.id for c in PAPER.primary] == [f"P{i}" for i in range(1, 18)]
    assert len(PAPER.secondary) == 37 and PAPER.plan_commit == "b80dd04" and SEEDS == list(range(5, 15))
    keys = [(c.scenario, c.metric, frozenset((c.a, c.b))) for c in PAPER.claims]
    assert len(keys) == len(set(keys)), "a claim and its mirror image (or a duplicate) are both in the family"
    assert {c.id for c in PAPER.primary if c.paired} == {"P10", "P12"}  # braking collisions, as the plan says
    assert paper_difference(PAPER.primary[9]) == pytest.approx(0.010 - 0.248)


def test_verdict_report_keeps_commits_apart_and_writes_both_readings(tmp_path):
    from kddrl_trl.reporting.builder import build_report
    from kddrl_trl.reporting.records import find_runs

    for seed in range(3):
        for algo, speed, hit in (("kddrl", 130.0, False), ("ni", 120.0, True), ("idm_mobil", 100.0, False)):
            fake_run(
                tmp_path / "runs" / f"{algo}{seed}",
                algo,
                seed,
                speeds=(speed + seed, speed + 1),
                collisions=(hit, False),
                commit="aaaaaaa",
            )
    fake_run(tmp_path / "runs" / "k3", "kddrl", 3, speeds=(10.0, 10.0), collisions=(True, True), commit="bbbbbbb")
    build_report(find_runs([tmp_path / "runs"]), tmp_path / "rep", claims=PAPER)
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert set(report) == {"rows", "claims", "commits", "plan_commit"}
    assert report["commits"] == {"aaaaaaa": 9, "bbbbbbb": 1}
    rows = {r["algo"]: r for r in report["rows"]}
    assert rows["kddrl"]["seeds"] == [0, 1, 2] and rows["kddrl @bbbbbbb"]["seeds"] == [3]  # never pooled
    assert rows["ni"]["collisions_exact"]["collisions"] == 3 and rows["ni"]["collisions_exact"]["episodes"] == 6
    p1 = next(c for c in report["claims"] if c["id"] == "P1")
    for claim in report["claims"]:  # one schema: a secondary claim's verdicts and adjusted p-values are null
        assert {"family", "direction", "size", "ci", "n", "p_direction_adjusted", "p_size_adjusted"} <= set(claim)
    secondary = [c for c in report["claims"] if c["family"] == "secondary"]
    assert secondary and all(c["direction"] is None and c["p_size_adjusted"] is None for c in secondary)
    assert p1["family"] == "primary" and p1["direction"] == "pending" and p1["n"] == 0  # no seed 5-14 here
    assert p1["description"]["difference"] == pytest.approx(10.0)
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## The paper's claims" in md and "### Secondary claims (exploratory)" in md
    assert "| baseline | ni | 3 / 6 | 50.00% [" in md
