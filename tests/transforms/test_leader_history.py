"""``LeaderHistory``: the leaders' window kept from the instantaneous raw keys, for envs without
``("leaders","history")`` — bare, in the KDDRL stack, on serial and parallel envs with partial resets, and against the
SUMO env's own history."""

from __future__ import annotations

from functools import partial

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import Compose, ExcludeTransform, ParallelEnv, RenameTransform, SerialEnv, TransformedEnv
from torchrl.envs.utils import check_env_specs

from kddrl_trl import keys as K
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.transforms import LeaderHistory, make_kddrl_transforms
from kddrl_trl.transforms.leader_history import restart_window

ENV_HISTORY = ("leaders", "env_history")  # the env's own window, kept aside to compare with


def fake_without_history(num_roads=3, seed=0, keep_env_history=False):
    """The fake env as an env writing only instantaneous raw keys (its history removed, or renamed aside)."""
    hide = (
        RenameTransform([K.LEADERS_HISTORY], [ENV_HISTORY]) if keep_env_history else ExcludeTransform(K.LEADERS_HISTORY)
    )
    return TransformedEnv(FakeHighwayEnv(num_roads=num_roads, seed=seed), hide)


def accelerate(td):
    td.set(K.LC_ACTION, torch.nn.functional.one_hot(torch.randint(0, 3, td.batch_size), 3).float())
    td.set(K.CF_ACTION, torch.rand(*td.batch_size, 1) * 4 - 2)
    return td


def frame(y, v, present):
    """A one-row tensordict of leader kinematics a, b, c (followers absent)."""
    kin = torch.zeros(1, 6, 3)
    kin[0, :3, 0], kin[0, :3, 1] = torch.tensor(y), torch.tensor(v)
    mask = torch.zeros(1, 6, dtype=torch.bool)
    mask[0, :3] = torch.tensor(present)
    return TensorDict({K.NEIGHBORS_KIN: kin, K.NEIGHBORS_MASK: mask}, batch_size=[1])


def test_continuing_vehicles_roll_new_ones_restart_and_moves_follow_their_vehicle():
    t = LeaderHistory(history_len=4, dt=0.1)
    first = frame([50.0, 30.0, 80.0], [30.0, 20.0, 25.0], [True, True, False])
    w0 = t.fresh(first)
    assert torch.allclose(w0[0, 0, :, 0], torch.tensor([41.0, 44.0, 47.0, 50.0])) and (w0[0, 2] == 0).all()
    # a keeps its vehicle (50 + 3 m), b's vehicle is replaced (a jump of 20 m), c appears
    w1 = t.advance(
        w0, torch.tensor([[True, True, False]]), frame([53.0, 50.0, 90.0], [30.0, 20.0, 25.0], [True, True, True])
    )
    assert torch.allclose(w1[0, 0, :, 0], torch.tensor([44.0, 47.0, 50.0, 53.0]))
    assert torch.allclose(w1[0, 1], restart_window(torch.tensor(50.0), torch.tensor(20.0), 4, 0.1))
    assert torch.allclose(w1[0, 2], restart_window(torch.tensor(90.0), torch.tensor(25.0), 4, 0.1))
    # the ego changes lane to the left: the old a becomes b, and its window moves with it; a is now empty
    w2 = t.advance(
        w1, torch.tensor([[True, True, True]]), frame([0.0, 56.0, 52.0], [0.0, 30.0, 20.0], [False, True, True])
    )
    assert (w2[0, 0] == 0).all()
    assert torch.allclose(w2[0, 1, :, 0], torch.tensor([47.0, 50.0, 53.0, 56.0]))
    assert torch.allclose(w2[0, 2], torch.cat([w1[0, 1, 1:], torch.tensor([[52.0, 20.0]])]))  # the old b
    # a speed jump beyond any braking is another vehicle, even at the expected position
    w3 = t.advance(
        w2, torch.tensor([[False, True, True]]), frame([0.0, 59.0, 54.0], [0.0, 10.0, 20.0], [False, True, True])
    )
    assert torch.allclose(w3[0, 1], restart_window(torch.tensor(59.0), torch.tensor(10.0), 4, 0.1))


