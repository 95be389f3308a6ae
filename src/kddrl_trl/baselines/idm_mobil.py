"""Rule-based IDM + MOBIL ego policy (the paper's "IDM+MOBIL" baseline, Tables IV-V)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from kddrl_trl.keys import (
    CF_ACTION,
    EGO_LANE,
    EGO_STATE,
    KEEP,
    LC_ACTION,
    LC_ACTION_MASK,
    NEIGHBORS_KIN,
    NEIGHBORS_MASK,
    NEIGHBORS_REL,
)
from kddrl_trl.physics.idm import IDMParams, idm_acceleration
from kddrl_trl.physics.mobil import MOBILParams, mobil_prior


class IDMMobilPolicy(TensorDictModuleBase):
    """Ego policy: MOBIL lane choice (paper Eq. 20-22) and IDM car following (Eq. 11-12).

    Reads ``EGO_STATE`` [..., 3] (y, v_y, v_x), ``EGO_LANE`` [..., 1], ``NEIGHBORS_KIN`` [..., 6, 3],
    ``NEIGHBORS_MASK`` [..., 6] and ``LC_ACTION_MASK`` [..., 3]. Writes ``LC_ACTION``: one-hot float
    [..., 3] of the argmax of ``P_MOBIL`` over the allowed commands (keep is always allowed; ties go to
    keep), and ``CF_ACTION`` [..., 1]: IDM acceleration, clipped to [-5, 5], behind the most constraining
    leader the ego overlaps laterally (``|Δx| < lane_width``, from ``NEIGHBORS_REL``): leader b when driving
    in a lane; during a lane-change manoeuvre also the leader of the lane being entered (or left), so the
    ego does not run into the target lane's leader while it straddles two lanes.
    Works for any batch shape; no gradients.
    """

    in_keys = [EGO_STATE, EGO_LANE, NEIGHBORS_KIN, NEIGHBORS_MASK, NEIGHBORS_REL, LC_ACTION_MASK]
    out_keys = [LC_ACTION, CF_ACTION]

    def __init__(
        self,
        idm: IDMParams = IDMParams(),
        mobil: MOBILParams = MOBILParams(),
        num_lanes: int = 3,
        lane_width: float = 3.2,
    ):
        super().__init__()
        self.idm, self.mobil, self.num_lanes, self.lane_width = idm, mobil, num_lanes, lane_width

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Compute both actions from the raw observation and write them into ``tensordict``."""
        ego = tensordict.get(EGO_STATE)
        ego_y, ego_v = ego[..., 0], ego[..., 1]
        lane = tensordict.get(EGO_LANE)[..., 0]
        kin, mask = tensordict.get(NEIGHBORS_KIN), tensordict.get(NEIGHBORS_MASK).bool()
        allowed = tensordict.get(LC_ACTION_MASK).bool().clone()
        allowed[..., KEEP] = True

        prob = mobil_prior(ego_y, ego_v, kin, mask, lane, self.num_lanes, self.idm, self.mobil)
        score = prob.masked_fill(~allowed, -1.0)
        best = score.argmax(dim=-1)
        best = torch.where(score[..., KEEP] >= score.amax(dim=-1), torch.full_like(best, KEEP), best)
        lc = F.one_hot(best, 3).to(ego.dtype)

        leaders = kin[..., :3, :]  # a, b, c
        overlap = mask[..., :3] & (tensordict.get(NEIGHBORS_REL)[..., :3, 0].abs() < self.lane_width)
        gap = leaders[..., 0] - ego_y.unsqueeze(-1) - self.idm.length
        accel = idm_acceleration(ego_v.unsqueeze(-1), leaders[..., 1], gap, self.idm, has_leader=overlap)
        accel = accel.amin(dim=-1).clamp(-5.0, 5.0).unsqueeze(-1)

        tensordict.set(LC_ACTION, lc)
        tensordict.set(CF_ACTION, accel)
        return tensordict
