"""``PolicySnapshot``: a CPU copy of an acting policy, refreshed from its source, pickled without it."""

from __future__ import annotations

import pickle

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from kddrl_trl.collectors import PolicySnapshot


def _policy() -> TensorDictModule:
    torch.manual_seed(0)
    return TensorDictModule(torch.nn.Linear(3, 2), in_keys=["x"], out_keys=["y"])


def _acts(policy) -> torch.Tensor:
    return policy(TensorDict({"x": torch.arange(12.0).reshape(4, 3)}, [4])).get("y")


def test_a_snapshot_syncs_its_source_weights_in_place():
    source = _policy()
    snapshot = PolicySnapshot(source)
    weight = snapshot.policy.module.weight
    with torch.no_grad():
        source.module.weight.add_(1.0)
    assert not torch.equal(_acts(snapshot), _acts(source))
    snapshot.sync()
    assert snapshot.policy.module.weight is weight  # the same tensor: a process sharing it sees the new values
    torch.testing.assert_close(_acts(snapshot), _acts(source), rtol=0, atol=0)


def test_a_pickled_snapshot_acts_as_its_source_without_carrying_it():
    source = _policy()
    snapshot = PolicySnapshot(source)
    copy = pickle.loads(pickle.dumps(snapshot))
    assert "source" not in copy.__dict__ and "source" in snapshot.__dict__
    torch.testing.assert_close(_acts(copy), _acts(source), rtol=0, atol=0)
    with pytest.raises(RuntimeError, match="without its source"):
        copy.sync()
    snapshot.sync()  # the original keeps its source
