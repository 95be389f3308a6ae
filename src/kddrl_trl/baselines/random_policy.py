"""Uniformly random driving commands, as a cheap TensorDict module (no spec sampling on the hot path)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from ..keys import CF_ACTION, LC_ACTION


class RandomDrivingPolicy(TensorDictModuleBase):
    """Writes a uniformly random lane-change command (one-hot over left, keep, right) and a uniformly
    random acceleration in ``[low, high]`` m/s² for every element of the batch. Draws from ``generator``
    (or torch's global generator), so a seeded generator gives a reproducible action stream."""

    in_keys: list = []
    out_keys = [LC_ACTION, CF_ACTION]

    def __init__(self, low: float = -5.0, high: float = 5.0, generator: torch.Generator | None = None):
        super().__init__()
        self.low, self.high, self.generator = low, high, generator

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        shape = tensordict.batch_size
        lc = torch.randint(3, shape, generator=self.generator)
        cf = torch.rand((*shape, 1), generator=self.generator) * (self.high - self.low) + self.low
        tensordict.set(LC_ACTION, F.one_hot(lc, 3).float())
        tensordict.set(CF_ACTION, cf)
        return tensordict
