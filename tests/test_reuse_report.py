"""The HighwayEnv reuse measurement's results (studies/reuse/report.py): every arm recognised from its records, per-arm
intervals over seeds, exact pooled collision intervals and paired differences over the seeds both arms have."""

import json
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf
from testkit import fake_run

from studies.reuse import report


def _train_run(folder: Path, algo: str, seed: int, speed: float, collisions: int, options: dict | None = None) -> None:
    """A HighwayEnv run's records as the package's report reads them: evaluation episodes, summary, and a config
    holding the options that tell the arms apart."""
    fake_run(
        folder,
        algo,
        seed,
        speeds=(speed,) * 100,  # one row an episode, as its summary counts
        collisions=(True,) * collisions + (False,) * (100 - collisions),
        scenario="highwayenv",
        mean_speed_kmh=speed,
        collision_rate=collisions / 100,
        outcomes={"collision": collisions, "left_section": 100 - collisions},
        commit="abc1234",
    )
    config = OmegaConf.merge({"algo": {"name": algo}, "env": {"simulator": "highwayenv"}}, options or {})
    OmegaConf.save(config, folder / "config.yaml")


def _example(folder: Path, transforms: bool, seed: int, speed: float, collisions: int, reference=False, last=None):
    """The example's JSON; ``last`` = (speed, collisions) of the last policy, beside the kept one's (--validate-every)."""
    folder.mkdir(parents=True, exist_ok=True)
    name = "reference" if reference else "transforms" if transforms else "no-transforms"
    result = {
        "args": {"transforms": transforms, "seed": seed, "episodes": 300, "reference": reference},
        "mean_speed_kmh": speed,
        "collision_rate": collisions / 100,
        "episodes": 100,
        "commit": "abc1234",
    }
    if last is not None:
        result["last"] = {"mean_speed_kmh": last[0], "collision_rate": last[1] / 100, "episodes": 100}
    (folder / f"{name}__{seed}.json").write_text(json.dumps(result))


@pytest.fixture
def runs(tmp_path):
    for seed in range(3):
        base = tmp_path / "runs"
        _train_run(base / "highwayenv_gans" / f"highwayenv__kddrl__{seed}", "kddrl", seed, 100 + seed, seed)
        _train_run(
            base / "sumo_gans" / f"highwayenv__kddrl__{seed}",
            "kddrl",
            seed,
            90 + 2 * seed,
            2,
            {"algo": {"transforms": {"weights": "sumo"}}},
        )
        _train_run(base / "highwayenv_gans" / f"highwayenv__d3qn_td3__{seed}", "d3qn_td3", seed, 95.0, 5)
        _train_run(base / "highwayenv_gans" / f"highwayenv__idm_mobil__{seed}", "idm_mobil", seed, 80.0, 0)
        _train_run(
            base / "highwayenv_driver" / f"highwayenv__idm_mobil__{seed}",
            "idm_mobil",
            seed,
            81.0,
            0,
            {"env": {"highwayenv": {"ego_driver": "highwayenv"}}},
        )
        _example(base / "example", True, seed, 70.0 + seed, 10)
        if seed < 2:  # one seed missing: the paired difference uses the seeds both arms have
            _example(base / "example", False, seed, 60.0, 20)
        _example(base / "example_safe", True, seed, 72.0 + seed, 5)
        _example(base / "example_safe", False, seed, 71.0, 8)
        _example(base / "example_safe", True, seed, 75.0, 0, reference=True)  # --reference keeps its args
        if seed < 2:
            _example(base / "example_default_100k", True, seed, 74.0, 1)
            _example(base / "example_default_100k", False, seed, 73.0, 3)
            _example(base / "example_default_100k", True, seed, 76.0, 0, reference=True)
        if seed == 0:
            _example(base / "example_default", True, seed, 77.0, 2)
            _example(base / "example_default", True, seed, 76.0, 0, reference=True)
            _example(base / "example_best", True, seed, 74.0, 1, last=(80.0, 30))
            _example(base / "example_best", False, seed, 73.0, 4, last=(85.0, 40))
            _example(base / "example_best", False, seed, 76.0, 0, reference=True)
            _example(base / "example_scaled", False, seed, 75.0, 2, last=(78.0, 6))  # (v) and (x) not run yet
    _train_run(tmp_path / "runs" / "other" / "baseline__kddrl__0", "kddrl", 0, 130.0, 1)  # not HighwayEnv
    (tmp_path / "runs" / "other" / "baseline__kddrl__0" / "summary.json").write_text(
        json.dumps(
            {
                **json.loads((tmp_path / "runs/other/baseline__kddrl__0/summary.json").read_text()),
                "scenario": "baseline",
            }
        )
    )
    return tmp_path / "runs"


def test_every_arm_is_recognised_with_its_seeds(runs):
    results = report.read_results(runs)
    assert {arm: sorted(r) for arm, r in results.items()} == {
        "a": [0, 1, 2],
        "b": [0, 1],
        "c": [0, 1, 2],
        "d": [0, 1, 2],
        "e": [0, 1, 2],
        "f": [0, 1, 2],
        "g": [0, 1, 2],
        "h": [0, 1, 2],
        "i": [0, 1, 2],
        "j": [0, 1, 2],
        "k": [0, 1],
        "l": [0, 1],
        "m": [0, 1],
        "n": [0],
        "o": [],
        "p": [0],
        "q": [0],
        "r": [0],
        "s": [0],
        "t": [0],
        "u": [0],
        "v": [],
        "w": [0],
        "x": [],
        "y": [],
        "z": [0],
    }
    assert results["c"][1]["mean_speed_kmh"] == 92.0 and results["g"][2]["mean_speed_kmh"] == 81.0
    assert results["j"][1]["mean_speed_kmh"] == 75.0 and results["h"][2]["mean_speed_kmh"] == 74.0
    assert results["q"][0]["collisions"] == 1 and results["t"][0] == {
        **results["q"][0],
        "collisions": 30,
        "mean_speed_kmh": 80.0,
        "collision_rate": 0.3,
    }
    assert results["r"][0]["collisions"] == 4 and results["u"][0]["mean_speed_kmh"] == 85.0
    assert results["w"][0]["collisions"] == 2 and results["z"][0]["collisions"] == 6


