"""``CapturedPolicy``: a learner's acting policy run as its captured graph acts bit for bit as the policy itself."""

from __future__ import annotations

import copy
import pickle

import pytest
import torch
from testkit import compose_job
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from kddrl_trl import keys as K
from kddrl_trl.collectors import CapturedPolicy, MultiRatePolicy, capture
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.factories import make_learner
from kddrl_trl.transforms import DecisionClock, make_kddrl_transforms


def _learner(compile: bool = False):
    """The default job's KDDRL learner."""
    return make_learner(compose_job().algo, compile=compile)


def _frames(k: int = 6, n: int = 24, seed: int = 0) -> list:
    """Env frames with the deciding rows drawn at random: sub-batches of every size, none and all included."""
    env = TransformedEnv(
        FakeHighwayEnv(num_roads=k, seed=seed), Compose(make_kddrl_transforms(seed=seed), DecisionClock(20))
    )
    td, out = env.reset(), []
    gen = torch.Generator().manual_seed(seed)
    for i in range(n):
        td = env.rand_step(td)["next"]
        frame = td.clone()
        decide = frame.get(K.LC_DECIDE)
        rows = torch.rand(k, generator=gen) < (i % 4) / 3  # 0, 1/3, 2/3, all
        frame.set(K.LC_DECIDE, rows.reshape(decide.shape).to(decide.dtype))
        out.append(frame)
    return out


def _assert_same_actions(a_policy, b_policy, frames, seed: int) -> None:
    for t, frame in enumerate(frames):
        torch.manual_seed(seed + t)
        a = a_policy(frame.clone())
        torch.manual_seed(seed + t)
        b = b_policy(frame.clone())
        for key in (K.LC_ACTION, K.CF_ACTION):
            assert torch.equal(a[key], b[key]), (t, key)


def test_captured_policy_acts_bit_for_bit_as_the_policy_and_calls_warm_graphs_directly():
    """Exploring and greedy, over sub-batches of every size, after in-place updates of the weights and of ε and
    σ: the captured policy's actions are the eager policy's, bit for bit; its parts then run their graphs directly."""
    learner = _learner()
    eager = learner.policy()
    captured = capture(learner.policy(), eager_calls=3)
    assert isinstance(captured, MultiRatePolicy) and isinstance(captured.cf_policy, CapturedPolicy)
    frames = _frames()
    with torch.no_grad():
        with set_exploration_type(ExplorationType.RANDOM):
            _assert_same_actions(eager, captured, frames, seed=1)
            for p in learner.parameters():  # an optimiser's in-place step
                p.add_(0.01 * torch.randn_like(p))
            learner.explore_step(decisions=5000, frames=5000)  # ε and σ move, in place
            _assert_same_actions(eager, captured, frames, seed=2)
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            _assert_same_actions(eager, captured, frames, seed=3)
    for part in (captured.lc_policy, captured.cf_policy, captured.shared):
        direct = [f for f in part._warm.direct.values() if f is not None]
        assert direct, f"{part.module} never ran its graph directly"
    assert any(f is not None for f in captured.lc_policy._warm.direct.values())


def test_captured_policy_copies_and_pickles_without_its_graphs_and_acts_the_same():
    """A copy (a :class:`PolicySnapshot`'s, a spawned evaluator's pickle) traces again and acts the same."""
    learner = _learner()
    policy = capture(learner.policy(explore=False), eager_calls=0)
    frames = _frames(k=3, n=6)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        _assert_same_actions(learner.policy(explore=False), policy, frames, seed=0)
        for clone in (pickle.loads(pickle.dumps(policy)), copy.deepcopy(policy)):
            assert clone.cf_policy._warm is None and clone.cf_policy._calls == 0
            _assert_same_actions(policy, clone, frames, seed=0)
    lazy = capture(learner.policy(explore=False))  # the default: a policy that acts a few times is never traced
    with torch.no_grad():
        _assert_same_actions(learner.policy(explore=False), lazy, frames, seed=0)
    assert lazy.cf_policy._warm is None and lazy.cf_policy._calls == len(frames)


def test_a_learner_acts_through_its_captured_policy_when_compiled():
    """``Learner.policy`` captures where the learner compiles, and only there; any other policy is captured whole."""
    if not isinstance(_learner(compile=True).policy().cf_policy, CapturedPolicy):
        pytest.fail("a compiled learner's policy is not captured")
    assert not isinstance(_learner().policy().cf_policy, CapturedPolicy)
    whole = capture(_learner().cf_actor)
    assert isinstance(whole, CapturedPolicy) and whole.in_keys == list(_learner().cf_actor.in_keys)
