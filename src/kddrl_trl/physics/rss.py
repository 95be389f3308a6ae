"""Responsibility-Sensitive Safety (Shalev-Shwartz, Shammah, Shashua 2017), batched in torch: the safe
longitudinal distance between two cars in one lane (its Definition 1), the largest acceleration command that keeps
it (the worst-case safety layer's longitudinal bound, ``algo.shield=rss``), and the gap check a lane change must
pass before it starts. Not part of the KDDRL paper.

Conventions as in :mod:`kddrl_trl.physics.idm`: speeds in m/s, accelerations in m/s² (decelerations positive),
gaps bumper to bumper in m. The reference implementation is Intel's ``ad-rss`` (its
``calculateSafeLongitudinalDistanceSameDirection``); ``tests/physics/test_rss.py`` checks these functions against it
on random states, and that no contact ever happens under the bound in a 1-D car-following model whose leader brakes
within the assumptions.

The worst case (:class:`RSSParams`): every other car may brake at up to SUMO's ``emergencyDecel`` (9 m/s², above
the braking scenario's 8), the ego brakes at least at its command's lower bound (5 m/s², Eq. 31), and it responds
after one frame (0.1 s), during which its own command holds.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .. import keys as K

Num = float | Tensor


@dataclass(frozen=True)
class RSSParams:
    """The worst case the layer assumes (each field a float or a per-car tensor).

    Attributes:
        response: s, the ego's response time: one frame, during which its command holds.
        ego_brake: m/s², the braking the ego can always apply after it (Eq. 31's lower bound, -5).
        other_brake: m/s², the hardest braking of any other car (SUMO's ``emergencyDecel``, 9).
        other_response: s, a follower's response time in the lane-change check (a SUMO driver acts every frame).
        other_accel: m/s², a follower's largest acceleration during its response (the drivers' largest ``accel``).
        other_brake_min: m/s², the braking a follower applies at least once it responds (the drivers' smallest
            comfortable ``decel``, 3).
        margin: m, the gap kept beyond the safe distance (absorbs the simulator's discrete steps).
        horizon: m, the sensing range: where a watched lane shows no car, a standing one may wait just beyond it.
    """

    response: Num = 0.1
    ego_brake: Num = 5.0
    other_brake: Num = 9.0
    other_response: Num = 0.1
    other_accel: Num = 5.0
    other_brake_min: Num = 3.0
    margin: Num = 1.0
    horizon: Num = 200.0


def safe_distance(
    v_rear: Tensor, v_front: Tensor, response: Num, accel_max: Num, brake_min: Num, brake_max: Num
) -> Tensor:
    """RSS Definition 1: the smallest gap at which the rear car, accelerating at up to ``accel_max`` for
    ``response`` seconds and then braking at least at ``brake_min``, stops behind a front car that brakes at up to
    ``brake_max`` from now:
    ``[v_r ρ + a ρ²/2 + (v_r + a ρ)² / (2 b_min) - v_f² / (2 b_max)]_+``."""
    ahead = v_rear + accel_max * response
    d = v_rear * response + 0.5 * accel_max * response**2 + ahead**2 / (2.0 * brake_min)
    return (d - v_front**2 / (2.0 * brake_max)).clamp(min=0.0)


def longitudinal_bound(v: Tensor, v_lead: Tensor, gap: Tensor, p: RSSParams, low: float, high: float) -> Tensor:
    """The largest command ``a`` in ``[low, high]`` for which ``gap - margin`` still holds the safe distance
    (:func:`safe_distance` with ``a`` as the rear car's acceleration during its response, before its clamp at 0, so
    the margin holds against a faster leader too): the command after which the ego can still stop behind a leader
    that brakes at ``other_brake`` from now.

    With ``u = v + a ρ`` (the speed after the response) the distance is ``ρ (v + u) / 2 + u² / (2 B) - D_lead``,
    increasing in ``u`` for ``u >= 0``; its root is closed-form. Where no ``u >= 0`` keeps the gap (the leader
    already too close), the bound is ``low``: the proper response, braking as hard as the ego can."""
    rho, brake = p.response, p.ego_brake
    room = gap - p.margin + v_lead**2 / (2.0 * p.other_brake)
    # u² / (2B) + (ρ/2) u + (ρ v / 2 - room) = 0, the larger root
    disc = (0.5 * rho) ** 2 - 2.0 * (0.5 * rho * v - room) / brake
    u = brake * (-0.5 * rho + disc.clamp(min=0.0).sqrt())
    a = (u - v) / rho
    a = torch.where((disc < 0) | (u < 0), torch.full_like(a, low), a)
    return a.clamp(low, high)


def lane_change_safe(
    v: Tensor,
    gap_lead: Tensor,
    v_lead: Tensor,
    gap_follow: Tensor,
    v_follow: Tensor,
    p: RSSParams,
    lead_present: Tensor | None = None,
    follow_present: Tensor | None = None,
) -> Tensor:
    """Whether a lane change may start into a gap: the new leader is at least its safe distance ahead of the ego
    (the ego as the rear car, accelerating at up to 0 during its response: it keeps its speed while it steers), and
    the ego at least the new follower's safe distance ahead of it (the follower as the rear car, with its own
    response, acceleration and braking; the ego as the front car braking at up to ``ego_brake``), each with the
    ``margin``. A missing car (``*_present`` False) constrains nothing."""
    ok_lead = gap_lead - p.margin >= safe_distance(v, v_lead, p.response, 0.0, p.ego_brake, p.other_brake)
    ok_follow = gap_follow - p.margin >= safe_distance(
        v_follow, v, p.other_response, p.other_accel, p.other_brake_min, p.ego_brake
    )
    if lead_present is not None:
        ok_lead = ok_lead | ~lead_present.bool()
    if follow_present is not None:
        ok_follow = ok_follow | ~follow_present.bool()
    return ok_lead & ok_follow


def watched_leaders(
    ego: Tensor, kin: Tensor, mask: Tensor, active: Tensor, length: float
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The leaders a car-following bound must watch, from raw observation tensors (``keys.EGO_STATE``,
    ``NEIGHBORS_KIN``, ``NEIGHBORS_MASK``, ``LC_ACTIVE``; batch dims ``[*B]``): the current lane's (slot b) always,
    and during a lane change the target lane's (a while moving left, c while moving right, from the sign of the
    lateral speed). Returns ``(gap, speed, watched, present)``, each ``[*B, 3]`` over slots a, b, c: bumper-to-bumper
    gaps (m), the leaders' speeds (m/s), which slots are watched, and which watched slots hold a car."""
    ego, kin, mask = ego.to(torch.float32), kin.to(torch.float32), mask.bool()
    y, vx = ego[..., 0:1], ego[..., 2:3]
    leaders = kin[..., :3, :]
    gap = leaders[..., 0] - y - length
    active = active.bool().reshape(vx.shape)
    watched = torch.ones_like(mask[..., :3])
    watched[..., 0:1] = active & (vx > 0)
    watched[..., 2:3] = active & (vx < 0)
    return gap, leaders[..., 1], watched, mask[..., :3] & watched


def lane_safe(ego: Tensor, kin: Tensor, mask: Tensor, p: RSSParams, length: float) -> Tensor:
    """``[*B, 3]`` over ``keys.LC_ACTIONS`` (left, keep, right): :func:`lane_change_safe` for a lane change to each
    side, the new leader a (c) and follower d (f) read from raw observation tensors (``EGO_STATE``,
    ``NEIGHBORS_KIN``, ``NEIGHBORS_MASK``); keep is always True."""
    y, v = ego[..., 0:1].to(torch.float32), ego[..., 1:2].to(torch.float32)
    kin, present = kin.to(torch.float32), mask.bool()
    out = []
    for leader, follower in ((K.SLOT["a"], K.SLOT["d"]), (None, None), (K.SLOT["c"], K.SLOT["f"])):
        if leader is None:
            out.append(torch.ones_like(v, dtype=torch.bool))
            continue
        lead, follow = kin[..., leader, :], kin[..., follower, :]
        out.append(
            lane_change_safe(
                v,
                lead[..., 0:1] - y - length,
                lead[..., 1:2],
                y - follow[..., 0:1] - length,
                follow[..., 1:2],
                p,
                lead_present=present[..., leader : leader + 1],
                follow_present=present[..., follower : follower + 1],
            )
        )
    return torch.cat(out, dim=-1)


def follower_safe(ego: Tensor, kin: Tensor, mask: Tensor, p: RSSParams, length: float) -> Tensor:
    """``[*B]``: the current lane's follower (slot e) is at least its safe distance behind the ego (the follower as
    the rear car, as in :func:`lane_change_safe`), or there is none."""
    y, v = ego[..., 0].to(torch.float32), ego[..., 1].to(torch.float32)
    follow = kin[..., K.SLOT["e"], :].to(torch.float32)
    need = safe_distance(follow[..., 1], v, p.other_response, p.other_accel, p.other_brake_min, p.ego_brake)
    return (y - follow[..., 0] - length - p.margin >= need) | ~mask[..., K.SLOT["e"]].bool()
