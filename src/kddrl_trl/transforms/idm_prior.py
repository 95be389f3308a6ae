"""``IDMPrior``: the physics prior trajectory TC of leaders a, b, c (paper Eq. 11-12, input of Eq. 13)."""

from __future__ import annotations

from collections.abc import Mapping

import torch

from .. import keys as K
from ..physics import IDMParams, idm_rollout
from .predictive import PredictiveTransform, as_params, finite_or_zero, unbounded_spec


def as_idm_params(idm: IDMParams | Mapping | None) -> IDMParams:
    """``IDMParams`` from an ``IDMParams``, a mapping of its fields (Hydra config) or None (Table A.1)."""
    return as_params(IDMParams, idm)


def prior_trajectory(
    kin: torch.Tensor, mask: torch.Tensor, ahead: torch.Tensor, steps: int, dt: float, idm: IDMParams
) -> torch.Tensor:
    """IDM prior positions ``[*B, 3, steps]`` of leaders a, b, c from raw observation tensors (zeros where absent)."""
    kin = kin[..., :3, :2].to(torch.float32)
    ahead = ahead.to(torch.float32)
    present = mask[..., :3].bool() & torch.isfinite(kin).all(-1)
    has_ahead = present & (ahead[..., 2] > 0.5) & torch.isfinite(ahead[..., :2]).all(-1)
    zero = torch.zeros_like(kin[..., 0])
    y0 = torch.where(present, kin[..., 0], zero)
    v0 = torch.where(present, kin[..., 1], zero)
    y_a = torch.where(has_ahead, ahead[..., 0], zero)
    v_a = torch.where(has_ahead, ahead[..., 1], zero)
    traj = idm_rollout(y0, v0, y_a, v_a, has_ahead, steps=steps, dt=dt, params=idm).to(torch.float32)
    traj = torch.where(present.unsqueeze(-1), traj, torch.zeros_like(traj))
    return finite_or_zero(traj)


class IDMPrior(PredictiveTransform):
    """IDM rollout of the three leaders -> ``keys.PRED_PRIOR_TRAJ`` ``[*B, 3, steps]`` (paper Eq. 11-12).

    Algorithm 1 line 15 ("compute IDM initial trajectory TC^T"). Each leader a, b, c starts from its current
    position and speed (``NEIGHBORS_KIN[..., :3, :2]``) and follows, by the IDM of Eq. 11-12, the vehicle ahead
    of it (``LEADERS_AHEAD``: y, v, present), which keeps a constant speed; no vehicle ahead = free road.
    Integration: :func:`kddrl_trl.physics.idm_rollout` (semi-implicit Euler, ``steps`` of ``dt`` s; default
    20 x 0.1 s = the 2 s horizon of trajGAN). Output: absolute positions (m) at steps 1..steps.

    Absent leaders (``NEIGHBORS_MASK[..., :3]`` False, or non-finite kinematics) get zeros, never NaN.

    Args:
        idm: IDM parameters (default Table A.1); an :class:`IDMParams` or a mapping of its fields.
        steps: horizon in frames.
        dt: frame length (s).

    Examples:
        >>> from kddrl_trl.envs import FakeHighwayEnv
        >>> from torchrl.envs import TransformedEnv
        >>> env = TransformedEnv(FakeHighwayEnv(num_roads=4), IDMPrior())
        >>> env.reset()["pred", "prior_traj"].shape
        torch.Size([4, 3, 20])
    """

    def __init__(self, idm: IDMParams | Mapping | None = None, steps: int = 20, dt: float = 0.1):
        self.idm = as_idm_params(idm)
        self.steps, self.dt = int(steps), float(dt)
        super().__init__(in_keys=[K.NEIGHBORS_KIN, K.NEIGHBORS_MASK, K.LEADERS_AHEAD], out_keys=[K.PRED_PRIOR_TRAJ])

    def frame(self, values, noise=None) -> dict:
        traj = prior_trajectory(
            values[K.NEIGHBORS_KIN],
            values[K.NEIGHBORS_MASK],
            values[K.LEADERS_AHEAD],
            steps=self.steps,
            dt=self.dt,
            idm=self.idm,
        )
        return {K.PRED_PRIOR_TRAJ: traj}

    def out_specs(self, batch, device) -> dict:
        return {K.PRED_PRIOR_TRAJ: unbounded_spec(batch, (3, self.steps), device)}

    def __repr__(self) -> str:
        return f"{type(self).__name__}(steps={self.steps}, dt={self.dt}, idm={self.idm})"
