"""``LCGANPredictor``: the lane-change prior ``P_lcGAN = G(Z, C)`` at RL time (paper Eq. 16)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import Tensor

from kddrl_trl import keys as K
from kddrl_trl.generative.gan_inputs import lane_change_condition

from ..checkpoint import CheckpointError
from ..predictor import GANPredictor
from .model import KIND, NUM_ACTIONS, LCGenerator, condition_size


class LCGANPredictor(GANPredictor):
    """Frozen lcGAN generator as a TensorDict module: the raw observation -> ``keys.PRIOR_P_LCGAN``.

    Reads ``keys.EGO_STATE`` ``[*B, 3]`` (y, v_y longitudinal, v_x lateral; S_AV uses v = ``[..., 1]``,
    lateral speed = ``[..., 2]``), ``keys.EGO_LANE`` ``[*B, 1]``, ``keys.NEIGHBORS_REL`` ``[*B, 6, 4]``,
    ``keys.NEIGHBORS_MASK`` ``[*B, 6]``, ``keys.EGO_LANE_OFFSET`` ``[*B, 1]``, ``keys.NEIGHBORS_LANE_OFFSET``
    ``[*B, 6]`` and ``keys.PRED_KEY_GAPS`` ``[*B, 3, 2]`` (trajGAN key gaps); the
    condition is built by :func:`~kddrl_trl.generative.gan_inputs.lane_change_condition`, as for the training samples.
    Writes ``keys.PRIOR_P_LCGAN`` ``[*B, 3]``: a valid simplex over (left, keep, right), exactly 0 on directions
    without a lane. All environments go through ONE generator call, without gradients, on the net's device
    (inputs are moved there, the output back); the noise is one draw per call, or the mean of ``draws``
    draws (:meth:`noise`; the rest of the interface is :class:`~kddrl_trl.generative.predictor.GANPredictor`'s).

    Args:
        generator: a trained :class:`LCGenerator` (with its normalisation buffers).
        num_lanes: lanes of the road (left possible where lane < num_lanes - 1).
        seed: seed of the noise generator.
        draws: noise draws averaged per call.
    """

    kind = KIND
    in_keys = [
        K.EGO_STATE,
        K.EGO_LANE,
        K.NEIGHBORS_REL,
        K.NEIGHBORS_MASK,
        K.EGO_LANE_OFFSET,  # noqa: RUF012
        K.NEIGHBORS_LANE_OFFSET,
        K.PRED_KEY_GAPS,
    ]
    out_keys = [K.PRIOR_P_LCGAN]  # noqa: RUF012

    def __init__(self, generator: LCGenerator, num_lanes: int = 3, seed: int = 0, draws: int = 1):
        super().__init__(generator, seed, draws)
        self.num_lanes = int(num_lanes)

    @classmethod
    def build_net(cls, architecture: Mapping[str, Any]) -> LCGenerator:
        return LCGenerator(int(architecture["noise_dim"]), int(architecture["hidden"]), int(architecture["layers"]))

    @classmethod
    def check_architecture(cls, path: str | Path, architecture: Mapping[str, Any]) -> None:
        if architecture.get("condition_size") != condition_size() or architecture.get("actions") != list(K.LC_ACTIONS):
            raise CheckpointError(f"{path} was trained with another condition layout ({dict(architecture)})")

    def predict(
        self,
        state: Tensor,
        lane: Tensor,
        rel: Tensor,
        mask: Tensor,
        offset: Tensor,
        nb_offset: Tensor,
        gaps: Tensor,
        z: Tensor,
    ) -> Tensor:
        """Eq. 16 as a pure tensor function on ``[*B, ...]`` observations (see the class doc for the shapes)
        with ``z`` = :meth:`noise` of ``prod(B)`` rows -> ``P_lcGAN`` ``[*B, 3]`` on the device of ``state``."""
        batch, out_dev = state.shape[:-1], state.device
        n, dev = batch.numel(), self.device()
        state = state.reshape(n, 3).to(dev, torch.float32)
        fields = lane_change_condition(
            state[:, 1],
            state[:, 2],
            lane.reshape(n).to(dev),
            offset.reshape(n).to(dev),
            rel.reshape(n, 6, 4).to(dev),
            mask.reshape(n, 6).to(dev),
            nb_offset.reshape(n, 6).to(dev),
            gaps.reshape(n, 3, 2).to(dev),
        )
        c, avail = self.net.condition(**fields, num_lanes=self.num_lanes)
        k = z.shape[0]
        p = self.net(c.expand(k, n, c.shape[-1]), z, avail.expand(k, n, NUM_ACTIONS)).mean(0)
        return p.reshape(*batch, NUM_ACTIONS).to(out_dev)

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        state = tensordict.get(K.EGO_STATE)
        z = self.noise(state.shape[:-1].numel())
        p = self.predict(
            state,
            tensordict.get(K.EGO_LANE),
            tensordict.get(K.NEIGHBORS_REL),
            tensordict.get(K.NEIGHBORS_MASK),
            tensordict.get(K.EGO_LANE_OFFSET),
            tensordict.get(K.NEIGHBORS_LANE_OFFSET),
            tensordict.get(K.PRED_KEY_GAPS),
            z,
        )
        tensordict.set(K.PRIOR_P_LCGAN, p)
        return tensordict
