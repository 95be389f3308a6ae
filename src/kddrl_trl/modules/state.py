"""State builders of the two agents: s_D3QN (paper Eq. 24) and s_TD3 (paper Eq. 30), as TensorDict modules.

Both states start with the same block, built from the raw keys of the environment and scaled by the fixed
factors of :class:`StateScale` (so that raw SI values — positions of hundreds of metres — do not dominate
the features in [-1, 1] produced by the embedding):

========  =====================================================  ========================================
features  content                                                scaling
========  =====================================================  ========================================
3         s_AV = (y_AV, v_AV,y, v_AV,x) from ``keys.EGO_STATE``  y / position, v_y / speed, v_x / lat. speed
24        Δs_i = (Δx, Δy, Δv_x, Δv_y) of a..f, flattened slot     Δx / lat. position, Δy / position,
          by slot from ``keys.NEIGHBORS_REL``; absent slots = 0   Δv_x / lat. speed, Δv_y / speed
6         presence of a..f from ``keys.NEIGHBORS_MASK``           0 / 1
d         s_e from ``keys.EMBED_S_E`` (only when ``embed``)       none (tanh output, already in [-1, 1])
6         MOBIL criteria (only ``lc_state(mobil=True)``,          U / accel, flags 0 / 1
          ``algo=peng``): utilities U_left, U_keep, U_right
          (``keys.MOBIL_INCENTIVE``, Eq. 21-22) and safety flags
          (``keys.MOBIL_SAFE``, Eq. 20-21)
========  =====================================================  ========================================

``cf_state`` (Eq. 30) appends the held lane-change action a_D3QN^t (``keys.LC_ACTION``, one-hot, 3) and
the acceleration executed in the last frame a_TD3^{t-1} (``keys.EGO_ACCEL`` / accel, 1). Every scaled
feature is clipped to ±``StateScale.clip``.

State extras (the option ``algo.state_extras``, **not in the paper**; none by default): appended last to the
state of every agent of every learner (both hierarchical agents, the unified agents' ``keys.JOINT_OBS``), in the order
of :data:`STATE_EXTRAS`, one feature each, computed by :func:`headway_features` from the raw keys the states already
read (the current-lane leader, slot b: its gap ``Δy - vehicle_length`` bumper to bumper, its speed difference Δv_y),
so no key is added and the replay buffers are unchanged:

========  =====================================================  ========================================
``thw``   time headway gap / v_AV,y (s), capped at               / ``StateScale.time``, in [0, clip]
          ``time x clip`` = 10 s; the cap with no leader or the
          ego standing
``ttc``   time to collision gap / (v_AV,y - v_b) while closing   / ``StateScale.time``, in [0, clip]
          in (s), capped at 10 s; the cap when not closing in or
          with no leader
========  =====================================================  ========================================

Executed, not commanded: Eq. 30 reads "the continuous acceleration action executed at the previous
time step", and Algorithm 1 line 33 executes a_TD3 in the env. The env executes the command (already within
[-5, 5] m/s², Eq. 31) except where v + a dt would fall below 0 (v' = max(v + a dt, 0)), so the two differ only at
a standstill; with a car-following shield (``algo.shield``) the executed acceleration is the shielded command,
which is also the action buffer L stores, so state and action stay consistent. No option: the text is explicit.

The mask is included although Eq. 24 does not list it: an absent neighbour is written as zeros, which would
otherwise be indistinguishable from a neighbour level with the ego at the same speed.

``detach_s_e=True`` builds the state from a detached ``s_e`` (no gradient reaches the embedding through it);
see :mod:`kddrl_trl.modules.sharing` for when that is needed.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torch import nn

from .. import keys as K
from ..choices import STATE_EXTRAS, check_extras

#: size of the common block [s_AV (3), Δs_i (24), mask (6)]
BASE_DIM = 3 + 6 * 4 + 6


@dataclass(frozen=True)
class StateScale:
    """Fixed input scales of the agent states (SI units per unit of feature).

    Longitudinal values use fixed round scales (positions 100 m, speeds 50 m/s, accelerations 5 m/s² =
    the action bound of Eq. 31). Lateral values are small on a 3-lane road (offsets within ±2 lanes of
    3.2 m, lateral speeds ~1.6 m/s during a 2 s lane change), so they get their own scales — 10 m and
    5 m/s — instead of being squashed to ~0.03 by the longitudinal ones.
    """

    position: float = 100.0  # m, longitudinal y_AV and Δy
    speed: float = 50.0  # m/s, longitudinal v_y and Δv_y
    lateral_position: float = 10.0  # m, Δx
    lateral_speed: float = 5.0  # m/s, v_x and Δv_x
    accel: float = 5.0  # m/s², a_TD3^{t-1}
    time: float = 2.0  # s, the state extras thw / ttc (capped at time x clip = 10 s)
    vehicle_length: float = 5.0  # m, leader length in the extras' bumper-to-bumper gap (HighwayConfig default)
    clip: float = 5.0  # every scaled feature is clipped to ±clip

    @property
    def ego_units(self) -> tuple[float, float, float]:
        """Units of ``keys.EGO_STATE``'s features (y, v_y, v_x)."""
        return (self.position, self.speed, self.lateral_speed)

    @property
    def rel_units(self) -> tuple[float, float, float, float]:
        """Units of one slot of ``keys.NEIGHBORS_REL`` (REL_FEATURES order: Δx lateral, Δy, Δv_x lateral, Δv_y)."""
        return (self.lateral_position, self.position, self.lateral_speed, self.speed)


