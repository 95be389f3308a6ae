"""Key-step gaps ``y_lv^pre`` of the leaders (paper §III.B last paragraph, Eq. 24, Algorithm 1 line 17)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from .. import keys as K
from ..generative.gan_inputs import KEY_STEPS
from .predictive import PredictiveTransform, finite_or_zero, unbounded_spec


def key_step_gaps(traj: Tensor, ego_y: Tensor, present: Tensor, key_steps: Sequence[int] = KEY_STEPS) -> Tensor:
    """``y_lv,i^pre = [TG_i^{t10} - y_AV^t, TG_i^{t20} - y_AV^t]`` (paper Eq. 24), batched.

    Args:
        traj: ``[*B, 3, T]`` absolute predicted positions of leaders a, b, c at steps 1..T (m).
        ego_y: ``[*B]`` current ego position ``y_AV^t`` (m).
        present: ``[*B, 3]`` bool, leader present; absent leaders get 0 (never NaN).
        key_steps: 1-based steps to read (default 10 and 20: indices 9 and 19).

    Returns:
        ``[*B, 3, len(key_steps)]`` float32 gaps (m).
    """
    idx = [int(s) - 1 for s in key_steps]
    if max(idx) >= traj.shape[-1] or min(idx) < 0:
        raise ValueError(f"key steps {tuple(key_steps)} do not fit a horizon of {traj.shape[-1]} steps")
    gaps = traj[..., idx].to(torch.float32) - ego_y.to(torch.float32)[..., None, None]
    gaps = torch.where(present.bool().unsqueeze(-1), gaps, torch.zeros_like(gaps))
    return finite_or_zero(gaps)


class KeyGapsFromPrior(PredictiveTransform):
    """``keys.PRED_KEY_GAPS`` ``[*B, 3, 2]`` from the IDM prior ``PRED_PRIOR_TRAJ`` instead of trajGAN (Eq. 24).

    This is what the stacks *without trajGAN* use (``make_kddrl_transforms(trajgan=False)``; with
    ``priors=True`` it is the paper's "D3QN+TD3+LG" ablation row, ``algo=d3qn_td3_lg``): the key-step gaps of
    Eq. 24 are computed from the physics prior TC (Eq. 11-12) in place of the refined TG (Eq. 13), so that
    lcGAN (conditioned on key gaps, Eq. 16) and the shared embedding (Eq. 24) still get their input.
    Gap = prior position at step 10 / 20 minus the ego position ``EGO_STATE[..., 0]``; 0 for absent leaders.
    """

    def __init__(self, key_steps: Sequence[int] = KEY_STEPS):
        super().__init__(in_keys=[K.PRED_PRIOR_TRAJ, K.EGO_STATE, K.NEIGHBORS_MASK], out_keys=[K.PRED_KEY_GAPS])
        self.key_steps = tuple(int(s) for s in key_steps)

    def frame(self, values, noise=None) -> dict:
        gaps = key_step_gaps(
            values[K.PRED_PRIOR_TRAJ], values[K.EGO_STATE][..., 0], values[K.NEIGHBORS_MASK][..., :3], self.key_steps
        )
        return {K.PRED_KEY_GAPS: gaps}

    def out_specs(self, batch, device) -> dict:
        return {K.PRED_KEY_GAPS: unbounded_spec(batch, (3, len(self.key_steps)), device)}
