"""``SafetyShield``: a car-following safety shield for any policy, ``a_exec = min(a_agent, a_safe)`` (not in the paper).

Not part of the paper (its TD3 acts unshielded, §III.G.2); an option of every algo (``algo.shield``), off by
default. The bound ``a_safe`` comes from the raw keys of the frame the action is taken in:

* ``idm``: the braking (interaction) part of the IDM, Eq. 11-12 with ``v0 = inf`` (so the shield never caps the
  free-road speed): ``a_safe = a_max [1 - (s*/gap)^2]``, Table A.1 parameters;
* ``ttc``: when the time to collision ``gap / (v - v_lead)`` is below ``ttc`` seconds, the constant deceleration
  that brings the closing speed to zero before the gap shrinks to ``min_gap`` (plus the leader's own braking):
  ``a_safe = min(a_lead, 0) - (v - v_lead)^2 / (2 (gap - min_gap))``; no bound otherwise;
* ``rss``: the worst-case bound of Responsibility-Sensitive Safety (:func:`kddrl_trl.physics.rss.longitudinal_bound`):
  the largest command after which, one frame later, the ego can still stop behind a leader that brakes at up to
  9 m/s² from now (:class:`~kddrl_trl.physics.rss.RSSParams`); where the lane it must watch shows no car, a standing
  one is assumed just beyond the sensing range (``horizon``), which bounds the ego's speed to what it can stop
  from within it (about 160 km/h at 200 m). Its lateral half, the gap check before a lane change
  starts, is :class:`~kddrl_trl.transforms.rss_lane_mask.RSSLaneMask`.

The leaders checked are the current lane's (slot b) and, during a lane change, the target lane's (a to the left,
c to the right, from the sign of the lateral speed).

Where the executed action is recorded: the inverse path (``_inv_call``) replaces ``("cf", "action")`` in what the
env receives (TorchRL's ``inv`` works on a copy of the step's root, which keeps the agent's command); the post-step
hook (TorchRL's ``_post_step_mdp_hooks``, run by ``step_and_maybe_reset``: collectors,
:func:`~kddrl_trl.eval.evaluate_policy`, ``rollout``) writes the executed action into the recorded frame, so buffer
L stores ``(s, a_exec, r, s')``: the transition that really happened. TorchRL runs no hook on a bare ``env.step``
(nor on the last frame of ``env.rollout(..., break_when_any_done=False)``): there the frame keeps the agent's
command, and ``("next", "cf", "shield")`` still says the shield acted. Inside a ``ParallelEnv`` worker (its
TensorDicts are locked shared buffers) the executed action is written in place, and the outer env is sure to
receive the flag (its frame may keep the agent's command). Each frame carries
``("next", "cf", "shield")`` (``keys.CF_SHIELD``): True when the shield lowered the command, which the episode
tracker counts (``shield_interventions``, ``shield_rate``).

``record="command"`` (``algo.shield_buffer=command``) leaves the agent's own command in the recorded frame: buffer L
then stores ``(s, a_agent, r, s')``, the shield being part of the env the agent acts in. That is the transition the
correction signal (``penalty``) speaks of: with the executed action in the buffer, the critic never sees the command
the penalty was for, and cannot teach the actor to keep within the bound.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase
from torchrl.data import Categorical, Composite
from torchrl.envs.transforms import Transform

from .. import keys as K
from ..physics import IDMParams, idm_acceleration
from ..physics.rss import RSSParams, longitudinal_bound, watched_leaders

#: ``algo.shield`` kinds this transform implements (``none`` adds no transform)
SHIELD_KINDS = ("idm", "ttc", "rss")
#: what the recorded frame holds as the car-following action (``algo.shield_buffer``)
SHIELD_RECORDS = ("executed", "command")
_FLAG = "_shield_intervened"  # carries the intervention flag from the inverse path to ``_step``
_CORRECTION = "_shield_correction"  # and the correction a_agent - a_exec (m/s², >= 0), for ``penalty``


def ttc_bound(
    v: torch.Tensor,
    v_lead: torch.Tensor,
    a_lead: torch.Tensor,
    gap: torch.Tensor,
    ttc: float,
    min_gap: float,
    no_bound: float,
) -> torch.Tensor:
    """The ``ttc`` shield's bound (m/s²): while closing in with ``gap / (v - v_lead) < ttc``, the deceleration that
    cancels the closing speed within ``gap - min_gap`` (plus the leader's braking); ``no_bound`` otherwise."""
    closing = (v - v_lead).clamp(min=0.0)
    room = (gap - min_gap).clamp(min=0.1)
    need = torch.minimum(a_lead, torch.zeros_like(a_lead)) - closing**2 / (2.0 * room)
    risky = (closing > 0) & (gap < ttc * closing)
    return torch.where(risky, need, torch.full_like(need, no_bound))


def safe_acceleration(
    obs: TensorDictBase,
    kind: str,
    *,
    idm: IDMParams,
    ttc: float,
    min_gap: float,
    high: float,
    low: float = -5.0,
    rss: RSSParams | None = None,
) -> torch.Tensor:
    """``a_safe`` ``[*B, 1]`` (m/s², at most ``high``) of shield ``kind`` from the raw keys of ``obs``."""
    v = obs.get(K.EGO_STATE).to(torch.float32)[..., 1:2]
    active = obs.get(K.LC_ACTIVE, torch.zeros_like(v, dtype=torch.bool))
    gap, speed, watched, present = watched_leaders(
        obs.get(K.EGO_STATE), obs.get(K.NEIGHBORS_KIN), obs.get(K.NEIGHBORS_MASK), active, idm.length
    )
    if kind == "idm":
        bound = idm_acceleration(v, speed, gap, idm, has_leader=present).clamp(max=high)
    elif kind == "rss":  # a lane it must watch and sees no car in: a standing one may wait past the sensing range
        p = rss or RSSParams()
        unseen = watched & ~present
        gap = torch.where(unseen, torch.full_like(gap, p.horizon - idm.length), gap)
        speed = torch.where(unseen, torch.zeros_like(gap), speed)
        bound = longitudinal_bound(v, speed, gap, p, low, high)
        present = watched
    else:
        accel = obs.get(K.NEIGHBORS_KIN).to(torch.float32)[..., :3, 2]
        bound = ttc_bound(v, speed, accel, gap, ttc, min_gap, high)
    bound = torch.where(present, bound, torch.full_like(bound, high))
    return bound.amin(-1, keepdim=True)


class SafetyShield(Transform):
    """``a_exec = min(a_agent, a_safe)`` on ``keys.CF_ACTION`` before the env; the executed action recorded.

    Args:
        kind: ``"idm"`` or ``"ttc"`` (module docstring).
        low, high: the action bounds (m/s², Eq. 31); the executed action stays within them.
        ttc: s, the ``ttc`` shield's threshold. Defaults to 3 s.
        min_gap: m, the gap the ``ttc`` shield keeps. Defaults to 2 m.
        idm: IDM parameters of the ``idm`` shield (default Table A.1; ``v0`` is ignored: always ``inf``).
        rss: the worst case of the ``rss`` shield (default :class:`~kddrl_trl.physics.rss.RSSParams`).
        record: what the recorded frame holds as ``keys.CF_ACTION``: ``"executed"`` (default, the transition that
            happened) or ``"command"`` (the agent's own; module docstring).
        penalty: per m/s², the correction signal (``algo.shield_penalty``; not in the paper): the car-following
            reward of each frame (``keys.CF_REWARD``, Eq. 32) loses ``penalty * (a_agent - a_exec)``, so the learner
            is told how far the shield moved its command, not only overridden. 0 (default) leaves the reward as
            the env wrote it. The episode's ``return_cf`` then sums the penalised reward: what the learner got.
    """

    def __init__(
        self,
        kind: str,
        *,
        low: float = -5.0,
        high: float = 5.0,
        ttc: float = 3.0,
        min_gap: float = 2.0,
        idm: IDMParams | None = None,
        rss: RSSParams | None = None,
        penalty: float = 0.0,
        record: str = "executed",
    ):
        if kind not in SHIELD_KINDS:
            raise ValueError(f"SafetyShield: kind must be one of {', '.join(SHIELD_KINDS)}, got {kind!r}")
        super().__init__(in_keys=[], out_keys=[K.CF_SHIELD], in_keys_inv=[K.CF_ACTION], out_keys_inv=[K.CF_ACTION])
        self.kind, self.low, self.high = kind, float(low), float(high)
        self.ttc, self.min_gap = float(ttc), float(min_gap)
        base = idm if idm is not None else IDMParams()
        self.idm = IDMParams(**{**base.__dict__, "v0": math.inf})
        self.rss = rss if rss is not None else RSSParams()
        if not penalty >= 0:
            raise ValueError(f"SafetyShield: penalty must be >= 0 (reward per m/s² of correction), got {penalty!r}")
        self.penalty = float(penalty)
        if record not in SHIELD_RECORDS:
            raise ValueError(f"SafetyShield: record must be one of {', '.join(SHIELD_RECORDS)}, got {record!r}")
        self.record = record

    def shielded(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """(executed action, intervened) ``[*B, 1]`` for the command and raw keys at the root of ``tensordict``."""
        action = tensordict.get(K.CF_ACTION)
        bound = (
            safe_acceleration(
                tensordict,
                self.kind,
                idm=self.idm,
                ttc=self.ttc,
                min_gap=self.min_gap,
                high=self.high,
                low=self.low,
                rss=self.rss,
            )
            .to(action.dtype)
            .reshape(action.shape)
        )
        executed = torch.minimum(action, bound).clamp(self.low, self.high)
        return executed, executed < action

    # ---------------------------------------------------------------------------------- TorchRL
    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        with torch.no_grad():
            executed, flag = self.shielded(tensordict)
            if self.penalty:  # the agent's command within the bounds, less what is executed
                command = tensordict.get(K.CF_ACTION).clamp(self.low, self.high)
                tensordict.set(_CORRECTION, (command - executed).clamp(min=0.0))
        tensordict.set(K.CF_ACTION, executed)  # what the env receives (``inv`` works on a copy of the root)
        tensordict.set(_FLAG, flag)  # read (and removed) by _step
        return tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        flag = tensordict.pop(_FLAG, None)  # TorchRL hands _step the inverse-transformed input
        if flag is None:
            flag = torch.zeros(*next_tensordict.batch_size, 1, dtype=torch.bool)
        next_tensordict.set(K.CF_SHIELD, flag.reshape(*next_tensordict.batch_size, 1).to(next_tensordict.device))
        correction = tensordict.pop(_CORRECTION, None)
        if correction is not None:
            reward = next_tensordict.get(K.CF_REWARD)
            cost = self.penalty * correction.reshape(reward.shape).to(device=reward.device, dtype=reward.dtype)
            next_tensordict.set(K.CF_REWARD, reward - cost)
        return next_tensordict

    def _post_step_mdp_hooks(self, tensordict: TensorDictBase, tensordict_: TensorDictBase):
        # the frame that is recorded holds the executed action (recomputed from its root: stateless), or keeps the
        # agent's command
        if self.record == "command":
            return tensordict, tensordict_
        with torch.no_grad():
            executed = self.shielded(tensordict)[0]
        if tensordict.get(K.CF_ACTION[:-1]).is_locked:  # a ParallelEnv worker's shared buffers: written in place
            tensordict.set_(K.CF_ACTION, executed)
        else:
            tensordict.set(K.CF_ACTION, executed)
        return tensordict, tensordict_

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tensordict_reset.set(
            K.CF_SHIELD, torch.zeros(*tensordict_reset.batch_size, 1, dtype=torch.bool, device=tensordict_reset.device)
        )
        return tensordict_reset

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:  # forward(): nothing to add to a sample
        return next_tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        b, dev = observation_spec.shape, observation_spec.device
        observation_spec[K.CF_SHIELD] = Categorical(2, shape=(*b, 1), dtype=torch.bool, device=dev)
        return observation_spec

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(kind={self.kind!r}, ttc={self.ttc}, min_gap={self.min_gap}, penalty={self.penalty})"
        )