def headway_features(
    ego: torch.Tensor, rel: torch.Tensor, mask: torch.Tensor, extras=STATE_EXTRAS, scale: StateScale = StateScale()
) -> torch.Tensor:
    """The state extras ``[*B, len(extras)]`` (an option, not in the paper; module docstring): the time
    headway ``gap / v`` and the time to collision ``gap / (v - v_lead)`` to the current-lane leader (slot b), each
    capped at ``scale.time * scale.clip`` seconds (the cap when there is no leader, when the ego stands (thw) or is not
    closing in (ttc); 0 when the vehicles overlap) and divided by ``scale.time``.

    ``ego``: ``keys.EGO_STATE`` ``[*B, 3]``; ``rel``: ``keys.NEIGHBORS_REL`` ``[*B, 6, 4]``; ``mask``:
    ``keys.NEIGHBORS_MASK`` ``[*B, 6]``.

    Examples:
        >>> import torch
        >>> rel = torch.zeros(6, 4); rel[1, 1], rel[1, 3] = 35.0, -5.0   # leader 35 m ahead (30 m gap), 5 m/s slower
        >>> headway_features(torch.tensor([0.0, 20.0, 0.0]), rel, torch.ones(6, dtype=torch.bool))
        tensor([0.7500, 3.0000])
    """
    cap = scale.time * scale.clip
    lead = rel[..., 1, :]
    gap = (lead[..., 1:2] - scale.vehicle_length).clamp(min=0.0)
    v, closing = ego[..., 1:2], -lead[..., 3:4]
    big = torch.full_like(gap, cap)
    thw = torch.where(v > 0, gap / v.clamp(min=1e-6), big)
    ttc = torch.where(closing > 0, gap / closing.clamp(min=1e-6), big)
    present = mask[..., 1:2].bool()
    values = {"thw": thw, "ttc": ttc}
    out = [torch.where(present, values[e], big).clamp(max=cap) / scale.time for e in check_extras(extras)]
    return torch.cat(out, dim=-1) if out else ego[..., :0]


#: size of the MOBIL criteria block of ``lc_state(mobil=True)``: 3 utilities, 3 safety flags
MOBIL_DIM = 3 + 3


