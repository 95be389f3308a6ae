"""Priorities of prioritized replay (Schaul et al., 2016; ``train.prioritized``; not in the paper).

Every learner's value loss reports, per sampled transition, ``|δ|`` (``keys.PRIORITY``): the absolute TD error of
its Bellman target (Eq. 4 for the D3QN, Eq. 6-7 for TD3, the soft target for PASAC), the largest over twin critics.
TorchRL's ``PrioritizedSampler`` turns it into ``P(i) ∝ (|δ_i| + ε)^α`` and hands the next sample its
importance-sampling weights ``keys.PRIORITY_WEIGHT``, by which the TorchRL losses weight their means."""

from __future__ import annotations

import torch


def td_priority(squared_td_error: torch.Tensor, batch_numel: int) -> torch.Tensor:
    """``|δ|`` ``[batch_numel]`` from a loss's squared TD errors (TorchRL's ``td_error`` metadata: ``[B]``,
    ``[B, 1]`` or ``[critics, B]``), the largest over critics; detached."""
    return squared_td_error.detach().reshape(-1, batch_numel).amax(0).sqrt()
