"""Gymnasium registration and API conformance."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import kddrl_trl  # noqa: F401  (registers the id)
from kddrl_trl.gym_env import ENV_ID

pytestmark = pytest.mark.usefixtures("no_sumo_open")


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_env_checker_passes():
    env = gym.make(ENV_ID, scenario="baseline")
    try:
        check_env(env.unwrapped, skip_render_check=True)
    finally:
        env.close()


def test_episode_runs_to_the_end_with_metrics():
    env = gym.make(ENV_ID, scenario="braking", reward="cf")
    try:
        obs, info = env.reset(seed=3)
        assert env.observation_space.contains(obs)
        for _ in range(1000):
            obs, reward, terminated, truncated, info = env.step({"lc": 1, "cf": np.array([0.0], np.float32)})
            assert reward == info["reward_cf"]
            if terminated or truncated:
                break
        assert terminated or truncated
        assert info["episode"]["frames"] > 0 and 100 <= info["episode"]["braking_distance"] <= 300
    finally:
        env.close()