def lc_obs_dim(embed_dim: int = 0, mobil: bool = False, extras=()) -> int:
    """Size of ``keys.LC_OBS`` (Eq. 24) for an embedding of ``embed_dim`` (0 = no ``s_e``), with the MOBIL
    criteria of Peng et al. when ``mobil`` and the state ``extras`` (:data:`STATE_EXTRAS`)."""
    return BASE_DIM + embed_dim + (MOBIL_DIM if mobil else 0) + len(check_extras(extras))


def cf_obs_dim(embed_dim: int = 0, extras=()) -> int:
    """Size of ``keys.CF_OBS`` (Eq. 30) for an embedding of ``embed_dim`` (0 = no ``s_e``), with the state
    ``extras`` (:data:`STATE_EXTRAS`); also the size of ``keys.JOINT_OBS`` with ``embed_dim`` 0."""
    return BASE_DIM + embed_dim + 3 + 1 + len(check_extras(extras))


class _StateNet(nn.Module):
    """Concatenates the scaled state features; the input order is that of the builder's ``in_keys``."""

    def __init__(self, scale: StateScale, embed: bool, detach_s_e: bool, actions: bool, mobil: bool = False, extras=()):
        super().__init__()
        self.scale, self.embed, self.detach_s_e, self.actions, self.mobil = scale, embed, detach_s_e, actions, mobil
        self.extras = check_extras(extras)
        s = scale
        self.register_buffer("ego_scale", torch.tensor(s.ego_units), persistent=False)
        self.register_buffer("rel_scale", torch.tensor(s.rel_units), persistent=False)

    def forward(self, ego: torch.Tensor, rel: torch.Tensor, mask: torch.Tensor, *rest: torch.Tensor) -> torch.Tensor:
        c = self.scale.clip
        present, rel_raw = mask.to(rel.dtype), rel
        rel = torch.where(mask.bool().unsqueeze(-1), rel / self.rel_scale, rel.new_zeros(()))
        parts = [(ego / self.ego_scale).clamp(-c, c), rel.clamp(-c, c).flatten(-2), present]
        rest = list(rest)
        if self.embed:
            s_e = rest.pop(0)
            parts.append(s_e.detach() if self.detach_s_e else s_e)
        if self.mobil:
            incentive, safe = rest.pop(0), rest.pop(0)
            parts.append((incentive.to(ego.dtype) / self.scale.accel).clamp(-c, c))
            parts.append(safe.to(ego.dtype))
        if self.actions:
            lc_action, accel = rest
            parts.append(lc_action.to(ego.dtype))
            parts.append((accel.to(ego.dtype) / self.scale.accel).clamp(-c, c))
        if self.extras:
            parts.append(headway_features(ego, rel_raw, mask, self.extras, self.scale).clamp(-c, c))
        return torch.cat(parts, dim=-1)


