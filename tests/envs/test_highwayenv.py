"""KDDRL on HighwayEnv (``kddrl_trl.envs.highwayenv``, the optional extra ``.[highway]``): specs, the keys' values
against HighwayEnv's own state, the KDDRL stack on it, episodes, and ``train env=highwayenv``. Skipped without
``highway_env``."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import check_env_specs

from kddrl_trl import keys as K

pytest.importorskip("highway_env")

from testkit import command  # noqa: E402

from kddrl_trl.envs.highwayenv import HighwayEnvAdapter  # noqa: E402
from kddrl_trl.eval import evaluate_policy  # noqa: E402
from kddrl_trl.highwayenv_options import HighwayEnvOptions  # noqa: E402

#: a small, fast road: few vehicles, few observed
SMALL = {"options": HighwayEnvOptions(vehicles_count=12, observed_vehicles=10)}


def test_adapter_has_the_sumo_specs_but_the_leader_history():
    from kddrl_trl.envs.specs import observation_spec

    env = HighwayEnvAdapter(num_roads=2, seed=0, **SMALL)
    try:
        check_env_specs(env)
        sumo = observation_spec(env.config, (2,))
        del sumo[K.LEADERS_HISTORY]
        assert env.observation_spec == sumo
        td = env.reset()
        assert K.LEADERS_HISTORY not in td.keys(True)
    finally:
        env.close()


def test_keys_are_highwayenv_state_in_si_units():
    """Ego position from its start, speed, lane (0 = rightmost) and the current leader's gap, speed and acceleration
    are HighwayEnv's own vehicle state, converted."""
    env = HighwayEnvAdapter(num_roads=1, seed=0, ego_lane=0, **SMALL)
    try:
        env.reset()
        for _ in range(15):
            td = env.step(command(env, K.KEEP, 1.0))["next"]
        hw = env.roads[0]
        ego = hw.vehicle
        state = td.get(K.EGO_STATE)[0]
        assert float(state[0]) == pytest.approx(ego.position[0] - env._x0[0], abs=1e-3)
        assert float(state[1]) == pytest.approx(ego.speed * np.cos(ego.heading), abs=1e-3)
        assert int(td.get(K.EGO_LANE)) == 0 and ego.lane_index[2] == 2  # rightmost: HighwayEnv's lane id 2 of 3
        assert float(td.get(K.EGO_ACCEL)) == pytest.approx(1.0, abs=1e-4)  # the command, executed
        assert bool(td.get(K.NEIGHBORS_MASK)[0, K.SLOT["b"]])  # seed 0 has a leader in the ego's lane
        leader = min(
            (v for v in hw.road.vehicles if v is not ego and v.lane_index[2] == 2 and v.position[0] > ego.position[0]),
            key=lambda v: v.position[0],
        )
        rel, kin = td.get(K.NEIGHBORS_REL)[0, K.SLOT["b"]], td.get(K.NEIGHBORS_KIN)[0, K.SLOT["b"]]
        assert float(rel[1]) == pytest.approx(leader.position[0] - ego.position[0], abs=1e-3)
        assert float(kin[1]) == pytest.approx(leader.speed * np.cos(leader.heading), abs=1e-3)
        assert float(kin[2]) == pytest.approx(leader.action["acceleration"], abs=1e-4)
        assert float(kin[2]) != 0.0
        mask = td.get(K.LC_ACTION_MASK)[0]
        assert mask.tolist() == [True, True, False]  # no lane to the right of the rightmost
    finally:
        env.close()


def test_a_lane_change_moves_left_masks_commands_and_ends():
    env = HighwayEnvAdapter(num_roads=1, seed=1, ego_lane=0, **SMALL)
    try:
        env.reset()
        td = env.step(command(env, K.LEFT))["next"]
        assert bool(td.get(K.LC_STARTED)) and bool(td.get(K.LC_ACTIVE))
        assert not bool(td.get(K.LC_ACTION_MASK)[0, K.LEFT])  # no new command while it is active
        assert float(td.get(K.EGO_STATE)[0, 2]) > 0  # lateral speed to the left
        lanes, frames = [], 1
        while bool(td.get(K.LC_ACTIVE)) and frames < 60:
            td = env.step(command(env, K.LEFT))["next"]  # ignored: masked
            assert not bool(td.get(K.LC_STARTED))
            lanes.append(int(td.get(K.EGO_LANE)))
            frames += 1
        assert lanes[-1] == 1 and frames < 60  # one lane to the left, then over
        assert float(td.get(K.LC_REWARD)) == pytest.approx(float(td.get(K.EGO_STATE)[0, 1] - 20.0) / 30.0, abs=1e-4)
    finally:
        env.close()