def test_two_vehicles_continuing_one_leader_do_not_share_its_window():
    """The ego changes lane to the left: the old c becomes b exactly, while a new car in c is within the tolerances
    of the old c too (side by side in the next lane). b keeps the old c's window, c restarts."""
    t = LeaderHistory(history_len=4, dt=0.1)
    w0 = t.fresh(frame([0.0, 0.0, 100.0], [0.0, 0.0, 24.0], [False, False, True]))
    w1 = t.advance(
        w0, torch.tensor([[False, False, True]]), frame([0.0, 102.4, 101.8], [0.0, 24.0, 24.5], [False, True, True])
    )
    assert torch.allclose(w1[0, 1], torch.cat([w0[0, 2, 1:], torch.tensor([[102.4, 24.0]])]))
    assert torch.allclose(w1[0, 2], restart_window(torch.tensor(101.8), torch.tensor(24.5), 4, 0.1))
    # either claimant alone continues the old c: the pairing, not the tolerance, decides
    alone = t.advance(
        w0, torch.tensor([[False, False, True]]), frame([0.0, 0.0, 101.8], [0.0, 0.0, 24.5], [False, False, True])
    )
    assert torch.allclose(alone[0, 2], torch.cat([w0[0, 2, 1:], torch.tensor([[101.8, 24.5]])]))


def test_it_reproduces_the_fake_envs_history_and_declares_its_spec():
    """The fake's traffic drives at constant speed, so its own window (constant-speed back-extrapolation) is what
    the transform must give at every frame, slot changes and partial resets included."""
    torch.manual_seed(24)  # actions whose rollout has a lane change beside a car continuing the old leader c
    env = TransformedEnv(fake_without_history(keep_env_history=True), LeaderHistory())
    td = env.rollout(300, accelerate, break_when_any_done=False)
    check_env_specs(env, seed=None)
    assert K.LEADERS_HISTORY in env.observation_spec.keys(True, True)
    assert K.LEADERS_HISTORY in env.state_spec.keys(True, True)  # carried into (partial) resets and workers
    assert td["next", "done"].any(), "no episode ended: no reset was exercised"
    torch.testing.assert_close(td["next", *K.LEADERS_HISTORY], td["next", *ENV_HISTORY], atol=1e-3, rtol=0)
    torch.testing.assert_close(td[K.LEADERS_HISTORY], td[ENV_HISTORY], atol=1e-3, rtol=0)


def test_a_partial_reset_refills_only_the_rows_that_reset():
    env = TransformedEnv(fake_without_history(3), LeaderHistory())
    td = env.reset()
    for _ in range(5):
        td = env.step(accelerate(td))["next"]
    before = td[K.LEADERS_HISTORY].clone()
    td["_reset"] = torch.tensor([[False], [True], [False]])
    out = env.reset(td)
    assert torch.equal(out[K.LEADERS_HISTORY][[0, 2]], before[[0, 2]])
    assert torch.equal(out[K.LEADERS_HISTORY][1], env.transform[-1].fresh(out)[1])


def test_inert_where_the_env_writes_its_own_history():
    base = FakeHighwayEnv(num_roads=2, seed=1)
    env = TransformedEnv(FakeHighwayEnv(num_roads=2, seed=1), LeaderHistory())
    assert K.LEADERS_HISTORY not in env.state_spec.keys(True, True)
    torch.manual_seed(0)
    a = env.rollout(20, accelerate, break_when_any_done=False)
    torch.manual_seed(0)
    b = base.rollout(20, accelerate, break_when_any_done=False)
    assert torch.equal(a["next", *K.LEADERS_HISTORY], b["next", *K.LEADERS_HISTORY])
    stack_env = TransformedEnv(FakeHighwayEnv(num_roads=2), make_kddrl_transforms())
    assert K.LEADERS_HISTORY not in stack_env.state_spec.keys(True, True)  # the SUMO pipeline's specs: unchanged


