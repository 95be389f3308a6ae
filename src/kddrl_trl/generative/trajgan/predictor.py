"""``TrajGANPredictor``: batched trajGAN inference at RL time, ``TG = TC + G(Z, TC)`` (paper Eq. 13)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import Tensor

from kddrl_trl import keys as K

from ..checkpoint import CheckpointError
from ..predictor import GANPredictor
from .model import FEATURES_VERSION, KIND, TrajGenerator, condition_features, generator_from_architecture, refine


class TrajGANPredictor(GANPredictor):
    """Batched trajGAN inference in the environment: ``PRED_PRIOR_TRAJ`` -> ``PRED_TRAJ`` (absolute m).

    Reads ``LEADERS_HISTORY`` [*B, 3, H, 2], ``LEADERS_AHEAD`` [*B, 3, 3], ``NEIGHBORS_MASK`` [*B, 6] (slots 0..2
    = leaders a, b, c) and ``PRED_PRIOR_TRAJ`` [*B, 3, T]; writes ``PRED_TRAJ`` [*B, 3, T]. All present leaders
    of all environments go through ONE generator call. ``reduce="sample"`` returns one draw, ``"mean"`` the
    mean of ``num_samples`` draws. An absent leader (mask False or non-finite inputs) gets its prior, or zeros
    where the prior is not finite either; the output is never NaN. The noise (:meth:`noise`, one row per leader
    slot, present or not, so the stream does not depend on who is present) and the rest of the interface are
    those of :class:`~kddrl_trl.generative.predictor.GANPredictor`. No gradients.
    """

    kind = KIND
    in_keys = [K.LEADERS_HISTORY, K.LEADERS_AHEAD, K.NEIGHBORS_MASK, K.PRED_PRIOR_TRAJ]  # noqa: RUF012
    out_keys = [K.PRED_TRAJ]  # noqa: RUF012

    def __init__(
        self,
        generator_net: TrajGenerator,
        architecture: Mapping[str, Any],
        num_samples: int = 1,
        reduce: str = "sample",
        seed: int = 0,
    ):
        if reduce not in ("sample", "mean"):
            raise ValueError(f"reduce must be 'sample' or 'mean', got {reduce!r}")
        if int(num_samples) < 1:
            raise ValueError(f"num_samples must be >= 1, got {num_samples!r}")
        super().__init__(generator_net, seed, int(num_samples) if reduce == "mean" else 1)
        self.architecture = dict(architecture)
        self.history_len, self.horizon = int(architecture["history_len"]), int(architecture["horizon"])
        self.use_history = bool(architecture["use_history"])
        self.num_samples, self.reduce = int(num_samples), reduce

    @classmethod
    def build_net(cls, architecture: Mapping[str, Any]) -> TrajGenerator:
        return generator_from_architecture(architecture)

    @classmethod
    def check_architecture(cls, path: str | Path, architecture: Mapping[str, Any]) -> None:
        if architecture.get("features") != FEATURES_VERSION:
            raise CheckpointError(
                f"{path}: condition layout {architecture.get('features')!r} is not {FEATURES_VERSION!r}"
            )

    @classmethod
    def from_net(cls, net: TrajGenerator, architecture: Mapping[str, Any], **kwargs) -> TrajGANPredictor:
        return cls(net, architecture, **kwargs)

    def _refine_rows(self, hist: Tensor, ahead: Tensor, prior: Tensor, mask: Tensor, z: Tensor) -> Tensor:
        """Dense inference on every row ``[N, ...]`` with noise ``z`` ``[k, N, noise_dim]``: rows that are
        absent or not finite get their prior (zeros where it is not finite), never NaN. No data-dependent
        shapes."""
        prior_ok = torch.isfinite(prior).all(-1)
        present = mask & prior_ok & torch.isfinite(hist).flatten(1).all(-1) & torch.isfinite(ahead).all(-1)
        zero = torch.zeros((), dtype=prior.dtype, device=prior.device)
        base = torch.where(prior_ok.unsqueeze(-1), prior, zero)
        hist = torch.where(present[:, None, None], hist, zero)
        ahead = torch.where(present[:, None], ahead, zero)
        p = torch.where(present[:, None], prior, zero)
        s = refine(self.net, self.net.normalize(condition_features(hist, ahead, p, self.use_history)), p, z)
        s = s.mean(0) if self.reduce == "mean" else s[0]
        return torch.where(present.unsqueeze(-1), s, base)

    def predict(self, hist: Tensor, ahead: Tensor, mask: Tensor, prior: Tensor, z: Tensor) -> Tensor:
        """Eq. 13 as a pure tensor function: ``TG = prior + G(Z, C(hist, ahead, prior))`` for leaders a, b, c.

        Args: ``hist`` ``[*B, 3, H, 2]``, ``ahead`` ``[*B, 3, 3]``, ``mask`` ``[*B, 3]`` (leader present),
        ``prior`` ``[*B, 3, T]``, ``z`` = :meth:`noise` of ``prod(B) * 3`` rows. Returns ``[*B, 3, T]`` float32
        absolute positions (m) on the device of ``prior``, never NaN."""
        batch = hist.shape[:-3]
        h, t = hist.shape[-2], prior.shape[-1]
        if t != self.horizon or (self.use_history and h != self.history_len):
            raise ValueError(
                f"trajGAN was trained with history {self.history_len} / horizon {self.horizon}, "
                f"got history {h} / horizon {t}"
            )
        dev, out_dev = self.device(), prior.device
        out = self._refine_rows(
            hist.reshape(-1, h, 2).to(dev, torch.float32),
            ahead.reshape(-1, 3).to(dev, torch.float32),
            prior.reshape(-1, t).to(dev, torch.float32),
            mask.reshape(-1).to(dev, torch.bool),
            z,
        )
        out = torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)
        return out.reshape(*batch, 3, t).to(out_dev)

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        hist = tensordict.get(K.LEADERS_HISTORY)
        z = self.noise(hist.shape[:-3].numel() * 3)
        tensordict.set(
            K.PRED_TRAJ,
            self.predict(
                hist,
                tensordict.get(K.LEADERS_AHEAD),
                tensordict.get(K.NEIGHBORS_MASK)[..., :3].bool(),
                tensordict.get(K.PRED_PRIOR_TRAJ),
                z,
            ),
        )
        return tensordict
