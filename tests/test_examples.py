"""The examples run as a user runs them: the transforms in a plain TorchRL TD3 loop, both arms, a few frames."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from torchrl.envs import ObservationNorm

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _example():
    """The example as a module: the repository's root is on the tests' path, as for the studies' scripts."""
    return importlib.import_module("examples.transforms_in_torchrl_td3")


@pytest.mark.parametrize("transforms", [True, False])
def test_transforms_in_a_torchrl_td3_loop(transforms, tmp_path):
    example = _example()
    env = example.make_env("sumo", 2, 0, transforms)
    try:
        width = env.observation_spec["observation"].shape[-1]
    finally:
        env.close()
    assert width == (3 + 24 + 6) + ((6 + 3 + 3) if transforms else 0)  # raw; + key gaps and both priors
    out = tmp_path / "result.json"
    args = ["--episodes", "2", "--warmup", "160", "--roads", "2", "--eval-episodes", "2", "--out", str(out)]
    args += ["--buffer", "200"]  # fills and cycles within the run: it keeps only the keys the loss reads
    result = example.main(args if transforms else [*args, "--no-transforms"])
    assert 0.0 < result["mean_speed_kmh"] < 250.0 and 0.0 <= result["collision_rate"] <= 1.0
    assert 2 <= result["episodes"] < 2 + 2 and result["train_episodes"] >= 2 and result["train_frames"] > 0
    assert json.loads(out.read_text()) == result and result["args"]["transforms"] == transforms


def test_a_buffer_smaller_than_the_warmup_is_refused(capsys):
    with pytest.raises(SystemExit):
        _example().main(["--buffer", "100", "--warmup", "160"])
    assert "--buffer 100 is below --warmup 160" in capsys.readouterr().err


def test_the_examples_observation_statistics_come_from_random_steps_and_scale_by_at_least_one():
    """``observation_statistics``: mean and standard deviation of random steps, each feature's scale at least 1 (a
    presence flag is only centred, never blown up); ``make_env(norm=...)`` standardises with them, and the whole
    training loop runs with ``--obs-norm``."""
    example = _example()
    env = example.make_env("sumo", 2, 0, False)
    try:
        loc, scale = example.observation_statistics(env, 200)
    finally:
        env.close()
    assert loc.shape == scale.shape == (3 + 24 + 6,) and bool((scale >= 1.0).all())
    assert float(scale.max()) > 5.0  # positions and speeds are scaled down: the raw ones span metres to 100s
    env = example.make_env("sumo", 2, 0, False, norm=(loc, scale))
    try:
        standardised, norm = env.reset()["observation"], env.transform[-1]
    finally:
        env.close()
    assert isinstance(norm, ObservationNorm) and torch.equal(norm.loc, loc) and torch.equal(norm.scale, scale)
    assert norm.loc is not loc  # a copy: training's statistics stay as they were measured
    assert bool(torch.isfinite(standardised).all()) and float(standardised.abs().max()) < 50.0
    args = ["--episodes", "2", "--warmup", "160", "--roads", "2", "--eval-episodes", "2", "--norm-frames", "100"]
    result = example.main([*args, "--no-transforms", "--obs-norm", "--no-obs-scale"])
    assert result["args"]["obs_norm"] and result["episodes"] >= 2


def test_the_examples_reference_is_highwayenvs_idm_in_its_lane(tmp_path):
    """``--reference``: no training; HighwayEnv's IDM drives the ego with its lane kept, on the evaluation traffic.
    It needs ``--env highwayenv``."""
    example = _example()
    with pytest.raises(SystemExit):
        example.main(["--reference"])
    pytest.importorskip("highway_env")
    out = tmp_path / "reference.json"
    result = example.main(
        ["--env", "highwayenv", "--reference", "--roads", "2", "--eval-episodes", "2", "--out", str(out)]
    )
    assert result["episodes"] >= 2 and 0.0 < result["mean_speed_kmh"] < 250.0 and "train_frames" not in result
    assert json.loads(out.read_text())["args"]["reference"] is True


def test_the_example_runs_on_highwayenv(tmp_path):
    """``--env highwayenv`` (the optional extra ``.[highway]``): the same loop on HighwayEnv, with the transforms
    and the GANs trained on HighwayEnv's traffic."""
    pytest.importorskip("highway_env")
    out = tmp_path / "result.json"
    result = _example().main(
        [
            "--env",
            "highwayenv",
            "--episodes",
            "2",
            "--warmup",
            "160",
            "--roads",
            "2",
            "--eval-episodes",
            "2",
            "--out",
            str(out),
        ]
    )
    assert 0.0 < result["mean_speed_kmh"] < 250.0 and result["episodes"] >= 2
    assert json.loads(out.read_text())["args"]["env"] == "highwayenv"


