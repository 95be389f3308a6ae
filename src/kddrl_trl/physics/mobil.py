"""MOBIL lane-change model (paper Eq. 20-22, Kesting et al. 2007), batched in torch.

Neighbour slots follow ``kddrl_trl.keys``: a, b, c, d, e, f = left leader, current leader, right leader,
left follower, current follower, right follower; outputs are ordered (left, keep, right). Lane 0 is the
rightmost lane, so "left" means ``lane + 1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from kddrl_trl.keys import KEEP, LEFT, RIGHT
from kddrl_trl.physics.idm import IDMParams, idm_acceleration

Num = float | Tensor


@dataclass(frozen=True)
class MOBILParams:
    """MOBIL parameters, paper Table A.1.

    Attributes:
        politeness: politeness factor ``p`` of Eq. 21 (-).
        threshold: lane-change threshold ``Δa_th`` of Eq. 21-22 (m/s²).
        b_safe: maximum safe deceleration imposed on the new follower, ``a_TF_new > -b_safe`` (m/s²).
        y_safe: minimum safe bumper-to-bumper gap of Eq. 20 (m). The paper leaves its value open; we take
            the IDM jam gap ``s0`` = 5 m.
    """

    politeness: Num = 0.1
    threshold: Num = 0.3
    b_safe: Num = 4.0
    y_safe: Num = 5.0


def mobil_utilities(
    ego_y: Tensor,
    ego_v: Tensor,
    kin: Tensor,
    mask: Tensor,
    lane: Tensor,
    num_lanes: int = 3,
    idm: IDMParams = IDMParams(),
    mobil: MOBILParams = MOBILParams(),
) -> tuple[Tensor, Tensor]:
    """MOBIL utilities ``U_d`` (paper Eq. 21) and safety flags (Eq. 20 and ``a_TF_new > -b_safe``).

    Args:
        ego_y, ego_v: ego front-bumper position (m) and speed (m/s), shape ``[...]``.
        kin: ``[..., 6, 3]`` absolute position, speed, acceleration of slots a..f.
        mask: ``[..., 6]`` bool, slot occupied.
        lane: ``[...]`` integer ego lane, 0 = rightmost.

    For a change to the target lane with leader TL and follower TF (left: a, d; right: c, f)::

        U_d = (a_AV_new - a_AV_old) + p [(a_CF_new - a_CF_old) + (a_TF_new - a_TF_old)]

    with AV = ego (old: behind b, new: behind TL), CF = current follower e (old: behind ego, new: behind b)
    and TF (old: behind TL, new: behind ego). An absent follower contributes 0; an absent leader means free
    road. A direction is safe when the target lane exists, the bumper-to-bumper gaps to TL and TF (where
    present) exceed ``y_safe`` and ``a_TF_new > -b_safe``.

    ``U_keep`` (Eq. 22) is "a preset baseline utility ... calculated by inferring the acceleration of AV and
    its following vehicle through the IDM in the current lane", required > 0. Our reading:
    ``U_keep = max(threshold, a_AV_old + p a_CF_old)``. ``safe[..., KEEP]`` is always True.

    Returns:
        ``U`` ``[..., 3]`` and ``safe`` ``[..., 3]`` (bool), both ordered (left, keep, right).
    """
    ego_y = torch.as_tensor(ego_y, dtype=kin.dtype, device=kin.device)
    ego_v = torch.as_tensor(ego_v, dtype=kin.dtype, device=kin.device)
    mask = mask.bool()
    lane = torch.as_tensor(lane, device=kin.device)
    kin = torch.where(mask.unsqueeze(-1), kin, torch.zeros_like(kin))  # absent slots: no garbage
    L, p = idm.length, mobil.politeness
    y, v = kin[..., 0], kin[..., 1]
    ego_y, ego_v = torch.broadcast_tensors(ego_y, ego_v)
    ego_y, ego_v = ego_y.expand(y.shape[:-1]), ego_v.expand(y.shape[:-1])
    true = torch.ones_like(mask[..., 0])
    ya, yb, yc, yd, ye, yf = y.unbind(-1)
    va, vb, vc, vd, ve, vf = v.unbind(-1)
    ma, mb, mc, md, me, mf = mask.unbind(-1)
    # every IDM evaluation MOBIL needs, in one batched call: (follower y, v; leader y, v; leader present)
    pairs = [
        (ego_y, ego_v, yb, vb, mb),  # 0 a_AV_old: ego behind b
        (ye, ve, ego_y, ego_v, true),  # 1 a_CF_old: e behind ego
        (ye, ve, yb, vb, mb),  # 2 a_CF_new: e behind b
        (ego_y, ego_v, ya, va, ma),  # 3 left:  a_AV_new, ego behind a
        (yd, vd, ya, va, ma),  # 4 left:  a_TF_old, d behind a
        (yd, vd, ego_y, ego_v, true),  # 5 left:  a_TF_new, d behind ego
        (ego_y, ego_v, yc, vc, mc),  # 6 right: a_AV_new, ego behind c
        (yf, vf, yc, vc, mc),  # 7 right: a_TF_old, f behind c
        (yf, vf, ego_y, ego_v, true),  # 8 right: a_TF_new, f behind ego
    ]
    y_f, v_f, y_l, v_l, m_l = (torch.stack(col, dim=-1) for col in zip(*pairs))
    gap = y_l - y_f - L
    acc = idm_acceleration(v_f, v_l, gap, idm, has_leader=m_l)
    a_av_old, a_cf_old, a_cf_new = acc[..., 0], acc[..., 1], acc[..., 2]
    zero = torch.zeros_like(a_av_old)
    d_cf = torch.where(me, a_cf_new - a_cf_old, zero)

    def direction(i: int, ml: Tensor, mf: Tensor, lane_ok: Tensor) -> tuple[Tensor, Tensor]:
        a_av_new, a_tf_old, a_tf_new = acc[..., i], acc[..., i + 1], acc[..., i + 2]
        gap_l, gap_f = gap[..., i], gap[..., i + 2]
        d_tf = torch.where(mf, a_tf_new - a_tf_old, zero)
        u = (a_av_new - a_av_old) + p * (d_cf + d_tf)
        safe = lane_ok & (~ml | (gap_l > mobil.y_safe)) & (~mf | ((gap_f > mobil.y_safe) & (a_tf_new > -mobil.b_safe)))
        return u, safe

    u_left, safe_left = direction(3, ma, md, lane < num_lanes - 1)
    u_right, safe_right = direction(6, mc, mf, lane > 0)
    keep_raw = a_av_old + p * torch.where(me, a_cf_old, zero)
    u_keep = torch.maximum(keep_raw, torch.as_tensor(mobil.threshold, dtype=kin.dtype, device=kin.device))
    u_left, u_keep, u_right = torch.broadcast_tensors(u_left, u_keep, u_right)
    safe_left, safe_right = torch.broadcast_tensors(safe_left, safe_right)
    U = torch.stack([u_left, u_keep, u_right], dim=-1)
    safe = torch.stack([safe_left, torch.ones_like(safe_left), safe_right], dim=-1)
    return U, safe


def mobil_prior(
    ego_y: Tensor,
    ego_v: Tensor,
    kin: Tensor,
    mask: Tensor,
    lane: Tensor,
    num_lanes: int = 3,
    idm: IDMParams = IDMParams(),
    mobil: MOBILParams = MOBILParams(),
) -> Tensor:
    """Knowledge-driven lane-change prior ``P_MOBIL`` over (left, keep, right), paper Eq. 22.

    Same inputs as :func:`mobil_utilities`. A direction d in {left, right} scores ``max(0, U_d)`` only where
    it is safe (Eq. 20-21) and ``U_d > threshold``, else 0; keep scores ``U_keep > 0``. Probabilities are
    score / sum of scores, with ``p_keep = 1 - p_left - p_right``. Always a valid simplex, never NaN.

    Returns:
        ``[..., 3]`` probabilities ordered (left, keep, right).
    """
    U, safe = mobil_utilities(ego_y, ego_v, kin, mask, lane, num_lanes, idm, mobil)
    ok = safe & (U > mobil.threshold)
    score = torch.where(ok, U.clamp(min=0.0), torch.zeros_like(U))
    keep = U[..., KEEP].clamp(min=1e-6)  # > 0 already (threshold > 0); guard against threshold <= 0
    total = score[..., LEFT] + score[..., RIGHT] + keep
    p_left, p_right = score[..., LEFT] / total, score[..., RIGHT] / total
    p_keep = (1.0 - p_left - p_right).clamp(min=0.0)  # clamp: float rounding when U_d >> U_keep
    return torch.stack([p_left, p_keep, p_right], dim=-1)
