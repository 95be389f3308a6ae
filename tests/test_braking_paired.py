"""The braking study's paired comparison (studies/braking/paired.py): runs paired by scenario, algo and seed across
folders, the paired t interval of the differences, and a refusal where an arm's run has no control."""

import json
from pathlib import Path

import pytest
from scipy.stats import ttest_rel

from studies.braking import paired


def _run(sweep: Path, algo: str, seed: int, collisions: float, speed: float) -> None:
    folder = sweep / f"braking__{algo}__{seed}"
    folder.mkdir(parents=True)
    summary = {"scenario": "braking", "algo": algo, "seed": seed, "collision_rate": collisions, "mean_speed_kmh": speed}
    (folder / "summary.json").write_text(json.dumps(summary))


def test_pairs_by_seed_across_control_folders(tmp_path, capsys):
    arm = {0: 0.06, 1: 0.05, 2: 0.07}
    control = {0: 0.14, 1: 0.10, 2: 0.16}
    for seed in arm:  # the arm's seeds in one folder, its controls' seeds split over two, with one extra seed
        _run(tmp_path / "arm", "kddrl", seed, arm[seed], 100.0 + seed)
        _run(tmp_path / ("c1" if seed < 2 else "c2"), "kddrl", seed, control[seed], 110.0)
    _run(tmp_path / "c2", "kddrl", 3, 0.9, 110.0)  # a control the arm lacks: left out
    out = paired.main(
        [str(tmp_path / "arm"), str(tmp_path / "c1"), str(tmp_path / "c2"), "--out", str(tmp_path / "p.json")]
    )
    row = out["braking/kddrl"]
    assert row["seeds"] == [0, 1, 2]
    diff = row["collision_rate"]["difference"]
    x, y = [100 * arm[s] for s in arm], [100 * control[s] for s in arm]
    ci = ttest_rel(x, y).confidence_interval(0.95)
    assert diff["mean"] == pytest.approx(-7.333333, abs=1e-5)
    assert (diff["ci_low"], diff["ci_high"]) == pytest.approx((ci.low, ci.high))
    assert row["mean_speed_kmh"]["difference"]["mean"] == pytest.approx(-9.0)
    assert json.loads((tmp_path / "p.json").read_text())["braking/kddrl"]["seeds"] == [0, 1, 2]
    assert "| braking/kddrl | 0,1,2 | test collisions (points) |" in capsys.readouterr().out


def test_refuses_an_arm_run_without_its_control(tmp_path):
    _run(tmp_path / "arm", "ni", 0, 0.1, 100.0)
    _run(tmp_path / "arm", "ni", 1, 0.1, 100.0)
    _run(tmp_path / "control", "ni", 0, 0.2, 100.0)
    with pytest.raises(SystemExit, match=r"without their control.*'ni', 1"):
        paired.main([str(tmp_path / "arm"), str(tmp_path / "control")])


def test_refuses_one_run_in_two_control_folders(tmp_path):
    _run(tmp_path / "arm", "ni", 0, 0.1, 100.0)
    _run(tmp_path / "c1", "ni", 0, 0.2, 100.0)
    _run(tmp_path / "c2", "ni", 0, 0.3, 100.0)
    with pytest.raises(SystemExit, match="twice"):
        paired.main([str(tmp_path / "arm"), str(tmp_path / "c1"), str(tmp_path / "c2")])


def test_a_rates_interval_stays_within_0_and_100_points(tmp_path):
    for seed, rate in enumerate((0.0, 0.0, 0.06)):
        _run(tmp_path / "arm", "peng", seed, rate, 100.0)
        _run(tmp_path / "control", "peng", seed, 0.1, 100.0)
    arm = paired.main([str(tmp_path / "arm"), str(tmp_path / "control")])["braking/peng"]["collision_rate"]["arm"]
    assert arm["mean"] == pytest.approx(2.0) and arm["ci_low"] == 0.0 and arm["ci_high"] > 2.0


def test_validation_reads_each_runs_last_validations(tmp_path, capsys):
    for sweep, rates in (("arm", (0.30, 0.04, 0.06)), ("control", (0.30, 0.14, 0.16))):
        for seed in (0, 1):
            _run(tmp_path / sweep, "kddrl", seed, 0.99, 100.0)  # the test rates: not read with --validation
            rows = "".join(f"{rate + 0.01 * seed},{100.0 + i}\n" for i, rate in enumerate(rates))
            (tmp_path / sweep / f"braking__kddrl__{seed}" / "validation.csv").write_text(
                "collision_rate,mean_speed_kmh\n" + rows
            )
    out = paired.main([str(tmp_path / "arm"), str(tmp_path / "control"), "--validation", "2"])
    assert out["braking/kddrl"]["collision_rate"]["difference"]["mean"] == pytest.approx(-10.0)
    assert "| validation collisions (points) |" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="holds 3 validations, --validation asks for 4"):
        paired.main([str(tmp_path / "arm"), str(tmp_path / "control"), "--validation", "4"])