def lc_state(
    embed: bool = True,
    *,
    mobil: bool = False,
    detach_s_e: bool = False,
    scale: StateScale = StateScale(),
    out_key: NestedKey = K.LC_OBS,
    extras=(),
) -> TensorDictModule:
    """D3QN state ``s_D3QN = [s_AV, Δs_i, s_e]`` — paper Eq. 24 — as a TensorDict module.

    Reads ``keys.EGO_STATE`` ``[*B, 3]``, ``keys.NEIGHBORS_REL`` ``[*B, 6, 4]``, ``keys.NEIGHBORS_MASK``
    ``[*B, 6]`` and, when ``embed``, ``keys.EMBED_S_E`` ``[*B, d]``; writes ``out_key`` ``[*B, 33 + d]``
    (layout and scaling in the module docstring; ``d = 0`` without ``s_e``).

    Args:
        embed (bool): include ``s_e``; ``False`` for the pure D3QN+TD3 state. Defaults to ``True``.

    Keyword Args:
        mobil (bool): append MOBIL's safety-efficiency criteria (``keys.MOBIL_INCENTIVE``, ``keys.MOBIL_SAFE``,
            written by :class:`~kddrl_trl.transforms.MOBILCriteria`): the lane-change state of Peng et al. (2022).
            Defaults to ``False``.
        detach_s_e (bool): use ``s_e.detach()``. Defaults to ``False`` (the D3QN TD loss trains the
            embedding, see :mod:`kddrl_trl.modules.sharing`).
        scale (StateScale): input scales. Defaults to ``StateScale()``.
        out_key (NestedKey): defaults to ``keys.LC_OBS``.
        extras (tuple of str): state extras of :data:`STATE_EXTRAS` appended last (``algo.state_extras``,
            not in the paper). Defaults to none.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from kddrl_trl import keys as K
        >>> from kddrl_trl.modules import lc_state
        >>> td = TensorDict({K.EGO_STATE: torch.tensor([200.0, 30.0, 0.0]), K.NEIGHBORS_REL: torch.zeros(6, 4),
        ...                  K.NEIGHBORS_MASK: torch.zeros(6, dtype=torch.bool)}, [])
        >>> lc_state(embed=False)(td)[K.LC_OBS][:3]
        tensor([2.0000, 0.6000, 0.0000])
    """
    in_keys = (
        [K.EGO_STATE, K.NEIGHBORS_REL, K.NEIGHBORS_MASK]
        + ([K.EMBED_S_E] if embed else [])
        + ([K.MOBIL_INCENTIVE, K.MOBIL_SAFE] if mobil else [])
    )
    return TensorDictModule(
        _StateNet(scale, embed, detach_s_e, actions=False, mobil=mobil, extras=extras),
        in_keys=in_keys,
        out_keys=[out_key],
    )


def cf_state(
    embed: bool = True,
    *,
    detach_s_e: bool = False,
    scale: StateScale = StateScale(),
    out_key: NestedKey = K.CF_OBS,
    lc_action_key: NestedKey = K.LC_ACTION,
    extras=(),
) -> TensorDictModule:
    """TD3 state ``s_TD3 = [s_AV, Δs_i, s_e, a_D3QN^t, a_TD3^{t-1}]`` — paper Eq. 30 — as a TensorDict module.

    Reads the inputs of :func:`lc_state` plus ``keys.LC_ACTION`` ``[*B, 3]`` (the held one-hot lane-change
    action) and ``keys.EGO_ACCEL`` ``[*B, 1]`` (acceleration executed in the last frame, m/s²); writes
    ``out_key`` ``[*B, 37 + d]``.

    Args:
        embed (bool): include ``s_e``. Defaults to ``True``.

    Keyword Args:
        detach_s_e (bool): use ``s_e.detach()``. Defaults to ``False``: the TD3 critic loss trains the
            embedding; the actor loss must not — pass the batch through
            :func:`kddrl_trl.modules.sharing.detach_embedding` before ``TD3Loss.actor_loss`` (or build a
            separate actor state with ``detach_s_e=True``).
        scale (StateScale): input scales. Defaults to ``StateScale()``.
        out_key (NestedKey): defaults to ``keys.CF_OBS``.
        lc_action_key (NestedKey): the lane-change action read. Defaults to ``keys.LC_ACTION`` (the command in
            force now); the unified agents, which choose both actions at once, read ``keys.LC_HELD`` (the command
            of the previous frame) into ``keys.JOINT_OBS``.
        extras (tuple of str): state extras of :data:`STATE_EXTRAS` appended last (``algo.state_extras``,
            not in the paper). Defaults to none.
    """
    in_keys = (
        [K.EGO_STATE, K.NEIGHBORS_REL, K.NEIGHBORS_MASK]
        + ([K.EMBED_S_E] if embed else [])
        + [lc_action_key, K.EGO_ACCEL]
    )
    return TensorDictModule(
        _StateNet(scale, embed, detach_s_e, actions=True, extras=extras), in_keys=in_keys, out_keys=[out_key]
    )
