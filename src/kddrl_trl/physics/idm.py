"""Intelligent Driver Model (paper Eq. 11-12, Treiber et al. 2000), batched in torch.

Positions are longitudinal FRONT-bumper positions (m), so the bumper-to-bumper gap between a follower and
its leader is ``y_leader - y_follower - length``. Speeds in m/s, accelerations in m/s², time in s.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

#: smallest bumper-to-bumper gap (m) fed to the interaction term; keeps ``s*/gap`` finite at zero or
#: negative gaps (overlap), where IDM then returns a very strong but finite deceleration.
MIN_GAP = 0.1

Num = float | Tensor


@dataclass(frozen=True)
class IDMParams:
    """IDM parameters, paper Table A.1. Each field may be a float or a tensor (per-vehicle, broadcasting).

    Attributes:
        v0: desired speed (m/s), 130 km/h.
        T: desired time headway (s).
        s0: desired minimum (jam) gap (m).
        a_max: maximum acceleration (m/s²).
        b: comfortable deceleration (m/s², positive).
        delta: acceleration exponent (-).
        length: vehicle length (m), used to turn front-bumper positions into bumper-to-bumper gaps.
    """

    v0: Num = 130 / 3.6
    T: Num = 1.5
    s0: Num = 5.0
    a_max: Num = 5.0
    b: Num = 4.0
    delta: Num = 4.0
    length: Num = 5.0


def idm_acceleration(
    v: Tensor,
    v_lead: Tensor | float,
    gap: Tensor | float,
    params: IDMParams = IDMParams(),
    has_leader: Tensor | None = None,
) -> Tensor:
    """IDM acceleration, paper Eq. 11-12 (batched, all arguments broadcast).

    ``a = a_max [1 - (v/v0)^delta - (s*/gap)^2]`` with
    ``s* = s0 + max(0, v T + v (v - v_lead) / (2 sqrt(a_max b)))``.

    The approach-rate term uses ``v - v_lead`` (follower minus leader, positive when closing in) as in
    Treiber's IDM and SUMO; Eq. 12 as printed has the opposite sign, which we read as a typo. The dynamic
    part of ``s*`` is clipped at 0 (Treiber's book / SUMO) so a much faster leader cannot produce braking.
    ``v`` is clipped at 0 inside the free-road term. ``gap`` (bumper-to-bumper, m) is clamped to
    ``MIN_GAP`` so the result is always finite. Where ``has_leader`` (bool) is False the interaction term
    is dropped (free road) and ``v_lead``/``gap`` there are ignored.

    Returns:
        acceleration (m/s²) with the broadcast shape of all inputs and parameters.
    """
    v = torch.as_tensor(v, dtype=torch.get_default_dtype())
    v_lead = torch.as_tensor(v_lead, dtype=v.dtype, device=v.device)
    gap = torch.as_tensor(gap, dtype=v.dtype, device=v.device)
    p = params
    free = 1.0 - (v.clamp(min=0.0) / p.v0) ** p.delta
    if has_leader is not None:
        has_leader = torch.as_tensor(has_leader, device=v.device).bool()
        # neutral values where absent so garbage (NaN/inf) there never leaks into the result
        gap = torch.where(has_leader, gap, torch.ones_like(gap))
        v_lead = torch.where(has_leader, v_lead, torch.zeros_like(v_lead))
    dyn = v * p.T + v * (v - v_lead) / (2.0 * (p.a_max * p.b) ** 0.5)
    s_star = p.s0 + dyn.clamp(min=0.0)
    interaction = (s_star / gap.clamp(min=MIN_GAP)) ** 2
    if has_leader is not None:
        interaction = torch.where(has_leader, interaction, torch.zeros_like(interaction))
    return p.a_max * (free - interaction)


_FAR = 1e9  # m


def idm_rollout(
    y0: Tensor,
    v0: Tensor,
    y_ahead: Tensor,
    v_ahead: Tensor,
    has_ahead: Tensor,
    steps: int = 20,
    dt: float = 0.1,
    params: IDMParams = IDMParams(),
) -> Tensor:
    """IDM prior trajectory of a leader (``TC^T`` of paper Eq. 13, built from Eq. 11-12).

    The leader (position ``y0``, speed ``v0``) follows its own leader, "the vehicle ahead" (``y_ahead``,
    ``v_ahead``, presence ``has_ahead``), which is assumed to keep a constant speed. Integration is
    semi-implicit (symplectic) Euler as in SUMO: ``v' = max(v + a dt, 0)``, ``y' = y + v' dt``.

    Returns:
        positions (m) at steps ``1..steps``, shape ``[..., steps]`` (broadcast of the inputs).
    """
    y = torch.as_tensor(y0, dtype=torch.get_default_dtype())
    v = torch.as_tensor(v0, dtype=y.dtype, device=y.device)
    y_a = torch.as_tensor(y_ahead, dtype=y.dtype, device=y.device)
    v_a = torch.as_tensor(v_ahead, dtype=y.dtype, device=y.device)
    has = torch.as_tensor(has_ahead, device=y.device).bool()
    # an absent vehicle ahead is replaced once by one far away at the leader's own speed: its interaction
    # term (s*/gap)^2 is then ~1e-14 m/s², i.e. free road, and the loop needs no masking (hot path of the
    # IDMPrior transform: 20 small steps every frame)
    y, v, y_a, v_a, has = torch.broadcast_tensors(y, v, y_a, v_a, has)
    y_a = torch.where(has, y_a, y + _FAR)
    v_a = torch.where(has, v_a, v)
    out = torch.empty((*y.shape, steps), dtype=y.dtype, device=y.device)
    for k in range(steps):
        a = idm_acceleration(v, v_a, y_a - y - params.length, params)
        v = (v + a * dt).clamp(min=0.0)
        y = y + v * dt
        y_a = y_a + v_a * dt
        out[..., k] = y
    return out