def test_a_kept_policy_without_its_last_evaluation_is_refused(runs):
    path = runs / "example_best" / "transforms__0.json"
    path.write_text(json.dumps({k: v for k, v in json.loads(path.read_text()).items() if k != "last"}))
    with pytest.raises(ValueError, match='example_best/transforms__0.json: no "last" evaluation'):
        report.read_results(runs)


def test_a_reference_result_where_none_belongs_is_refused(runs):
    _example(runs / "example", True, 0, 75.0, 0, reference=True)
    with pytest.raises(ValueError, match="example/reference__0.json: a reference result"):
        report.read_results(runs)


def test_intervals_pooled_collisions_and_paired_differences(runs, tmp_path):
    out = report.main([str(runs), "--out", str(tmp_path / "out")])
    d = out["arms"]["d"]
    assert d["mean_speed_kmh"]["mean"] == pytest.approx(101.0)
    assert d["mean_speed_kmh"]["ci_low"] < 101.0 < d["mean_speed_kmh"]["ci_high"]
    pooled = out["arms"]["f"]["collision_rate"]["pooled"]
    assert pooled["collisions"] == 0 and pooled["episodes"] == 300
    assert pooled["clopper_pearson"][0] == 0.0 and 0.0 < pooled["clopper_pearson"][1] < 0.02
    pairs = {(p["arm"], p["reference"]): p for p in out["paired_differences"]}
    ab = pairs[("a", "b")]
    assert ab["seeds"] == [0, 1] and ab["mean_speed_kmh"]["mean"] == pytest.approx(np.mean([10.0, 11.0]))
    dc = pairs[("d", "c")]
    assert dc["mean_speed_kmh"]["mean"] == pytest.approx(np.mean([10.0, 9.0, 8.0]))
    assert dc["collision_rate"]["mean"] == pytest.approx(np.mean([-0.02, -0.01, 0.0]))
    assert dc["collision_rate"]["ci_low"] < 0.0  # a difference of rates may be negative
    cut = [a for a in out["arms"].values() if a["collision_rate"]["ci_low"] == 0.0]
    assert cut, "the fixture has an arm whose rate interval over seeds reaches below 0 %"
    for arm in out["arms"].values():  # an arm's rate interval stays within [0, 1]
        rate = arm["collision_rate"]
        assert rate["ci_low"] is None or 0.0 <= rate["ci_low"] <= rate["mean"] <= rate["ci_high"] <= 1.0
    hj = pairs[("h", "j")]
    assert hj["seeds"] == [0, 1, 2] and hj["collision_rate"]["mean"] == pytest.approx(0.05)
    assert pairs[("k", "m")]["seeds"] == [0, 1] and pairs[("k", "m")]["collision_rate"]["mean"] == 0.01
    assert pairs[("n", "p")]["seeds"] == [0] and pairs[("n", "o")]["seeds"] == []
    assert pairs[("r", "u")]["collision_rate"]["mean"] == pytest.approx(-0.36)
    assert pairs[("w", "r")]["collision_rate"]["mean"] == pytest.approx(-0.02) and pairs[("v", "w")]["seeds"] == []
    md = (tmp_path / "out" / "results.md").read_text()
    assert md.count("| (") == 22 + 19  # (o), (v), (x), (y) and their pairs not run yet
    assert json.loads((tmp_path / "out" / "results.json").read_text()) == json.loads(json.dumps(out))


def test_a_difference_of_collision_rates_is_cut_to_the_range_it_can_take():
    """Two seeds whose differences of rates disagree give a Student-t interval far beyond ±1; it is cut to [-1, 1],
    while a speed difference, which has no such range, keeps its whole interval."""
    results = {arm: {} for arm in report.ARMS}
    for seed, (rate_a, rate_b, speed_a) in enumerate([(0.9, 0.0, 90.0), (0.1, 0.95, 70.0)]):
        for arm, rate, speed in (("a", rate_a, speed_a), ("b", rate_b, 80.0)):
            results[arm][seed] = {
                "mean_speed_kmh": speed,
                "collision_rate": rate,
                "episodes": 100,
                "collisions": round(100 * rate),
                "commit": "abc1234",
            }
    ab = report.summarise(results)["paired_differences"][0]
    assert (ab["arm"], ab["reference"]) == ("a", "b")
    assert ab["collision_rate"]["mean"] == pytest.approx(0.025)
    assert (ab["collision_rate"]["ci_low"], ab["collision_rate"]["ci_high"]) == (-1.0, 1.0)
    assert ab["mean_speed_kmh"]["ci_low"] < -100.0 and ab["mean_speed_kmh"]["ci_high"] > 100.0


def test_an_arm_not_run_yet_has_no_row(runs, tmp_path):
    for folder in ("example_default_100k", "example_default"):
        for path in (runs / folder).glob("*.json"):
            path.unlink()
    out = report.main([str(runs), "--out", str(tmp_path / "out")])
    assert out["arms"]["k"]["seeds"] == [] and out["arms"]["k"]["mean_speed_kmh"]["mean"] is None
    md = (tmp_path / "out" / "results.md").read_text()
    assert "| (k)" not in md and "| (k) − (m)" not in md and md.count("| (") == 17 + 15