def test_kddrl_stack_passes_check_env_specs_and_rolls_out_episodes():
    from kddrl_trl.transforms import make_kddrl_transforms

    env = TransformedEnv(HighwayEnvAdapter(num_roads=2, seed=0, **SMALL), make_kddrl_transforms())
    try:
        check_env_specs(env)
        td = env.rollout(12, break_when_any_done=False)
        assert td["next", "pred", "key_gaps"].shape == (2, 12, 3, 2)
        assert td["next", "prior", "p_lcgan"].shape == (2, 12, 3)
        hist = td["next", "leaders", "history"]  # kept by LeaderHistory
        assert hist.shape == (2, 12, 3, 10, 2) and torch.isfinite(hist).all()
        present = td["next", "neighbors", "mask"][..., 1]
        assert torch.equal(hist[..., 1, -1, 0][present], td["next", "neighbors", "kin"][..., 1, 0][present])
    finally:
        env.close()


def test_episodes_end_as_on_sumo_and_are_evaluated():
    """Past the 420 m section (terminated), or a collision; the episode metrics of the SUMO env come out."""
    from kddrl_trl.baselines import IDMMobilPolicy

    env = HighwayEnvAdapter(num_roads=2, seed=0, section_length=120.0, **SMALL)  # short episodes: a fast test
    try:
        episodes = evaluate_policy(env, IDMMobilPolicy(num_lanes=3, lane_width=4.0), episodes=3, seed=5, progress=False)
    finally:
        env.close()
    assert len(episodes) == 3
    for ep in episodes:
        assert ep["outcome"] in ("left_section", "collision", "max_steps")
        assert 40 < ep["mean_speed_kmh"] < 180 and ep["frames"] > 10
    assert env.stats["episodes"] >= 3


def test_highwayenv_config_is_typed_and_checked_before_any_simulator_starts():
    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        good = compose(config_name="config", overrides=["env=highwayenv"])
        bad = compose(config_name="config", overrides=["env=highwayenv", "env.lane_width=3.2"])
        braking = compose(config_name="config", overrides=["env=highwayenv", "+scenario=braking"])
    job = OmegaConf.to_object(good)
    assert job.env.simulator == "highwayenv" and isinstance(job.env.highwayenv, HighwayEnvOptions)
    with pytest.raises(ValueError, match="lane_width"):
        OmegaConf.to_object(bad)
    with pytest.raises(ValueError, match="braking.enabled"):
        OmegaConf.to_object(braking)


@pytest.mark.slow
def test_kddrl_trains_on_highwayenv_as_typed(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "kddrl_trl.train",
        "env=highwayenv",
        "episodes=2",
        "eval_episodes=1",
        "env.num_roads=2",
        "env.max_steps=150",
        "env.highwayenv.vehicles_count=12",
        "env.highwayenv.observed_vehicles=10",
        "progress=false",
        "train.warmup_frames=50",
        "train.batch_size_cf=32",
        "train.batch_size_lc=8",
        "train.eval_every=0",
        "compile=false",
        "algo.learner.d3qn.hidden=[32,32]",
        "algo.learner.td3.hidden=[32,32]",
    ]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    (run,) = list((tmp_path / "runs").glob("highwayenv__kddrl__0__*"))
    summary = json.loads((run / "summary.json").read_text())
    assert summary["scenario"] == "highwayenv" and summary["episodes"] == 1
    assert summary["training"]["episodes"] == 2 and summary["training"]["cf_updates"] > 0


def test_same_seed_same_traffic_other_seed_other_traffic():
    def ego_and_leaders(seed):
        env = HighwayEnvAdapter(num_roads=2, seed=seed, **SMALL)
        try:
            td = env.rollout(8, lambda td: td.update(command(env, K.KEEP, 0.5)), break_when_any_done=False)
        finally:
            env.close()
        return td["next", "neighbors", "kin"]

    first = ego_and_leaders(0)
    assert torch.equal(first, ego_and_leaders(0))
    assert not torch.equal(first, ego_and_leaders(1))


