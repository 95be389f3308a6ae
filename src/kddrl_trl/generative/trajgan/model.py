"""trajGAN networks (paper Eq. 13-15): the condition, the generator ``G(Z, TC)``, the discriminator
``D(trajectory, TC)`` and the refinement ``TG = TC + G`` that training and inference share.

Condition (all positions RELATIVE to the leader's current position ``y0 = history[:, -1, 0]``, speeds as
they are, each feature standardised with train-split statistics):

* ``prior - y0`` [horizon] (always);
* with ``use_history`` (default): the leader history positions ``history[:, :-1, 0] - y0`` [H-1] (the last
  one is 0 by construction), its speeds ``history[:, :, 1]`` [H], and the vehicle ahead of the leader:
  ``present * (y_ahead - y0)``, ``present * v_ahead``, ``present`` [3].

Generator output and discriminator input live in the standardised residual space
``r = (future - prior - res_mean) / res_std`` (per horizon step, train statistics), a bijection of
``future - y0`` given ``TC``; the statistics are buffers of the generator, so every checkpoint carries them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor, nn

from ..mlp import mlp

KIND = "trajgan"
#: identifies the condition layout (part of the checkpoint architecture)
FEATURES_VERSION = "trajgan-cond/1: prior-y0[T], hist_y-y0[H-1], hist_v[H], ahead(p*(y-y0), p*v, p)[3]"


def condition_features(history: Tensor, ahead: Tensor, prior: Tensor, use_history: bool = True) -> Tensor:
    """Raw (unstandardised) condition of each leader: ``[N, H, 2]``, ``[N, 3]``, ``[N, T]`` -> ``[N, C]``.

    Everything is relative to ``y0 = history[:, -1, 0]`` (see the module docstring)."""
    y0 = history[:, -1, 0:1]
    parts = [prior - y0]
    if use_history:
        present = (ahead[:, 2:3] > 0).to(prior.dtype)
        parts += [
            history[:, :-1, 0] - y0,
            history[:, :, 1],
            present * (ahead[:, 0:1] - y0),
            present * ahead[:, 1:2],
            present,
        ]
    return torch.cat(parts, dim=-1)


def cond_dim(history_len: int, horizon: int, use_history: bool) -> int:
    """Length of :func:`condition_features`' output."""
    return horizon + (2 * history_len - 1 + 3 if use_history else 0)


class TrajGenerator(nn.Module):
    """``G(Z, TC)`` (Eq. 13): an MLP on ``[condition, noise]`` plus a linear skip from the condition.

    Returns the standardised residual on the prior; the normalisation statistics are buffers (saved in
    the state dict). The output layers start at zero, so an untrained generator returns
    ``TC + mean residual``."""

    def __init__(self, cond_dim: int, horizon: int, noise_dim: int, hidden: Sequence[int]):
        super().__init__()
        self.cond_dim, self.horizon, self.noise_dim = cond_dim, horizon, noise_dim
        self.net = mlp([cond_dim + noise_dim, *hidden, horizon], nn.SiLU)
        self.skip = nn.Linear(cond_dim, horizon)
        for lin in (self.net[-1], self.skip):
            nn.init.zeros_(lin.weight)
            nn.init.zeros_(lin.bias)
        self.register_buffer("cond_mean", torch.zeros(cond_dim))
        self.register_buffer("cond_std", torch.ones(cond_dim))
        self.register_buffer("res_mean", torch.zeros(horizon))
        self.register_buffer("res_std", torch.ones(horizon))

    def normalize(self, cond_raw: Tensor) -> Tensor:
        return (cond_raw - self.cond_mean) / self.cond_std

    def forward(self, cond: Tensor, z: Tensor) -> Tensor:
        """Standardised condition ``[N, C]``, noise ``[N, noise_dim]`` -> standardised residual ``[N, T]``."""
        return self.net(torch.cat([cond, z], dim=-1)) + self.skip(cond)

    def to_metres(self, r: Tensor) -> Tensor:
        """Standardised residual -> residual on the prior in metres."""
        return r * self.res_std + self.res_mean

    def to_standard(self, residual: Tensor) -> Tensor:
        return (residual - self.res_mean) / self.res_std


class TrajDiscriminator(nn.Module):
    """``D(trajectory, TC)``: an MLP on ``[standardised residual, standardised condition]`` -> one logit."""

    def __init__(self, cond_dim: int, horizon: int, hidden: Sequence[int]):
        super().__init__()
        self.net = mlp([horizon + cond_dim, *hidden, 1], lambda: nn.LeakyReLU(0.2))

    def forward(self, r: Tensor, cond: Tensor) -> Tensor:
        return self.net(torch.cat([r, cond], dim=-1)).squeeze(-1)


def generator_from_architecture(arch: Mapping[str, Any]) -> TrajGenerator:
    """An untrained generator of a checkpoint's ``architecture`` (its weights are loaded next)."""
    return TrajGenerator(
        int(arch["cond_dim"]), int(arch["horizon"]), int(arch["noise_dim"]), [int(h) for h in arch["g_hidden"]]
    )


def refine(gen: TrajGenerator, cond: Tensor, prior: Tensor, z: Tensor) -> Tensor:
    """Eq. 13 on ``m`` rows: ``prior + G(z, cond)`` for each of the ``k`` noise draws ``z`` ``[k, m, noise_dim]``
    (``cond`` normalised ``[m, cond_dim]``, ``prior`` ``[m, T]``) -> ``[k, m, T]`` absolute positions."""
    k, m = z.shape[0], z.shape[1]
    r = gen(cond.unsqueeze(0).expand(k, m, -1).reshape(k * m, -1), z.reshape(k * m, -1))
    return prior.unsqueeze(0) + gen.to_metres(r).reshape(k, m, -1)
