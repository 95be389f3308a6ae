"""``PortablePrioritizedSampler``: TorchRL's ``PrioritizedSampler`` (prioritized replay, ``train.prioritized``) on
any torch build.

TorchRL keeps the priorities in sum and min segment trees of its C++ extension (``torchrl._torchrl``). That
extension is compiled against one torch release: TorchRL 0.14.1's does not load with torch 2.13 (an undefined
symbol), and without it TorchRL's ``PrioritizedSampler`` refuses to start. This sampler is TorchRL's own (sampling,
importance weights, priority updates, ``state_dict``), with TorchRL's trees where the extension loads and, where it
does not, :class:`TensorSumTree` / :class:`TensorMinTree`: the same interface on one flat tensor (a query is a
reduction, sampling a ``cumsum`` + ``searchsorted``: O(capacity) per call instead of O(log capacity);
``benchmarks/replay_sampling.py`` measures what a prioritized minibatch costs against a uniform one).
"""

from __future__ import annotations

import logging

import torch
from torchrl.data.replay_buffers.samplers import prioritized as _torchrl_prioritized
from torchrl.data.replay_buffers.samplers.prioritized import PrioritizedSampler

log = logging.getLogger(__name__)
_told = False  # the fallback is announced once per process


def native_trees_available() -> bool:
    """Whether TorchRL's C++ segment trees loaded (its extension matches the installed torch)."""
    return _torchrl_prioritized.SumSegmentTreeFp32 is not None


class _TensorTree:
    """A segment tree's interface (``tree[index]``, ``tree[index] = value``, ``query(start, end)``) on one flat
    float64 tensor of ``capacity`` entries, ``fill`` where nothing was written."""

    fill: float  # the reduction's identity

    def __init__(self, capacity: int, device: torch.device | str | None = None):
        self.values = torch.full((int(capacity),), self.fill, dtype=torch.float64, device=device)

    def __len__(self) -> int:
        return self.values.numel()

    def _index(self, index) -> torch.Tensor:
        return torch.as_tensor(index, dtype=torch.long, device=self.values.device)

    def __getitem__(self, index) -> torch.Tensor:
        return self.values[self._index(index)].to(torch.float32)

    def __setitem__(self, index, value) -> None:
        value = torch.as_tensor(value, dtype=torch.float64, device=self.values.device)
        self.values[self._index(index)] = value

    def _reduce(self, values: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def query(self, start, end) -> float:
        """The reduction over ``[start, end)``."""
        return float(self._reduce(self.values[int(start) : int(end)]))


class TensorSumTree(_TensorTree):
    """Sum tree: ``query`` sums; :meth:`scan_lower_bound` finds where cumulative masses fall."""

    fill = 0.0

    def _reduce(self, values: torch.Tensor) -> torch.Tensor:
        return values.sum()

    def scan_lower_bound(self, mass) -> torch.Tensor:
        """For each ``mass``, the first index whose cumulative sum exceeds it."""
        mass = torch.as_tensor(mass, dtype=torch.float64, device=self.values.device)
        return torch.searchsorted(self.values.cumsum(0), mass, right=True)


class TensorMinTree(_TensorTree):
    """Min tree: ``query`` takes the minimum (``inf`` where nothing was written)."""

    fill = float("inf")

    def _reduce(self, values: torch.Tensor) -> torch.Tensor:
        return values.min()


class PortablePrioritizedSampler(PrioritizedSampler):
    """TorchRL's ``PrioritizedSampler``; on the tensor trees of this module where TorchRL's C++ ones did not load
    (module docstring)."""

    def _init(self) -> None:
        if native_trees_available():
            return super()._init()
        global _told
        if not _told:  # TorchRL's import-time warning says prioritized buffers "may not work": they do, on these
            log.info(
                "prioritized replay on kddrl_trl's tensor segment trees (TorchRL's C++ trees did not load "
                "with this torch; kddrl_trl/training/priority_trees.py)"
            )
            _told = True
        self._sum_tree = TensorSumTree(self._max_capacity, self._device)
        self._min_tree = TensorMinTree(self._max_capacity, self._device)
        self._max_priority = None