def test_highwayenvs_own_driver_can_drive_the_ego():
    """``ego_driver=highwayenv``: the ego is HighwayEnv's IDM/MOBIL vehicle, whatever the policy commands (two
    opposite command sequences give the same episode), and its own lane changes are flagged as started."""
    from highway_env.vehicle.behavior import IDMVehicle

    from kddrl_trl.envs import make_config
    from kddrl_trl.highwayenv_options import check_config

    options = HighwayEnvOptions(vehicles_count=12, observed_vehicles=10, ego_driver="highwayenv")

    def episode(lc: int, accel: float):
        env = HighwayEnvAdapter(num_roads=1, seed=5, options=options)
        try:
            env.reset()
            assert isinstance(env.roads[0].vehicle, IDMVehicle)
            frames = []
            for _ in range(150):
                td = env.step(command(env, lc, accel))["next"]
                frames.append(td.select(K.EGO_STATE, K.EGO_LANE, K.LC_STARTED, "done"))
                if bool(td["done"]):
                    break
            return torch.stack(frames)
        finally:
            env.close()

    slow, fast = episode(K.LEFT, -5.0), episode(K.RIGHT, 5.0)
    assert torch.equal(slow[K.EGO_STATE], fast[K.EGO_STATE]) and len(slow) > 20
    lanes, started = slow[K.EGO_LANE].reshape(-1), slow[K.LC_STARTED].reshape(-1)
    assert int(started.sum()) >= int((lanes[1:] != lanes[:-1]).sum())
    with pytest.raises(ValueError, match="ego_driver"):
        check_config(make_config("baseline", {"lane_width": 4.0}), {"ego_driver": "carla"})


def test_highwayenvs_idm_with_its_lane_kept_drives_the_ego_in_one_lane():
    """``ego_driver=highwayenv_idm``: HighwayEnv's IDM vehicle drives the ego whatever the policy commands, and never
    changes lanes (MOBIL off), where the same driver with MOBIL on (``highwayenv``) does, from the same resets."""

    def episodes(driver: str, lc: int, accel: float) -> tuple[int, int, torch.Tensor]:
        """Lane changes started and lanes left over 4 episodes of 2 roads, and the ego speeds of every frame."""
        options = HighwayEnvOptions(vehicles_count=12, observed_vehicles=10, ego_driver=driver)
        started = moved = 0
        speeds = []
        for seed in (5, 6):
            env = HighwayEnvAdapter(num_roads=2, seed=seed, options=options)
            try:
                lane = env.reset()[K.EGO_LANE].reshape(-1).clone()
                assert all(r.vehicle.enable_lane_change == (driver == "highwayenv") for r in env.roads)
                for _ in range(200):
                    td = env.step(command(env, lc, accel))["next"]
                    started += int(td[K.LC_STARTED].sum())
                    moved += int((td[K.EGO_LANE].reshape(-1) != lane).sum())
                    speeds.append(td[K.EGO_STATE][..., 1].reshape(-1))
                    if bool(td["done"].any()):
                        break
            finally:
                env.close()
        return started, moved, torch.cat(speeds)

    started, moved, slow = episodes("highwayenv_idm", K.LEFT, -5.0)
    assert (started, moved) == (0, 0)
    assert torch.equal(slow, episodes("highwayenv_idm", K.RIGHT, 5.0)[2])  # the commands are ignored
    assert episodes("highwayenv", K.KEEP, 0.0)[0] > 0  # with MOBIL on, the same driver changes lanes


def test_the_highwayenv_throughput_benchmark_runs_at_its_smallest_size(tmp_path):
    """``benchmarks/highwayenv_throughput.py`` as a user runs it, one road and a few frames per arm: it ends without
    an error and writes a row with each arm's frames per second."""
    import os
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "highwayenv_throughput.json"
    cmd = [sys.executable, "-m", "benchmarks.highwayenv_throughput", "--roads", "1", "--frames", "10"]
    cmd += ["--repeats", "1", "--vehicles", "5", "--out", str(out)]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=900, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = json.loads(out.read_text())["rows"]
    arms = ("bare_fps", "adapter_fps", "stack_fps")
    assert len(rows) == 1 and rows[0]["num_roads"] == 1 and all(rows[0][arm] > 0 for arm in arms)
