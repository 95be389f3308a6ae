"""MOBIL on the ego's observation: ``MOBILPrior``, the knowledge-driven lane-change prior P_MOBIL (paper Eq. 20-22,
Algorithm 1 lines 19-20); ``MOBILSafetyMask``, MOBIL's safety check as a hard constraint on the lane-change commands
(§III.C.2); and ``MOBILCriteria``, MOBIL's safety-efficiency criteria themselves (the utilities and safety flags that
Peng et al. (2022) give their D3QN lane-change agent, ``algo=peng``)."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torchrl.data import Categorical

from .. import keys as K
from ..physics import IDMParams, MOBILParams, mobil_prior, mobil_utilities
from .idm_prior import as_idm_params
from .predictive import PredictiveTransform, as_params, finite_or_zero, probability_spec, unbounded_spec


def as_mobil_params(mobil: MOBILParams | Mapping | None) -> MOBILParams:
    """``MOBILParams`` from a ``MOBILParams``, a mapping of its fields (Hydra config) or None (Table A.1)."""
    return as_params(MOBILParams, mobil)


def _mobil_on_obs(
    fn,
    ego: torch.Tensor,
    lane: torch.Tensor,
    kin: torch.Tensor,
    mask: torch.Tensor,
    num_lanes: int,
    idm: IDMParams,
    mobil: MOBILParams,
):
    """``fn`` (:func:`mobil_prior` or :func:`mobil_utilities`) on raw observation tensors: ego y and v from
    ``EGO_STATE``, the lane from ``EGO_LANE``, neighbours with non-finite kinematics treated as absent."""
    ego, kin = ego.to(torch.float32), kin.to(torch.float32)
    mask = mask.bool() & torch.isfinite(kin).all(-1)
    return fn(ego[..., 0], ego[..., 1], kin, mask, lane[..., 0].long(), num_lanes, idm, mobil)


def mobil_prior_from_obs(
    ego: torch.Tensor,
    lane: torch.Tensor,
    kin: torch.Tensor,
    mask: torch.Tensor,
    num_lanes: int,
    idm: IDMParams,
    mobil: MOBILParams,
) -> torch.Tensor:
    """``P_MOBIL`` ``[*B, 3]`` from raw observation tensors (a simplex, never NaN)."""
    p = _mobil_on_obs(mobil_prior, ego, lane, kin, mask, num_lanes, idm, mobil)
    return finite_or_zero(p.to(torch.float32)).clamp(0.0, 1.0)


def mobil_criteria_from_obs(
    ego: torch.Tensor,
    lane: torch.Tensor,
    kin: torch.Tensor,
    mask: torch.Tensor,
    num_lanes: int,
    idm: IDMParams,
    mobil: MOBILParams,
) -> tuple[torch.Tensor, torch.Tensor]:
    """MOBIL's utilities ``U`` ``[*B, 3]`` (m/s², Eq. 21-22, never NaN) and safety flags ``[*B, 3]`` (bool, Eq. 20-21;
    False where the lane does not exist) from raw observation tensors, ordered (left, keep, right)."""
    u, safe = _mobil_on_obs(mobil_utilities, ego, lane, kin, mask, num_lanes, idm, mobil)
    return finite_or_zero(u.to(torch.float32)), safe


def mobil_safe_from_obs(
    ego: torch.Tensor,
    lane: torch.Tensor,
    kin: torch.Tensor,
    mask: torch.Tensor,
    num_lanes: int,
    idm: IDMParams,
    mobil: MOBILParams,
) -> torch.Tensor:
    """MOBIL's safety flags ``[*B, 3]`` (bool, left / keep / right) from raw observation tensors: the target lane
    exists, the gaps to its leader and follower exceed ``y_safe`` (Eq. 20) and the new follower brakes less than
    ``b_safe`` (Eq. 21, ``a_TF_new > -b_safe``); keep is always safe."""
    return mobil_criteria_from_obs(ego, lane, kin, mask, num_lanes, idm, mobil)[1]


class _MOBILOnObs(PredictiveTransform):
    """What the MOBIL transforms share: MOBIL and IDM parameters (default Table A.1; the dataclasses or mappings of
    their fields), the road's ``num_lanes``, the raw observation keys MOBIL reads (``EGO_STATE``, ``EGO_LANE``,
    ``NEIGHBORS_KIN``, ``NEIGHBORS_MASK``, then ``extra_in_keys``) and :meth:`on_obs`, one of the ``*_from_obs``
    functions above applied to a frame's values with those parameters."""

    def __init__(
        self,
        mobil: MOBILParams | Mapping | None,
        idm: IDMParams | Mapping | None,
        num_lanes: int,
        *,
        out_keys: list,
        extra_in_keys: tuple = (),
    ):
        self.mobil, self.idm, self.num_lanes = as_mobil_params(mobil), as_idm_params(idm), int(num_lanes)
        in_keys = [K.EGO_STATE, K.EGO_LANE, K.NEIGHBORS_KIN, K.NEIGHBORS_MASK, *extra_in_keys]
        super().__init__(in_keys=in_keys, out_keys=out_keys)

    def on_obs(self, fn, values):
        return fn(
            values[K.EGO_STATE],
            values[K.EGO_LANE],
            values[K.NEIGHBORS_KIN],
            values[K.NEIGHBORS_MASK],
            num_lanes=self.num_lanes,
            idm=self.idm,
            mobil=self.mobil,
        )

    def __repr__(self) -> str:
        return f"{type(self).__name__}(num_lanes={self.num_lanes}, mobil={self.mobil}, idm={self.idm})"


