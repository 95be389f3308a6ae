"""The reward variants (``env.reward``): Eq. 26-29, 32-33 as written, and ``safe``, which removes the reward trap."""

from __future__ import annotations

import pytest
import torch

from kddrl_trl.envs import FakeHighwayEnv, make_config
from kddrl_trl.envs.rewards import car_following_reward, efficiency_reward, lane_change_reward

GAMMA, DT = 0.99, 0.1  # per-frame discount of the TD3 agent, frame length (s)
V0, GAP0, LEADER_DECEL = 36.0, 100.0, 8.0


def discounted_return(cfg, decel: float, horizon: int = 1000) -> tuple[float, bool]:
    """Car-following return (Eq. 32, the env's own reward functions) of an ego at 36 m/s braking at a constant
    ``decel`` (m/s², 0 = driving on) behind a leader 100 m ahead that brakes at 8 m/s² to a stop and stays there;
    kinematics as the env's (v' = max(v + a dt, 0), executed a = (v' - v)/dt). Ends at a collision (bumper contact)
    or after ``horizon`` frames (the env's max_steps). Returns (return, collided)."""
    y, v, yl, vl, total = 0.0, V0, GAP0, V0, 0.0
    for t in range(horizon):
        v_new = max(v - decel * DT, 0.0)
        a, v = (v_new - v) / DT, v_new
        y += v * DT
        vl = max(vl - LEADER_DECEL * DT, 0.0)
        yl += vl * DT
        collided = yl - y - cfg.vehicle_length <= 0.0
        total += GAMMA**t * car_following_reward(v, a, float(collided), cfg)
        if collided:
            return total, True
    return total, False


def best_stop_and_best_crash(cfg) -> tuple[float, float]:
    """Best return over constant decelerations 0..5 m/s² (step 0.01) that stop in time, and over those that crash."""
    outcomes = [discounted_return(cfg, d / 100) for d in range(0, 501)]
    stops = [r for r, crashed in outcomes if not crashed]
    crashes = [r for r, crashed in outcomes if crashed]
    assert stops and crashes
    return max(stops), max(crashes)


def test_the_paper_reward_prefers_a_crash_to_stopping_behind_a_braking_leader():
    """The trap of Eq. 27 + 33: below 72 km/h -1 per frame, at -5 m/s² another -1; standing costs ~-1 per frame
    for the rest of the episode, so the best crash (-40) beats the best stop (-55) at γ = 0.99 per frame."""
    stop, crash = best_stop_and_best_crash(make_config())
    assert crash > stop + 10.0
    assert discounted_return(make_config(), 0.0)[1]  # driving on crashes within 5 s


def test_the_safe_reward_makes_the_best_stop_clearly_better_than_any_crash():
    stop, crash = best_stop_and_best_crash(make_config(overrides={"reward": "safe"}))
    assert stop > 0.0 and stop > crash + 30.0


def test_safe_differs_from_the_paper_only_below_v_min():
    paper, safe = make_config(), make_config(overrides={"reward": "safe"})
    v = torch.linspace(0.0, 60.0, 601)
    below = v < paper.v_min
    r_paper = car_following_reward(v, torch.full_like(v, -5.0), torch.zeros_like(v), paper)
    r_safe = car_following_reward(v, torch.full_like(v, -5.0), torch.zeros_like(v), safe)
    assert torch.equal(r_paper[~below], r_safe[~below])
    assert torch.allclose(r_safe[below], torch.full_like(v[below], -1.0))  # Eq. 33's -1 at -5 m/s² only
    assert torch.allclose(r_paper[below], torch.full_like(v[below], -2.0))
    assert efficiency_reward(60.0, paper) == -1.0 and lane_change_reward(60.0, True, False, safe) == -2.0
    assert car_following_reward(25.0, 0.0, 1.0, safe) == pytest.approx(5.0 / 30.0 - 100.0)


def test_both_envs_use_the_configured_variant():
    """The fake env computes its rewards with the same functions and config (the SUMO env:
    tests/envs/test_env_sumo.py)."""
    import torch.nn.functional as F

    from kddrl_trl import keys as K

    def stop(td):
        return td.update(
            {K.LC_ACTION: F.one_hot(torch.ones(2, dtype=torch.long), 3).float(), K.CF_ACTION: torch.full((2, 1), -5.0)}
        )

    rolls = {
        r: FakeHighwayEnv(num_roads=2, seed=0, reward=r).rollout(80, stop, break_when_any_done=False)
        for r in ("paper", "safe")
    }
    slow = rolls["paper"]["next", "ego", "state"][..., 1] < make_config().v_min
    slow &= ~rolls["paper"]["next", K.COLLISION][..., 0] & ~rolls["safe"]["next", K.COLLISION][..., 0]
    assert slow.any()
    assert (rolls["paper"]["next", *K.CF_REWARD][..., 0][slow] <= -1.0).all()
    assert (rolls["safe"]["next", *K.CF_REWARD][..., 0][slow] >= -1.0).all()
