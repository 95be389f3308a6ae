"""``LCGANPrior``: the data-driven lane-change prior P_lcGAN (paper Eq. 16, Algorithm 1 line 18)."""

from __future__ import annotations

from pathlib import Path

import torch
from tensordict.nn import TensorDictModuleBase

from .. import keys as K
from .frozen_predictor import FrozenPredictorTransform
from .predictive import finite_or_zero, probability_spec


class LCGANPrior(FrozenPredictorTransform):
    """``P_lcGAN^t = G(Z^t, C^t)`` (paper Eq. 16) -> ``keys.PRIOR_P_LCGAN`` ``[*B, 3]`` over (left, keep, right).

    Wraps the frozen :class:`~kddrl_trl.generative.LCGANPredictor` (default: the shipped weights, or
    ``checkpoint``), or any TensorDict module ``predictor`` writing ``PRIOR_P_LCGAN``. The condition
    ``C^t = {S_AV, S_SV, y_lv^pre}`` is read from the raw observation (``EGO_STATE``, ``EGO_LANE``,
    ``NEIGHBORS_REL``, ``NEIGHBORS_MASK``, ``EGO_LANE_OFFSET``, ``NEIGHBORS_LANE_OFFSET``) and the key-step gaps
    ``PRED_KEY_GAPS`` written by the transform before it (:class:`TrajGANPrediction`, or :class:`KeyGapsFromPrior` in
    the stacks without trajGAN). One generator call for all environments, under ``no_grad`` with
    ``requires_grad=False`` weights.

    Noise: ``draws`` noise draws averaged per call (1 = one sample), from the predictor's own
    ``torch.Generator`` seeded with ``seed`` (a stream over calls, untouched by resets; :meth:`reseed`
    restarts it). Impossible directions (no lane) are exactly 0. Loading, freezing, noise and reseeding:
    :class:`~kddrl_trl.transforms.frozen_predictor.FrozenPredictorTransform`.

    Args:
        predictor: a TensorDict module with out key ``PRIOR_P_LCGAN`` (exclusive with ``checkpoint``).
        checkpoint: lcGAN checkpoint path (default: the weights shipped with the package).
        num_lanes: lanes of the road.
        draws, seed: noise options of the default predictor.
        device: device of the default predictor (inputs are moved there and outputs back).
    """

    kind, out_key = "lcgan", K.PRIOR_P_LCGAN

    def __init__(
        self,
        predictor: TensorDictModuleBase | None = None,
        *,
        checkpoint: str | Path | None = None,
        num_lanes: int = 3,
        draws: int = 1,
        seed: int = 0,
        device: str | torch.device = "cpu",
    ):
        super().__init__(
            predictor,
            checkpoint=checkpoint,
            seed=seed,
            device=device,
            options={"num_lanes": int(num_lanes), "draws": int(draws)},
            in_keys=[],
            out_keys=[K.PRIOR_P_LCGAN],
        )

    def predict_inputs(self, values) -> tuple:
        return tuple(
            values[k]
            for k in (
                K.EGO_STATE,
                K.EGO_LANE,
                K.NEIGHBORS_REL,
                K.NEIGHBORS_MASK,
                K.EGO_LANE_OFFSET,
                K.NEIGHBORS_LANE_OFFSET,
                K.PRED_KEY_GAPS,
            )
        )

    def frame(self, values, noise=None) -> dict:
        return {K.PRIOR_P_LCGAN: finite_or_zero(self.prediction(values, noise).to(torch.float32)).clamp(0.0, 1.0)}

    def out_specs(self, batch, device) -> dict:
        return {K.PRIOR_P_LCGAN: probability_spec(batch, (3,), device)}
