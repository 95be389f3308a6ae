"""``PolicySnapshot``: a CPU copy of an acting policy that :meth:`~PolicySnapshot.sync` refreshes from its source.

Two uses, one class:

- a non-CPU learner acts through it (:meth:`kddrl_trl.training.Learner.policy`): the env's TensorDicts are on the
  CPU, and acting there is faster than a GPU call with the transfers there and back
  (``benchmarks/gpu_update.py --acting-calls N`` measures both: ``gpu.acting``);
- an overlapped collection (``collector.sync=false``, :class:`~kddrl_trl.collectors.overlap.OverlappedCollector`):
  the worker acts with the snapshot while the learner updates its own weights, and the snapshot is refreshed only
  while the worker waits between two batches.
"""

from __future__ import annotations

import copy

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase


class PolicySnapshot(TensorDictModuleBase):
    """A CPU deep copy of ``policy`` (its networks and exploration schedules: ε, σ are module buffers), acting
    like it; :meth:`sync` copies the source's current weights and buffers into the copy's own tensors, in place
    (so a worker process that shares those tensors reads the new values). It pickles without its source (the
    learner's own policy, possibly on a GPU): an unpickled snapshot acts alone and cannot :meth:`sync`."""

    def __init__(self, policy: TensorDictModuleBase):
        super().__init__()
        self.__dict__["source"] = policy  # not a submodule: this module's state is the copy's
        self.policy = copy.deepcopy(policy).to("cpu")
        self.in_keys, self.out_keys = list(policy.in_keys), list(policy.out_keys)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state.pop("source", None)
        return state

    @torch.no_grad()
    def sync(self) -> None:
        """Copies the source's current weights and exploration state into the copy."""
        if "source" not in self.__dict__:
            raise RuntimeError("PolicySnapshot.sync: this snapshot was unpickled without its source policy")
        mine, theirs = self.policy.state_dict(keep_vars=True), self.source.state_dict(keep_vars=True)
        torch._foreach_copy_([mine[k].data for k in mine], [theirs[k].data for k in mine])

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self.policy(tensordict)
