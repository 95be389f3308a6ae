"""Who is at fault in a collision: Responsibility-Sensitive Safety's proper response (Shalev-Shwartz, Shammah,
Shashua 2017, its Definitions 4-7: the dangerous situation, the blame time, the proper response), read frame by
frame from what the ego observed and did. Not part of the KDDRL paper; every run records it
(``collision_fault`` of :class:`~kddrl_trl.envs.episode_metrics.EpisodeTracker`).

The ego breaks its proper response in a frame when

* **longitudinally**, its executed acceleration exceeds the RSS bound toward the leaders it must watch
  (:func:`kddrl_trl.physics.rss.longitudinal_bound` over :func:`~kddrl_trl.physics.rss.watched_leaders`, the cars it
  sees: no car is assumed beyond the sensing range here, that is the layer's caution, not a duty), unless it
  already stands; where no command keeps the safe distance the bound is the hardest braking, so a car in danger
  keeps its proper response only by braking at it;
* **laterally**, a lane change starts into a gap that RSS calls unsafe for the new leader or the new follower
  (:func:`~kddrl_trl.physics.rss.lane_safe`).

A breach is held until the situation is safe again: the longitudinal one until a frame in which the ego keeps the
safe distance to every watched leader (the bound is above the hardest braking) and keeps its proper response; the
lateral one until the manoeuvre has ended and the current lane's follower is at its safe distance behind
(:func:`~kddrl_trl.physics.rss.follower_safe`). At a collision, with the other vehicle's neighbour slot:

* ``ego``: a lateral breach is held, or the other car is a leader (a, b, c) and a longitudinal breach is held: the
  ego closed in on a leader or entered an unsafe gap;
* ``other``: the ego kept its proper response: the other car is a follower (d, e, f: under RSS the rear car answers
  for the distance), or a leader that cut in or braked beyond the worst case;
* ``unknown``: the other vehicle was not a neighbour in the last observation, or the frames lack the raw keys.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .. import keys as K
from ..physics.rss import RSSParams, follower_safe, lane_safe, longitudinal_bound, watched_leaders

#: ``collision_fault`` labels (``""`` for an episode without a collision)
FAULTS = ("ego", "other", "unknown")
#: m/s², how far the executed acceleration may exceed the bound before it counts as a breach (float32 rounding)
TOLERANCE = 1e-3
#: m/s, below this speed a car that is not accelerating stands (its braking can do no more)
STANDING = 0.01


def breaches(
    ego: Tensor,
    kin: Tensor,
    mask: Tensor,
    active: Tensor,
    accel: Tensor,
    speed_after: Tensor,
    started: Tensor,
    command: Tensor,
    active_after: Tensor,
    p: RSSParams,
    length: float,
    low: float,
) -> dict[str, Tensor]:
    """Per frame ``[*B]``: the ego's breaches of its proper response and the frames that clear them.

    Args:
        ego, kin, mask, active: the observation the frame's action was taken in (``keys.EGO_STATE``,
            ``NEIGHBORS_KIN``, ``NEIGHBORS_MASK``, ``LC_ACTIVE``).
        accel: m/s², the acceleration executed in the frame (``("next", keys.EGO_ACCEL)``).
        speed_after: m/s, the ego's speed after it.
        started: a lane change started in the frame (``("next", keys.LC_STARTED)``); ``command`` its side
            (a ``keys.LC_ACTIONS`` index, the frame's lane command).
        active_after: the manoeuvre is under way after the frame (``("next", keys.LC_ACTIVE)``).
        p, length, low: the worst case, the vehicles' length (m) and the hardest braking command (m/s², Eq. 31).

    Returns ``lon``, ``lon_clear``, ``lat``, ``lat_clear`` (bool): a longitudinal breach, a frame safe along the
    lane, a lateral breach (an unsafe lane change started), a frame with no manoeuvre and a safe follower.
    """
    gap, speed, _, present = watched_leaders(ego, kin, mask, active, length)
    v = ego[..., 1:2].to(torch.float32)
    bound = longitudinal_bound(v.expand_as(gap), speed, gap, p, low, float("inf"))
    bound = torch.where(present, bound, torch.full_like(bound, float("inf"))).amin(-1)
    accel, speed_after = accel.to(torch.float32), speed_after.to(torch.float32)
    standing = (speed_after <= STANDING) & (accel <= 0)
    lon = (accel > bound + TOLERANCE) & ~standing
    in_danger = bound <= low
    side = lane_safe(ego, kin, mask, p, length).gather(-1, command.long().unsqueeze(-1)).squeeze(-1)
    lat = started.bool() & ~side
    lat_clear = ~active_after.bool() & ~started.bool() & follower_safe(ego, kin, mask, p, length)
    return {"lon": lon, "lon_clear": ~lon & ~in_danger, "lat": lat, "lat_clear": lat_clear & ~lat}


def held(breach: Tensor, clear: Tensor, carry_breach: Tensor, carry_clear: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``[B, T]``: whether a breach is held at each frame: the last breach came after the last clearing. ``breach``
    and ``clear`` hold, per frame, an increasing frame number where the frame breaches (clears) and 0 elsewhere;
    ``carry_*`` (``[B]``) the last ones of earlier batches. Returns ``(held, last breach, last clearing)`` at the
    batch's last frame (``[B]`` each, to carry)."""
    last_breach = torch.maximum(breach.cummax(1).values, carry_breach[:, None])
    last_clear = torch.maximum(clear.cummax(1).values, carry_clear[:, None])
    return last_breach > last_clear, last_breach[:, -1], last_clear[:, -1]


def fault(slot: int, lon_held: bool, lat_held: bool) -> str:
    """The class of one collision (module docstring) from the other vehicle's neighbour slot (-1: none) and the
    breaches held at the crash frame."""
    if lat_held:
        return "ego"
    if slot < 0:
        return "unknown"
    if K.NEIGHBOR_SLOTS[slot] in K.LEADER_SLOTS:
        return "ego" if lon_held else "other"
    return "other"