class MOBILPrior(_MOBILOnObs):
    """``P_MOBIL`` over (left, keep, right) -> ``keys.PRIOR_P_MOBIL`` ``[*B, 3]`` (paper Eq. 20-22).

    Safety check (Eq. 20, plus ``a_TF_new > -b_safe`` of Eq. 21), utilities ``U_d`` (Eq. 21) and their
    normalisation (Eq. 22) by :func:`kddrl_trl.physics.mobil_prior`, fed with the ego position and speed
    (``EGO_STATE[..., 0]``, ``[..., 1]``), its lane (``EGO_LANE``) and the neighbours' absolute kinematics and
    presence (``NEIGHBORS_KIN``, ``NEIGHBORS_MASK``). An unsafe direction, one below the threshold
    ``Δa_th`` or one without a lane (``num_lanes``) gets 0; the result is a simplex, never NaN. The prior is a
    physics statement about the traffic, not about the command interface: it does not read
    ``LC_ACTION_MASK`` (a lane change in progress does not change it).

    Args:
        mobil: MOBIL parameters (default Table A.1); :class:`MOBILParams` or a mapping of its fields.
        idm: IDM parameters of the accelerations MOBIL compares (default Table A.1).
        num_lanes: lanes of the road (left exists where lane < num_lanes - 1, right where lane > 0).
    """

    def __init__(
        self, mobil: MOBILParams | Mapping | None = None, idm: IDMParams | Mapping | None = None, num_lanes: int = 3
    ):
        super().__init__(mobil, idm, num_lanes, out_keys=[K.PRIOR_P_MOBIL])

    def frame(self, values, noise=None) -> dict:
        p = self.on_obs(mobil_prior_from_obs, values)
        return {K.PRIOR_P_MOBIL: p}

    def out_specs(self, batch, device) -> dict:
        return {K.PRIOR_P_MOBIL: probability_spec(batch, (3,), device)}


