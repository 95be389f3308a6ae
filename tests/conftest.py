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
    return TensorDict({K.LC_ACTION: F.one_hot(lc.long(), 3).float(), K.CF_ACTION: accel.reshape(k, 1).float()},
                      batch_size=[k])


@pytest.fixture
def no_sumo_open():
    """Every test that opens a SUMO env must leave none open behind it."""
    from kddrl_trl.envs import sim

    yield
    assert sim._ACTIVE is None, "a test left a SUMO simulation open"
