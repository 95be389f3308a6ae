"""lcGAN networks (paper Eq. 16-17): the generator ``G(Z, C)`` with the normalisation of the condition ``C``
(see the package docstring for its layout) and the discriminator ``D(P, C)``."""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torch import Tensor, nn

from kddrl_trl import keys as K

from ..mlp import mlp

KIND = "lcgan"
NUM_ACTIONS = len(K.LC_ACTIONS)
_STD_FLOOR = 0.1
_MASKED_LOGIT = -1e4  # exp(-1e4) == 0 in float32: impossible directions get probability exactly 0


def condition_size() -> int:
    """Length of the assembled condition vector C (see the module docstring)."""
    return 4 + 2 + 6 * 4 + 6 + 6 + 3 * 2 + 3


def lane_availability(lane: Tensor, num_lanes: int | Tensor) -> Tensor:
    """``[..., 3]`` bool over (left, keep, right): which directions exist (lane 0 = rightmost)."""
    lane = torch.as_tensor(lane).long()
    num_lanes = torch.as_tensor(num_lanes, device=lane.device)
    left, right = lane < num_lanes - 1, lane > 0
    left, right = torch.broadcast_tensors(left, right)
    return torch.stack([left, torch.ones_like(left), right], dim=-1)


def _mlp(n_in: int, hidden: int, layers: int, n_out: int) -> nn.Sequential:
    return mlp([n_in, *[hidden] * layers, n_out], lambda: nn.LeakyReLU(0.2))


def _masked_moments(x: Tensor, present: Tensor) -> tuple[Tensor, Tensor]:
    """Mean and std (floored) of ``x [N, ..., F]`` over the rows where ``present [N, ...]``, per slot/feature."""
    w = present.unsqueeze(-1).to(torch.float64)
    x = x.to(torch.float64) * w
    n = w.sum(0).clamp(min=1.0)
    mean = x.sum(0) / n
    var = ((x - mean * w) ** 2).sum(0) / n
    return mean.float(), var.sqrt().clamp(min=_STD_FLOOR).float()


class LCGenerator(nn.Module):
    """G(Z, C) -> P over (left, keep, right), paper Eq. 16. Holds the condition's normalisation buffers."""

    def __init__(self, noise_dim: int = 8, hidden: int = 64, layers: int = 2):
        super().__init__()
        self.noise_dim = noise_dim
        self.net = _mlp(condition_size() + noise_dim, hidden, layers, NUM_ACTIONS)
        self.register_buffer("s_av_mean", torch.zeros(4))
        self.register_buffer("s_av_std", torch.ones(4))
        self.register_buffer("rel_mean", torch.zeros(6, 4))
        self.register_buffer("rel_std", torch.ones(6, 4))
        self.register_buffer("offset_mean", torch.zeros(6, 1))
        self.register_buffer("offset_std", torch.ones(6, 1))
        self.register_buffer("gap_mean", torch.zeros(3, 2))
        self.register_buffer("gap_std", torch.ones(3, 2))

    @torch.no_grad()
    def fit_normalisation(self, samples: TensorDict) -> None:
        """Normalisation statistics from the train split's ``lane_changes`` samples."""
        s_av = samples["s_av"].float()
        self.s_av_mean.copy_(s_av.mean(0))
        self.s_av_std.copy_(s_av.std(0).nan_to_num(1.0).clamp(min=_STD_FLOOR))
        for name, x, m in (
            ("rel", samples["rel"], samples["mask"]),
            ("offset", samples["lane_offset"].unsqueeze(-1), samples["mask"]),
            ("gap", samples["key_gaps"], samples["key_gaps_mask"]),
        ):
            mean, std = _masked_moments(x, m.bool())
            getattr(self, f"{name}_mean").copy_(mean)
            getattr(self, f"{name}_std").copy_(std)

    def condition(
        self,
        s_av: Tensor,
        rel: Tensor,
        lane_offset: Tensor,
        mask: Tensor,
        key_gaps: Tensor,
        key_gaps_mask: Tensor,
        num_lanes: int | Tensor,
    ) -> tuple[Tensor, Tensor]:
        """Assemble and normalise C; returns ``(C [..., condition_size()], available [..., 3] bool)``.

        Absent slots (mask False) contribute zeros whatever their raw values (even NaN)."""
        mask, key_gaps_mask = mask.bool(), key_gaps_mask.bool()
        avail = lane_availability(s_av[..., 2].round(), num_lanes)
        z_s = (s_av - self.s_av_mean) / self.s_av_std
        z_rel = torch.where(mask.unsqueeze(-1), (rel - self.rel_mean) / self.rel_std, torch.zeros_like(rel))
        z_off = torch.where(
            mask, (lane_offset - self.offset_mean[:, 0]) / self.offset_std[:, 0], torch.zeros_like(lane_offset)
        )
        z_gap = torch.where(
            key_gaps_mask.unsqueeze(-1), (key_gaps - self.gap_mean) / self.gap_std, torch.zeros_like(key_gaps)
        )
        c = torch.cat(
            [
                z_s,
                avail[..., [0, 2]].to(z_s.dtype),
                z_rel.flatten(-2),
                mask.to(z_s.dtype),
                z_off,
                z_gap.flatten(-2),
                key_gaps_mask.to(z_s.dtype),
            ],
            dim=-1,
        )
        return c, avail

    def logits(self, c: Tensor, z: Tensor, available: Tensor) -> Tensor:
        """Action logits with impossible directions masked to a large negative value."""
        out = self.net(torch.cat([c, z], dim=-1))
        return out.masked_fill(~available, _MASKED_LOGIT)

    def forward(self, c: Tensor, z: Tensor, available: Tensor) -> Tensor:
        """P_lcGAN = G(Z, C) (Eq. 16): ``[..., 3]`` probabilities, exactly 0 on impossible directions."""
        return torch.softmax(self.logits(c, z, available), dim=-1)


class LCDiscriminator(nn.Module):
    """D(P, C) -> logit of "real human action", paper Eq. 17 (``s = sigmoid(logit)``)."""

    def __init__(self, hidden: int = 64, layers: int = 2):
        super().__init__()
        self.net = _mlp(NUM_ACTIONS + condition_size(), hidden, layers, 1)

    def forward(self, p: Tensor, c: Tensor) -> Tensor:
        return self.net(torch.cat([p, c], dim=-1)).squeeze(-1)
