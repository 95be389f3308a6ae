"""Shared helpers for the test suite."""

from __future__ import annotations

import os
import tempfile

import pytest
import torch
import torch.nn.functional as F
from tensordict import TensorDict

from kddrl_trl import keys as K

# keep the network cache of the tests away from the user's cache, but share it between tests
os.environ.setdefault("KDDRL_TRL_CACHE", os.path.join(tempfile.gettempdir(), "kddrl_trl_test_cache"))
torch.set_num_threads(1)


def command(env, lc=K.KEEP, accel=0.0) -> TensorDict:
    """An action tensordict for every road of ``env``: lane-change index (or [K] tensor) and acceleration."""
    k = env.batch_size[0]
    lc = torch.as_tensor(lc).expand(k) if torch.as_tensor(lc).dim() == 0 else torch.as_tensor(lc)
    accel = torch.as_tensor(accel, dtype=torch.float32)
    accel = accel.expand(k) if accel.dim() == 0 else accel
    return TensorDict(
        {K.LC_ACTION: F.one_hot(lc.long(), 3).float(), K.CF_ACTION: accel.reshape(k, 1).float()}, batch_size=[k]
    )


@pytest.fixture
def no_sumo_open():
    """Every test that opens a SUMO env must leave none open behind it."""
    from kddrl_trl.envs import sim

    yield
    assert sim._ACTIVE is None, "a test left a SUMO simulation open"


#: a small hierarchical learner for the learner tests (test_learner.py, test_learner_update.py)
SMALL = {
    "embed_dim": 8,
    "embed_hidden": 16,
    "d3qn": {"hidden": [32, 32], "eps_decisions": 50},
    "td3": {"hidden": [32, 32]},
}


def fake_samples(n_frames: int, n_macros: int) -> tuple[list, list]:
    """``n_frames`` buffer-L and ``n_macros`` buffer-H samples collected (one batch of 40 frames on 4 roads) from
    the fake env with the full transform stack and a :data:`SMALL` learner's exploring policy."""
    from torchrl.envs import Compose, TransformedEnv

    from kddrl_trl.collectors import MultiTimescaleCollector
    from kddrl_trl.envs import FakeHighwayEnv
    from kddrl_trl.training import HierarchicalLearner, make_buffer
    from kddrl_trl.transforms import DecisionClock, make_kddrl_transforms

    torch.manual_seed(0)
    env = TransformedEnv(FakeHighwayEnv(num_roads=4, seed=0), Compose(make_kddrl_transforms(), DecisionClock(5)))
    learner = HierarchicalLearner(**SMALL)
    rb_l, rb_h = make_buffer(5000, 32, 0), make_buffer(5000, 16, 0)
    mtc = MultiTimescaleCollector.from_env(
        env, learner.policy(), frames_per_env=40, frame_buffer=rb_l, macro_buffer=rb_h, frame_keys=learner.buffer_keys()
    )
    next(iter(mtc))
    mtc.shutdown()
    return [rb_l.sample() for _ in range(n_frames)], [rb_h.sample() for _ in range(n_macros)]
