"""``studies/safety/ship.py``: the plan's choice of the shipped seed on validation traffic only, and the refusal to
ship a run whose records are not the study's."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest
from testkit import fake_run

SCENARIOS = ("baseline", "congested", "braking")


def _ship():
    from studies.safety import ship

    return ship


def run(folder: Path, algo: str, scenario: str, seed: int, speed: float, collisions: int, test_speed: float = 100.0):
    """A run whose test episodes drive at ``test_speed`` and whose validations (episodes 500 and 1000, 50 episodes
    each) at ``speed``; the last has ``collisions`` collisions, the first ten (read by nothing)."""
    fake_run(folder, algo=algo, seed=seed, scenario=scenario, speeds=[test_speed] * 4, collisions=[False] * 4,
             commit="abc1234")  # fmt: skip
    pd.DataFrame(
        {
            "episodes_trained": [1000, 500],  # not in order: the last is the one with the most episodes
            "episodes": [50, 50],
            "mean_speed_kmh": [speed, 200.0],
            "collision_rate": [collisions / 50, 0.2],
        }
    ).to_csv(folder / "validation.csv", index=False)
    return folder


def study(tmp_path: Path, speeds: dict[int, tuple], collisions: dict[int, tuple] | None = None) -> Path:
    root = tmp_path / "safety"
    for seed, per_scenario in speeds.items():
        for sc, speed, hits in zip(SCENARIOS, per_scenario, (collisions or {}).get(seed, (0, 0, 0))):
            for algo in ("kddrl", "d3qn_td3"):
                run(root / "runs" / f"{sc}__{algo}__{seed}", algo, sc, seed, speed, hits)
    return root


def test_the_fastest_seed_without_a_validation_collision_pooled_over_the_scenarios(tmp_path):
    ship = _ship()
    # seed 101 is fastest but collides once in braking; 102 beats 100 on the pooled mean, not on baseline
    root = study(tmp_path, {100: (130, 120, 110), 101: (150, 150, 150), 102: (125, 125, 125)}, {101: (0, 0, 1)})
    run(root / "runs" / "baseline__kddrl__103", "kddrl", "baseline", 103, 190.0, 0)  # one scenario only: no candidate
    chosen = ship.choose(root, commit="abc1234")
    assert chosen["kddrl"]["seed"] == 102 and chosen["kddrl"]["by_plan"]
    assert chosen["kddrl"]["mean_speed_kmh"] == pytest.approx(125.0)
    assert [r[0] for r in chosen["kddrl"]["ranking"]] == [102, 100, 101]
    assert chosen["kddrl"]["validations"][0]["episodes_trained"] == 1000  # the last validation, not the first
    # every seed collides: the plan's rule chooses none; the fewest collisions, then the speed, flagged
    root = study(tmp_path / "b", {100: (130, 130, 130), 101: (120, 120, 120)}, {100: (2, 0, 0), 101: (1, 0, 0)})
    chosen = ship.choose(root, commit="abc1234")
    assert chosen["d3qn_td3"]["seed"] == 101 and not chosen["d3qn_td3"]["by_plan"]


def test_a_run_ships_only_if_its_records_are_the_studys(tmp_path, monkeypatch):
    ship = _ship()
    root = study(tmp_path, {100: (130, 120, 110), 101: (120, 120, 120)})
    chosen = ship.choose(root, commit="abc1234")
    sweep = tmp_path / "sweep"
    for algo, row in chosen.items():
        for sc in SCENARIOS:
            shutil.copytree(row["runs"][sc], sweep / f"{sc}__{algo}__{row['seed']}")
    calls = []
    monkeypatch.setattr(ship, "ship", lambda run, name, why, dest: calls.append((run.name, name, why)) or dest / name)
    shipped = ship.ship_chosen(chosen, [tmp_path / "elsewhere", sweep], dest=tmp_path / "policies")
    assert [p.name for p in shipped] == [f"{a}_safe_{sc}" for a in ("kddrl", "d3qn_td3") for sc in SCENARIOS]
    assert calls[0][0] == "baseline__kddrl__100" and "seed 100" in calls[0][2] and "validation traffic" in calls[0][2]
    # a rerun whose test records differ (another CPU kind's arithmetic) is refused, naming the record
    episodes = sweep / "braking__kddrl__100" / "eval_episodes.csv"
    episodes.write_text(episodes.read_text().replace("100.0", "100.5", 1))
    with pytest.raises(
        SystemExit,
        match=r"braking__kddrl__100: eval_episodes.csv differs from the landed .*--rerun ships it as a rerun",
    ):
        ship.ship_chosen(chosen, [tmp_path / "elsewhere", sweep], dest=tmp_path / "policies")
    calls.clear()  # --rerun: it ships, its card saying it is a rerun and from which record on it differs
    ship.ship_chosen(chosen, [sweep], dest=tmp_path / "policies", rerun=True)
    (why,) = [w for run, _, w in calls if run == "braking__kddrl__100"]
    assert "a rerun of that seed" in why and "from eval_episodes.csv on" in why
    assert not any("rerun" in w for run, _, w in calls if run != "braking__kddrl__100")
    shutil.rmtree(sweep / "braking__kddrl__100")
    with pytest.raises(
        SystemExit, match=r"braking__kddrl__100: not a finished run in .*elsewhere, .*sweep; rerun it with SEEDS=100"
    ):
        ship.ship_chosen(chosen, [tmp_path / "elsewhere", sweep], dest=tmp_path / "policies")
