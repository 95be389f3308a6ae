"""``RSSLaneMask``: the lateral half of the worst-case safety layer (``algo.shield=rss``; not in the paper).

A lane change starts only into a gap that Responsibility-Sensitive Safety calls safe for both new neighbours
(:func:`kddrl_trl.physics.rss.lane_safe`): the target lane's leader at least its safe distance ahead of the ego,
and the ego at least the target lane's follower's safe distance ahead of it, under the layer's worst case
(:class:`~kddrl_trl.physics.rss.RSSParams`). The transform rewrites the env's command mask (``keys.LC_ACTION_MASK``)
as ``mask & safe``, as :class:`~kddrl_trl.transforms.MOBILSafetyMask` does with MOBIL's check, so the lane agent
picks among the safe commands when it acts and when its target is computed (keep is always allowed): an unsafe
command is replaced by the best safe one, keep-lane at worst.

A manoeuvre under way (``lc_duration``, 2 s) is not undone when its gap closes: the env runs it to its end, as
SUMO does. During it the longitudinal layer (:class:`~kddrl_trl.transforms.SafetyShield` ``kind="rss"``) keeps the
safe distance to the leaders of both lanes; a follower that closes in on the ego in the target lane after the
manoeuvre started is that follower's to answer under RSS (its proper response is to brake), which the collision
classes of the evaluation record.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torchrl.data import Categorical

from .. import keys as K
from ..physics.rss import RSSParams, lane_safe
from .predictive import PredictiveTransform


class RSSLaneMask(PredictiveTransform):
    """``keys.LC_ACTION_MASK`` AND the RSS gap check of each side (module docstring).

    Args:
        rss: the worst case (:class:`~kddrl_trl.physics.rss.RSSParams`, or a mapping of its fields).
        length: m, the vehicles' length (front-bumper positions to bumper-to-bumper gaps).
    """

    def __init__(self, rss: RSSParams | Mapping | None = None, length: float = 5.0):
        super().__init__(
            in_keys=[K.EGO_STATE, K.NEIGHBORS_KIN, K.NEIGHBORS_MASK, K.LC_ACTION_MASK], out_keys=[K.LC_ACTION_MASK]
        )
        self.rss = rss if isinstance(rss, RSSParams) else RSSParams(**dict(rss or {}))
        self.length = float(length)

    def frame(self, values, noise=None) -> dict:
        safe = lane_safe(values[K.EGO_STATE], values[K.NEIGHBORS_KIN], values[K.NEIGHBORS_MASK], self.rss, self.length)
        return {K.LC_ACTION_MASK: values[K.LC_ACTION_MASK].bool() & safe}

    def out_specs(self, batch, device) -> dict:
        return {K.LC_ACTION_MASK: Categorical(2, shape=(*batch, 3), dtype=torch.bool, device=device)}
