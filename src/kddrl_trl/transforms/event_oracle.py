"""``EventOracleKeyGaps``: the braking event car's key gaps from its script, in place of trajGAN's (an oracle for the
braking study, not in the paper)."""

from __future__ import annotations

import torch

from .. import keys as K
from ..envs.braking import FUTURE_FRAMES
from .key_gaps import KEY_STEPS
from .predictive import PredictiveTransform, finite_or_zero, unbounded_spec


class EventOracleKeyGaps(PredictiveTransform):
    """Overwrites, in ``keys.PRED_KEY_GAPS`` ``[*B, 3, 2]`` (Eq. 24), the row of the leader that is the braking
    event's car with its true key gaps: its position 10 and 20 frames ahead as the event's script makes it
    (``keys.BRAKING_FUTURE``, written by the SUMO env, :meth:`kddrl_trl.envs.braking.BrakingEvents.scripted_future`)
    minus the ego's position now. Every other row, and a step the script does not fix (once SUMO drives the released
    car), keeps the gap of the predictor before it (trajGAN, or the IDM prior without it).

    The oracle answers one question of the braking study: would the learners crash less if they knew where the
    braking car will be? It reads the event's script, not the simulator's future: a lookahead by saving and loading
    SUMO's state does not give back the same simulation (the rollouts part at once; most likely the TraCI commands
    that hold the event car and set the egos' modes are not restored), so it would not be the future the policy meets. Reads ``BRAKING_SLOT``, ``BRAKING_FUTURE``, ``BRAKING_FUTURE_KNOWN``
    (labels, never part of the agents' state otherwise) and ``EGO_STATE``.
    """

    def __init__(self):
        if tuple(FUTURE_FRAMES) != tuple(KEY_STEPS):
            raise ValueError(f"the env's scripted future is at frames {FUTURE_FRAMES}, the key steps are {KEY_STEPS}")
        super().__init__(
            in_keys=[K.PRED_KEY_GAPS, K.BRAKING_SLOT, K.BRAKING_FUTURE, K.BRAKING_FUTURE_KNOWN, K.EGO_STATE],
            out_keys=[K.PRED_KEY_GAPS],
        )

    def frame(self, values, noise=None) -> dict:
        gaps, slot = values[K.PRED_KEY_GAPS], values[K.BRAKING_SLOT][..., 0]
        leader = torch.nn.functional.one_hot(slot.clamp(min=0), 3).bool() & (slot >= 0).unsqueeze(-1)  # [*B, 3]
        known = leader.unsqueeze(-1) & values[K.BRAKING_FUTURE_KNOWN].bool().unsqueeze(-2)  # [*B, 3, 2]
        ego_y = values[K.EGO_STATE][..., 0]
        truth = (values[K.BRAKING_FUTURE] - ego_y.unsqueeze(-1)).unsqueeze(-2).expand_as(gaps)
        return {K.PRED_KEY_GAPS: finite_or_zero(torch.where(known, truth.to(gaps.dtype), gaps))}

    def out_specs(self, batch, device) -> dict:
        return {K.PRED_KEY_GAPS: unbounded_spec(batch, (3, len(KEY_STEPS)), device)}