class MOBILSafetyMask(_MOBILOnObs):
    """MOBIL's safety check as a hard constraint: ``keys.LC_ACTION_MASK`` AND the safety flags of Eq. 20-21.

    §III.C.2: "The built-in safety checking mechanism of the MOBIL enforces hard safety distance constraints to
    prevent the RL agent from attempting dangerous lane-changing maneuvers during exploration". ``P_MOBIL``
    (:class:`MOBILPrior`) only *informs* the agent (an input of the embedding, Eq. 23); this transform makes the
    check *binding*: it rewrites the env's command mask (no lane there, or a manoeuvre in progress) as
    ``mask & safe``, where ``safe`` is :func:`kddrl_trl.physics.mobil_utilities`' flags (Eq. 20 gaps to the
    target lane's leader and follower > ``y_safe``, Eq. 21 ``a_TF_new > -b_safe``; keep is always allowed). One
    mechanism for every algo (``algo.mobil_safety_mask``), because every consumer of the mask follows it:

    * acting: the D3QN ``QValueActor`` (``action_mask_key``) and the ε-greedy module pick among the allowed
      commands only;
    * learning: buffer H stores the mask at the decision and under ``"next"``; TorchRL's ``DQNLoss`` computes the
      double-DQN argmax (Eq. 4) with the Q actor on the next state, which masks with ``("next", "lc",
      "action_mask")``; the plain DQN target's max is masked the same way.

    The env still executes any command its own mask allows: the constraint lives in the agent's command set, as
    in the paper ("prevent the RL agent from attempting"). Reads only raw keys, so it works on any env writing
    them, and needs no other transform before it.

    Args: as :class:`MOBILPrior`.
    """

    def __init__(
        self, mobil: MOBILParams | Mapping | None = None, idm: IDMParams | Mapping | None = None, num_lanes: int = 3
    ):
        super().__init__(mobil, idm, num_lanes, out_keys=[K.LC_ACTION_MASK], extra_in_keys=[K.LC_ACTION_MASK])

    def frame(self, values, noise=None) -> dict:
        safe = self.on_obs(mobil_safe_from_obs, values)
        return {K.LC_ACTION_MASK: values[K.LC_ACTION_MASK].bool() & safe}

    def out_specs(self, batch, device) -> dict:
        return {K.LC_ACTION_MASK: Categorical(2, shape=(*batch, 3), dtype=torch.bool, device=device)}


class MOBILCriteria(MOBILPrior):
    """MOBIL's safety-efficiency criteria -> ``keys.MOBIL_INCENTIVE`` ``[*B, 3]`` (utilities U_left, U_keep, U_right,
    m/s², Eq. 21-22) and ``keys.MOBIL_SAFE`` ``[*B, 3]`` (bool: the direction passes the safety criterion, Eq. 20 and
    ``a_TF_new > -b_safe``; keep is always safe, a missing lane never is).

    The lane-change state of Peng et al. (2022) (``algo=peng``, :func:`~kddrl_trl.modules.lc_state` with
    ``mobil=True``). Same inputs and parameters as :class:`MOBILPrior`, computed by the same
    :func:`kddrl_trl.physics.mobil_utilities` (MOBILPrior normalises them into P_MOBIL; this transform hands the
    agent the criteria themselves). It writes state features only: masking unsafe commands out of
    ``keys.LC_ACTION_MASK`` is :class:`MOBILSafetyMask`'s job (``algo.mobil_safety_mask``), not this transform's.
    """

    def __init__(
        self, mobil: MOBILParams | Mapping | None = None, idm: IDMParams | Mapping | None = None, num_lanes: int = 3
    ):
        super().__init__(mobil, idm, num_lanes)
        self.out_keys = [K.MOBIL_INCENTIVE, K.MOBIL_SAFE]

    def frame(self, values, noise=None) -> dict:
        u, safe = self.on_obs(mobil_criteria_from_obs, values)
        return {K.MOBIL_INCENTIVE: u, K.MOBIL_SAFE: safe}

    def out_specs(self, batch, device) -> dict:
        return {
            K.MOBIL_INCENTIVE: unbounded_spec(batch, (3,), device),
            K.MOBIL_SAFE: Categorical(2, shape=(*batch, 3), dtype=torch.bool, device=device),
        }
