"""FakeHighwayEnv: same specs as the SUMO env, deterministic, same command semantics."""

from __future__ import annotations

from functools import partial

import pytest
import torch
from testkit import command
from torchrl.envs import Compose, ParallelEnv, RewardSum, SerialEnv, StepCounter, TransformedEnv
from torchrl.envs.utils import check_env_specs, step_mdp

from kddrl_trl import keys as K
from kddrl_trl.baselines import IDMMobilPolicy
from kddrl_trl.envs import FakeHighwayEnv, SumoHighwayEnv


@pytest.mark.parametrize("num_roads", [1, 8])
def test_specs_pass_and_match_the_sumo_env(num_roads, no_sumo_open):
    fake = FakeHighwayEnv("baseline", num_roads=num_roads, seed=0)
    check_env_specs(fake, seed=None)
    check_env_specs(TransformedEnv(fake, Compose(StepCounter(), RewardSum(in_keys=fake.reward_keys))), seed=None)
    real = SumoHighwayEnv("baseline", num_roads=num_roads, seed=0)
    try:
        for name in ("observation_spec", "action_spec", "reward_spec", "done_spec"):
            assert getattr(fake, name) == getattr(real, name), name
    finally:
        real.close()


def test_serial_and_parallel():
    for cls in (SerialEnv, partial(ParallelEnv, mp_start_method="fork")):
        env = cls(2, partial(FakeHighwayEnv, "congested", num_roads=3, seed=0))
        try:
            check_env_specs(env, seed=None)
        finally:
            env.close()


def test_deterministic_given_seed():
    a = FakeHighwayEnv(num_roads=4, seed=3).rollout(300, IDMMobilPolicy(), break_when_any_done=False)
    b = FakeHighwayEnv(num_roads=4, seed=3).rollout(300, IDMMobilPolicy(), break_when_any_done=False)
    c = FakeHighwayEnv(num_roads=4, seed=4).rollout(300, IDMMobilPolicy(), break_when_any_done=False)
    assert (a == b).all()
    assert not (a[K.EGO_STATE] == c[K.EGO_STATE]).all()
    assert a["next", "done"].any()  # episodes end and restart


def test_command_semantics():
    env = FakeHighwayEnv(num_roads=1, seed=0, flow_vph=1.0, ego_lane=1)  # practically empty road
    td = env.reset()
    v = td[K.EGO_STATE][0, 1].item()
    full = env.step(td.update(command(env, K.LEFT, 7.0)))
    assert full["next", K.EGO_STATE][0, 1].item() == pytest.approx(v + 0.5)  # clipped to 5 m/s²
    assert full["next", "lc", "started"].item()
    obs, lanes, active = step_mdp(full), [], []
    for _ in range(21):
        obs = step_mdp(env.step(obs.update(command(env, K.LEFT, 0.0))))
        lanes.append(obs[K.EGO_LANE].item())
        active.append(obs[K.LC_ACTIVE].item())
    assert lanes[-1] == 2 and sum(active) == 18  # 19 active frames after the command, as in the SUMO env
    assert obs[K.LC_ACTION_MASK].tolist() == [[False, True, True]]


def test_collision_and_rewards():
    env = FakeHighwayEnv(num_roads=8, seed=0, flow_vph=6000.0)
    td, frames = env.reset(), []
    for _ in range(300):
        full, td = env.step_and_maybe_reset(td.update(command(env, K.KEEP, 5.0)))
        frames.append(full)
    td = torch.stack(frames, 1)
    hit = td["next", "collision"].squeeze(-1)
    assert hit.any()
    assert (td["next", "terminated"][hit]).all() and (td["next", "lc", "reward"][hit] <= -99).all()
    eff, lc, col, acc = (td["next", *key] for key in K.TERM_KEYS)  # the named terms sum to the rewards
    torch.testing.assert_close(td["next", *K.LC_REWARD], eff + lc + col, rtol=0, atol=1e-5)
    torch.testing.assert_close(td["next", *K.CF_REWARD], eff + acc + col, rtol=0, atol=1e-5)
    assert (col[hit] == -100).all() and (col[~hit] == 0).all()
