"""The losses of lcGAN's generator beside the adversarial term (paper Eq. 19): the focal loss and its class
weights ``α``."""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from .model import NUM_ACTIONS


def focal_loss(log_p: Tensor, target: Tensor, alpha: Tensor, gamma: float = 2.0) -> Tensor:
    """Supervised term of Eq. 19: ``mean_i -α_k (1 - p_{i,k})^γ log p_{i,k}`` for the true class ``k``.

    Args:
        log_p: ``[N, 3]`` log-probabilities (masked log-softmax of G).
        target: ``[N]`` int64 true class (``keys.LEFT / KEEP / RIGHT``).
        alpha: ``[3]`` class weights α_k.
    """
    lp = log_p.gather(-1, target.unsqueeze(-1)).squeeze(-1)
    return (-alpha.to(lp)[target] * (1.0 - lp.exp()).pow(gamma) * lp).mean()


def class_weights(freq: Tensor, mode: Any = "inv_sqrt") -> Tensor:
    """α_k from class frequencies ``freq [3]``: "inv_sqrt", "inv", "none" or 3 explicit numbers.

    The inverse modes are normalised to mean 1 over the classes (a class never seen gets the largest
    weight of the others rather than infinity)."""
    if not isinstance(mode, str):
        a = torch.as_tensor([float(x) for x in mode], dtype=torch.float32)
        if a.shape != (NUM_ACTIONS,) or (a < 0).any():
            raise ValueError(f"alpha must be 3 non-negative numbers (left, keep, right), got {mode!r}")
        return a
    freq = torch.as_tensor(freq, dtype=torch.float64)
    if mode == "none":
        return torch.ones(NUM_ACTIONS)
    power = {"inv_sqrt": 0.5, "inv": 1.0}.get(mode)
    if power is None:
        raise ValueError(f"alpha must be 'inv_sqrt', 'inv', 'none' or 3 numbers, got {mode!r}")
    seen = freq > 0
    w = torch.where(seen, freq.clamp(min=1e-12).pow(-power), torch.zeros_like(freq))
    w = torch.where(seen, w, w.max())
    return (w / w.mean()).float()
