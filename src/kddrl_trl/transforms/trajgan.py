"""``TrajGANPrediction``: trajGAN-refined leader trajectories TG and their key-step gaps (Eq. 13, Eq. 24)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
from tensordict.nn import TensorDictModuleBase

from .. import keys as K
from .frozen_predictor import FrozenPredictorTransform
from .key_gaps import KEY_STEPS, key_step_gaps
from .predictive import finite_or_zero, unbounded_spec


class TrajGANPrediction(FrozenPredictorTransform):
    """``TG^T = G(Z^T, TC^T)`` (paper Eq. 13) -> ``keys.PRED_TRAJ`` ``[*B, 3, T]``, and the key-step gaps
    ``y_lv^pre`` of Eq. 24 -> ``keys.PRED_KEY_GAPS`` ``[*B, 3, 2]`` (Algorithm 1 lines 16-17).

    Wraps the frozen :class:`~kddrl_trl.generative.TrajGANPredictor` (default: the shipped weights, or
    ``checkpoint``), or any TensorDict module ``predictor`` that reads the raw leader keys plus
    ``PRED_PRIOR_TRAJ`` (written by :class:`IDMPrior` before it) and writes ``PRED_TRAJ``. The generator runs
    once per call for all environments x 3 leaders, under ``no_grad`` with ``requires_grad=False`` weights.

    Key gaps = TG at steps 10 and 20 (indices 9 and 19) minus the ego position ``EGO_STATE[..., 0]``; zero for
    absent leaders (``NEIGHBORS_MASK[..., :3]`` False). Absent leaders' TG is what the predictor gives them
    (the shipped one: the prior, i.e. zeros); never NaN.

    Noise: ``reduce="sample"`` uses one draw per leader, ``"mean"`` the mean of ``num_samples`` draws. The
    draws come from the predictor's own ``torch.Generator`` seeded with ``seed``: two transforms built with the
    same seed give the same outputs for the same sequence of calls. The generator is a stream over calls, not
    per-environment state, so resets (full or partial) never touch it; :meth:`reseed` restarts it. Loading,
    freezing, noise and reseeding: :class:`~kddrl_trl.transforms.frozen_predictor.FrozenPredictorTransform`.

    Args:
        predictor: a TensorDict module with out key ``PRED_TRAJ`` (exclusive with ``checkpoint``).
        checkpoint: trajGAN checkpoint path (default: the weights shipped with the package).
        num_samples, reduce, seed: noise options of the default predictor (see above).
        device: device of the default predictor (inputs are moved there and outputs back).
        key_steps: 1-based key steps of Eq. 24.
    """

    kind, out_key, rows_per_env = "trajgan", K.PRED_TRAJ, 3  # one noise row per leader a, b, c

    def __init__(
        self,
        predictor: TensorDictModuleBase | None = None,
        *,
        checkpoint: str | Path | None = None,
        num_samples: int = 1,
        reduce: str = "sample",
        seed: int = 0,
        device: str | torch.device = "cpu",
        key_steps: Sequence[int] = KEY_STEPS,
    ):
        super().__init__(
            predictor,
            checkpoint=checkpoint,
            seed=seed,
            device=device,
            options={"num_samples": num_samples, "reduce": reduce},
            in_keys=[K.NEIGHBORS_MASK],
            out_keys=[K.PRED_TRAJ, K.PRED_KEY_GAPS],
        )
        self.horizon = int(getattr(self.predictor, "horizon", 20))
        self.key_steps = tuple(int(s) for s in key_steps)

    def predict_inputs(self, values) -> tuple:
        return (
            values[K.LEADERS_HISTORY],
            values[K.LEADERS_AHEAD],
            values[K.NEIGHBORS_MASK][..., :3].bool(),
            values[K.PRED_PRIOR_TRAJ],
        )

    def frame(self, values, noise=None) -> dict:
        traj = finite_or_zero(self.prediction(values, noise).to(torch.float32))
        present = values[K.NEIGHBORS_MASK][..., :3].bool()
        return {
            K.PRED_TRAJ: traj,
            K.PRED_KEY_GAPS: key_step_gaps(traj, values[K.EGO_STATE][..., 0], present, self.key_steps),
        }

    def out_specs(self, batch, device) -> dict:
        return {
            K.PRED_TRAJ: unbounded_spec(batch, (3, self.horizon), device),
            K.PRED_KEY_GAPS: unbounded_spec(batch, (3, len(self.key_steps)), device),
        }

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(predictor={type(self.predictor).__name__}, horizon={self.horizon}, "
            f"key_steps={self.key_steps})"
        )