def test_sb3_ppo_example_learns_and_evaluates(tmp_path):
    """``examples/sb3_ppo.py`` (the optional extra ``.[sb3]``): PPO on the flat form, two envs in one DummyVecEnv."""
    pytest.importorskip("stable_baselines3")
    example = importlib.import_module("examples.sb3_ppo")
    out, saved = tmp_path / "ppo.json", tmp_path / "ppo.zip"
    args = ["--steps", "128", "--n-steps", "64", "--eval-episodes", "2", "--out", str(out), "--save", str(saved)]
    result = example.main(args)
    assert result["episodes"] == 2 and 0.0 < result["mean_speed_kmh"] < 250.0 and 0.0 <= result["collision_rate"] <= 1
    assert json.loads(out.read_text()) == result and result["args"]["envs"] == 2
    assert saved.is_file()  # SB3's own save; the result above is the model loaded back from it
    again = example.main(["--load", str(saved), "--steps", "0", "--eval-episodes", "2"])
    assert {k: again[k] for k in ("mean_speed_kmh", "collision_rate")} == {
        k: result[k] for k in ("mean_speed_kmh", "collision_rate")
    }  # the same greedy policy on the same evaluation traffic


@pytest.mark.parametrize("transforms", [True, False])
def test_the_examples_fixed_scales_divide_each_feature_in_concatenation_order(transforms):
    """``make_env(scale=True)``: the observation is the raw features (in the order CatTensors concatenates them,
    its sorted in_keys) divided by the fixed scales of ``SCALES`` and clipped to ±5; a wrong order would divide a
    position by a flag's 1 and a flag by 100 m."""
    example = _example()
    env = example.make_env("sumo", 2, 0, transforms, scale=True)
    try:
        td = env.rollout(30, break_when_any_done=False)["next"]
    finally:
        env.close()
    keys = sorted(example.RAW + (example.PREDICTIVE if transforms else []))
    units = [torch.tensor(example.SCALES[k]).repeat(td[k].shape[-1] // len(example.SCALES[k])) for k in keys]
    expected = torch.cat([td[k] / u for k, u in zip(keys, units)], -1).clamp(-5.0, 5.0)
    assert torch.allclose(td["observation"], expected, atol=1e-5)
    assert float(td[("ego", "state")][..., 0].abs().max()) > 20.0  # the raw position is far from unit scale
    assert float(td["observation"].abs().max()) <= 5.0


def test_the_example_keeps_its_best_validated_policy_and_reports_the_last_beside_it(tmp_path, capsys):
    """``--validate-every``: greedy validations on traffic of their own; the kept policy is the one of the highest
    mean return, evaluated as the result, the last one's evaluation beside it. ``--obs-scale`` and ``--obs-norm``
    are exclusive."""
    example = _example()
    with pytest.raises(SystemExit):
        example.main(["--obs-norm"])  # the fixed scales are the default
    assert "add --no-obs-scale" in capsys.readouterr().err
    args = ["--episodes", "4", "--warmup", "160", "--roads", "2", "--eval-episodes", "2", "--no-transforms"]
    result = example.main([*args, "--validate-every", "2", "--validate-episodes", "2"])
    validations = result["validations"]
    assert len(validations) >= 2 and [v["episode"] for v in validations] == sorted(v["episode"] for v in validations)
    best = max(validations, key=lambda v: v["mean_return"])
    assert result["kept_episode"] == best["episode"] and result["last"]["episodes"] >= 2
    assert {"mean_speed_kmh", "collision_rate", "mean_return"} <= set(result["last"]) and result["args"]["obs_scale"]
    assert all(0.0 <= v["accel_at_bound"] <= 1.0 for v in [*validations, result["last"]])
    if best["episode"] == result["train_episodes"]:  # the last policy is the kept one: one evaluation serves
        assert result["last"]["collision_rate"] == result["collision_rate"]


def test_the_examples_evaluation_counts_commands_at_the_bound():
    """``accel_at_bound``: the share of frames whose command lies at ±5 m/s² (a saturated actor), 1 for a policy
    that always floors it, 0 for one that always coasts."""
    from tensordict.nn import TensorDictModule, TensorDictSequential

    example = _example()
    for value, share in ((5.0, 1.0), (0.0, 0.0)):
        const = TensorDictModule(
            lambda o, v=value: torch.full((*o.shape[:-1], 1), v), ["observation"], [example.ACTION]
        )
        policy = TensorDictSequential(example.keep_lane(), const)
        result = example.evaluate(policy, "sumo", 2, 0, False, 2)
        assert result["accel_at_bound"] == share and result["episodes"] >= 2


@pytest.mark.parametrize("script", ["transforms_in_torchrl_td3.py", "sb3_ppo.py"])
def test_the_examples_help_shows_their_defaults(script):
    done = subprocess.run([sys.executable, str(EXAMPLES / script), "--help"], capture_output=True, text=True)
    if done.returncode != 0 and "No module named 'stable_baselines3'" in done.stderr:
        pytest.skip("the optional extra .[sb3] is not installed")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "(default: " in done.stdout