@pytest.mark.parametrize("batched", ["serial", "parallel"])
@pytest.mark.parametrize("where", ["outside", "inside"])
def test_serial_and_parallel_envs_with_partial_resets(batched, where):
    cls = SerialEnv if batched == "serial" else ParallelEnv
    if where == "outside":  # one transform over the batch of workers
        env = TransformedEnv(cls(2, partial(fake_without_history, 2, keep_env_history=True)), LeaderHistory())
    else:  # a transform in every worker
        env = cls(2, lambda: TransformedEnv(fake_without_history(2, keep_env_history=True), LeaderHistory()))
    try:
        check_env_specs(env, seed=None)
        td = env.rollout(250, accelerate, break_when_any_done=False)  # ends episodes at different frames
        assert td["next", "done"].any() and not td["next", "done"].all()
        torch.testing.assert_close(td["next", *K.LEADERS_HISTORY], td["next", *ENV_HISTORY], atol=1e-3, rtol=0)
    finally:
        env.close()


def test_the_kddrl_stack_runs_on_an_env_without_the_history_key():
    env = TransformedEnv(fake_without_history(2, keep_env_history=True), make_kddrl_transforms())
    check_env_specs(env, seed=None)
    td = env.rollout(30, accelerate, break_when_any_done=False)
    assert td["next", "pred", "key_gaps"].shape == (2, 30, 3, 2)
    torch.testing.assert_close(td["next", *K.LEADERS_HISTORY], td["next", *ENV_HISTORY], atol=1e-3, rtol=0)


@pytest.mark.usefixtures("no_sumo_open")
def test_on_the_sumo_env_it_reproduces_its_history_where_the_leaders_stay():
    from kddrl_trl.baselines import IDMMobilPolicy
    from kddrl_trl.envs import SumoHighwayEnv

    base = SumoHighwayEnv("baseline", num_roads=4, seed=0)
    env = TransformedEnv(base, Compose(RenameTransform([K.LEADERS_HISTORY], [ENV_HISTORY]), LeaderHistory()))
    policy, h = IDMMobilPolicy(), base.config.history_len
    try:
        td = env.reset()
        ids, compared = [], 0
        for _ in range(250):
            full, td = env.step_and_maybe_reset(policy(td))
            ids.append([list(s[:3]) for s in base.sim.observer.slots])
            ours, theirs = full["next", *K.LEADERS_HISTORY], full["next", *ENV_HISTORY]
            for r in range(base.num_roads):
                for s in range(3):
                    window = [frame[r][s] for frame in ids[-h:]]
                    if (
                        len(window) == h
                        and window[0] is not None
                        and len(set(window)) == 1
                        and base.sim.frame[r] >= h
                        and not full["next", "done"][r]
                    ):
                        torch.testing.assert_close(ours[r, s], theirs[r, s], atol=1e-4, rtol=0)
                        compared += 1
            if full["next", "done"].any():  # the roads that reset: compare from their new episodes only
                for r in full["next", "done"].reshape(-1).nonzero().flatten().tolist():
                    for frame in ids:
                        frame[r] = [None, None, None]
        assert compared > 500
    finally:
        env.close()


def test_the_stack_refuses_an_env_of_another_frame_time():
    """The history and trajGAN's key steps are in frames of 0.1 s: an env stepping 0.2 s is refused, by name."""
    from torchrl.envs import TransformedEnv

    from kddrl_trl.envs import FakeHighwayEnv
    from kddrl_trl.transforms import make_kddrl_transforms

    TransformedEnv(FakeHighwayEnv(num_roads=2), make_kddrl_transforms()).rollout(2)  # 0.1 s: accepted
    with pytest.raises(ValueError, match=r"frames last 0.2 s \(config.step_length\)"):
        env = TransformedEnv(FakeHighwayEnv(num_roads=2, step_length=0.2), make_kddrl_transforms())
        env.rollout(2)
