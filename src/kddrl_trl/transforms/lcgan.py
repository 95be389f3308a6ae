"""``LCGANPrior``: the data-driven lane-change prior P_lcGAN (paper Eq. 16, Algorithm 1 line 18)."""
from __future__ import annotations

from pathlib import Path

import torch
from tensordict.nn import TensorDictModuleBase

from .. import keys as K
from ._base import PredictiveTransform, finite_or_zero, probability_spec
from ._frozen import as_tensordict, freeze, run_frozen


class LCGANPrior(PredictiveTransform):
    """``P_lcGAN^t = G(Z^t, C^t)`` (paper Eq. 16) -> ``keys.PRIOR_P_LCGAN`` ``[*B, 3]`` over (left, keep, right).

    Wraps the frozen :class:`~kddrl_trl.generative.LCGANPredictor` (default: the shipped weights, or
    ``checkpoint``), or any TensorDict module ``predictor`` writing ``PRIOR_P_LCGAN``. The condition
    ``C^t = {S_AV, S_SV, y_lv^pre}`` is read from the raw observation (``EGO_STATE``, ``EGO_LANE``,
    ``NEIGHBORS_REL``, ``NEIGHBORS_MASK``) and the key-step gaps ``PRED_KEY_GAPS`` written by the transform before
    it (:class:`TrajGANPrediction`, or :class:`KeyGapsFromPrior` in the stacks without trajGAN). One generator
    call for all environments, under ``no_grad`` with ``requires_grad=False`` weights.

    Noise: ``draws`` noise draws averaged per call (1 = one sample), from the predictor's own
    ``torch.Generator`` seeded with ``seed`` (a stream over calls, untouched by resets; :meth:`reseed`
    restarts it). Impossible directions (no lane) are exactly 0.

    Args:
        predictor: a TensorDict module with out key ``PRIOR_P_LCGAN`` (exclusive with ``checkpoint``).
        checkpoint: lcGAN checkpoint path (default: the weights shipped with the package).
        num_lanes: lanes of the road.
        draws, seed: noise options of the default predictor.
        device: device of the default predictor (inputs are moved there and outputs back).
        compile: ``torch.compile`` this transform's :meth:`frame` when it is called on its own (``True`` /
            ``False`` / ``"auto"``; a user's predictor module is never compiled). In a
            :class:`~kddrl_trl.transforms.PredictiveStack` the stack's own ``compile`` applies.
    """

    def __init__(self, predictor: TensorDictModuleBase | None = None, *, checkpoint: str | Path | None = None,
                 num_lanes: int = 3, draws: int = 1, seed: int = 0, device: str | torch.device = "cpu",
                 compile: bool | str = False):
        if predictor is not None and checkpoint is not None:
            raise ValueError("give either a predictor module or a checkpoint path, not both")
        from ..generative import LCGANPredictor, load_predictor

        if predictor is None:
            predictor = load_predictor("lcgan", checkpoint, num_lanes=int(num_lanes), seed=int(seed),
                                       draws=int(draws), device=device)
        if K.PRIOR_P_LCGAN not in [tuple(k) if isinstance(k, (tuple, list)) else k for k in predictor.out_keys]:
            raise ValueError(f"the lcGAN predictor must write {K.PRIOR_P_LCGAN}, it writes {predictor.out_keys}")
        self.seed = int(getattr(predictor, "seed", seed))
        super().__init__(in_keys=list(predictor.in_keys), out_keys=[K.PRIOR_P_LCGAN], compile=compile,
                         pure=isinstance(predictor, LCGANPredictor))
        self.predictor = freeze(predictor)

    def reseed(self, seed: int | None = None) -> None:
        """Restart the predictor's noise stream (with ``seed``, or the constructor's)."""
        seed = self.seed if seed is None else int(seed)
        if hasattr(self.predictor, "reset"):
            self.predictor.reset(seed)
        elif isinstance(getattr(self.predictor, "rng", None), torch.Generator):
            self.predictor.rng.manual_seed(seed)

    def noise(self, batch: torch.Size) -> torch.Tensor | None:
        """The shipped predictor's noise for ``batch`` (a user's module draws its own)."""
        return self.predictor.noise(batch.numel()) if self.pure else None

    def frame(self, values, noise=None) -> dict:
        if self.pure:
            p = self.predictor.predict(values[K.EGO_STATE], values[K.EGO_LANE], values[K.NEIGHBORS_REL],
                                       values[K.NEIGHBORS_MASK], values[K.PRED_KEY_GAPS], noise)
        else:
            p = run_frozen(self.predictor, as_tensordict(values, values[K.EGO_STATE].shape[:-1]), K.PRIOR_P_LCGAN)
        return {K.PRIOR_P_LCGAN: finite_or_zero(p.to(torch.float32)).clamp(0.0, 1.0)}

    def out_specs(self, batch, device) -> dict:
        return {K.PRIOR_P_LCGAN: probability_spec(batch, (3,), device)}

    def __repr__(self) -> str:
        return f"{type(self).__name__}(predictor={type(self.predictor).__name__})"
