"""Soft target updates (paper Eq. 5 for D3QN, Eq. 9-10 for TD3, and the target embedding's, Eq. 23-24) over all
target tensors at once: TorchRL's ``SoftUpdate`` lerps its targets tensor by tensor; :class:`PolyakUpdate` does
the same arithmetic with one ``torch._foreach_lerp_`` per group of targets, so that a compiled or CUDA-graphed
update function holds it as a handful of kernels.

The semantics are ``SoftUpdate`` 's: the same tensors (those its ``init_`` kept: targets distinct from their
sources) and the same weight ``tau = 1 - eps``, ``target <- target + tau (source - target)``.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch
from torch import nn
from torchrl.objectives import SoftUpdate


def soft_update_tensors(updater: SoftUpdate) -> tuple[list[torch.Tensor], list[torch.Tensor], float]:
    """(targets, sources, tau) of a TorchRL ``SoftUpdate``, read from its loss module now (after the learner moved
    to its device: the tensors ``SoftUpdate`` cached at construction may be stale)."""
    loss = updater.loss_module
    targets, sources = [], []
    for key in updater._sources.keys(include_nested=True, leaves_only=True):
        key = key if isinstance(key, tuple) else (key,)
        sources.append(getattr(loss, key[0]).get(key[1:]))
        targets.append(getattr(loss, "target_" + key[0]).get(key[1:]))
    return targets, sources, 1.0 - float(updater.eps)


def module_tensors(
    target: nn.Module | None, source: nn.Module | None, tau: float
) -> tuple[list[torch.Tensor], list[torch.Tensor], float]:
    """(targets, sources, tau) of a target copy of a module (the target embedding); ``([], [], tau)`` for None."""
    if target is None or source is None:
        return [], [], float(tau)
    pairs = list(zip(target.parameters(), source.parameters(), strict=True))
    return [t for t, _ in pairs], [s for _, s in pairs], float(tau)


class PolyakUpdate:
    """``target <- (1 - tau) target + tau source`` for groups ``(targets, sources, tau)``
    (:func:`soft_update_tensors`, :func:`module_tensors`), one ``torch._foreach_lerp_`` per group. Call it inside
    the update function (no gradient flows). ``copies``: (targets, sources) copied as they are (buffers)."""

    def __init__(
        self,
        *groups: tuple[list[torch.Tensor], list[torch.Tensor], float],
        copies: Iterable[tuple[torch.Tensor, torch.Tensor]] = (),
    ):
        self.groups = [(list(t), list(s), float(tau)) for t, s, tau in groups if len(t)]
        for targets, sources, _ in self.groups:
            if len(targets) != len(sources):
                raise ValueError(f"PolyakUpdate: {len(targets)} targets for {len(sources)} sources")
        self.copies = list(copies)

    @torch.no_grad()
    def __call__(self) -> None:
        for targets, sources, tau in self.groups:
            torch._foreach_lerp_(targets, sources, tau)
        for target, source in self.copies:
            target.copy_(source)
