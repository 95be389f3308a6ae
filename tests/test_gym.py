"""Gymnasium registration and API conformance."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env

import kddrl_trl  # noqa: F401  (registers the id)
from kddrl_trl import keys as K
from kddrl_trl.gym_env import ENV_ID, SumoHighwayGymEnv

pytestmark = pytest.mark.usefixtures("no_sumo_open")


# advisory warnings of the checkers on the Dict form: unbounded observation entries, an acceleration in m/s²
ADVISORY = ("infinity", "symmetric and normalized", "different from the unwrapped")


def _assert_only_advisory(caught):
    unexpected = [str(w.message) for w in caught if not any(a in str(w.message) for a in ADVISORY)]
    assert not unexpected, unexpected


def test_gymnasium_check_env_passes_on_the_registered_env():
    """``check_env`` as it is, render check included: that check opens a second env while the first is open, whose
    SUMO then runs in a worker process."""
    env = gym.make(ENV_ID, scenario="baseline", render_mode="rgb_array")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env)
        _assert_only_advisory(caught)
    finally:
        env.close()


def test_no_episode_label_is_observed_and_every_label_is_in_info():
    env = gym.make(ENV_ID, scenario="braking")
    try:

        def leaves(space, prefix=()):
            for name, sub in space.spaces.items():
                yield from leaves(sub, (*prefix, name)) if isinstance(sub, spaces.Dict) else [(*prefix, name)]

        observed = set(leaves(env.observation_space))
        assert observed == {k if isinstance(k, tuple) else (k,) for k in K.SENSED_KEYS}
        assert not observed & {k if isinstance(k, tuple) else (k,) for k in K.EPISODE_LABEL_KEYS}
        assert {"episode", "braking", "collision"}.isdisjoint(env.observation_space.spaces)
        obs, info = env.reset(seed=1)
        assert env.observation_space.contains(obs)
        _, _, _, _, info = env.step({"lc": 1, "cf": np.array([0.0], np.float32)})
        labels = info["labels"]
        assert set(labels) == {"collision", "episode", "braking"}
        assert set(labels["episode"]) == {"outcome", "collision_kind", "collision_slot"}
        assert labels["episode"]["outcome"].shape == (1,) and labels["braking"]["distance"].shape == (1,)
    finally:
        env.close()


def test_two_envs_in_one_process_give_the_frames_of_one():
    """The second env's SUMO runs in a worker process (libsumo allows one simulation per process); the same seed
    and actions give the same frames as an env in this process."""
    here = gym.make(ENV_ID, scenario="braking", flatten=True, process="here")
    other = gym.make(ENV_ID, scenario="braking", flatten=True)
    try:
        a, _ = here.reset(seed=7)
        b, _ = other.reset(seed=7)
        assert type(other.unwrapped.sim).__name__ == "RoadSimProcess"
        assert type(here.unwrapped.sim).__name__ == "RoadSim"
        rng = np.random.default_rng(0)
        for _ in range(150):
            action = rng.uniform(-1, 1, 2).astype(np.float32)
            sa, sb = here.step(action), other.step(action)
            np.testing.assert_array_equal(sa[0], sb[0])
            assert sa[1:4] == sb[1:4]
            np.testing.assert_array_equal(sa[4]["labels"]["episode"]["outcome"], sb[4]["labels"]["episode"]["outcome"])
            if sa[2] or sa[3]:
                a, _ = here.reset()
                b, _ = other.reset()
                np.testing.assert_array_equal(a, b)
    finally:
        other.close()
        here.close()
    assert not other.unwrapped.sim and not here.unwrapped.sim


def test_flat_form_passes_stable_baselines3s_checker():
    sb3_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    env = gym.make(ENV_ID, scenario="baseline", flatten=True)
    try:
        assert env.observation_space.dtype == np.float32 and env.observation_space.shape == (134,)
        assert len(env.unwrapped.feature_names) == 134 and env.unwrapped.feature_names[:4] == [
            "ego/state[0]",
            "ego/state[1]",
            "ego/state[2]",
            "ego/lane",
        ]
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            sb3_checker.check_env(env)
        assert not [str(w.message) for w in caught if "unwrapped" not in str(w.message)]
    finally:
        env.close()


@pytest.mark.parametrize(
    ("action", "lc", "cf"),
    [((0.0, 0.0), K.KEEP, 0.0), ((0.9, -1.0), K.LEFT, -5.0), ((-0.5, 1.0), K.RIGHT, 5.0), ((0.3, 0.5), K.KEEP, 2.5)],
)
def test_flat_action_mapping(action, lc, cf):
    env = SumoHighwayGymEnv(flatten=True)  # no simulation starts before reset()
    assert env.decode_action(np.asarray(action, np.float32)) == (lc, pytest.approx(cf))


@pytest.mark.parametrize("action", [np.array([np.nan, 0.0]), np.array([0.0]), np.array([0.0, np.inf])])
def test_a_bad_flat_action_is_refused_by_name(action):
    with pytest.raises(ValueError, match="flat action must be 2 finite numbers"):
        SumoHighwayGymEnv(flatten=True).decode_action(action)


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
