"""``TraceRecorder``: the kinematics of whole evaluation episodes, for space-time diagrams (paper Fig. 14) and
videos (:mod:`kddrl_trl.eval.render`), from the frames any highway env writes.

It reads only the raw keys of ``kddrl_trl.keys`` (no simulator): the ego's position, lane, speeds and
acceleration, the six neighbours' relative positions (slots a-f, where present), the lane-change start flags and
the braking phase. The ego's lateral position is its lane centre, moved by its lateral speed while a lane change
is under way (``EGO_STATE``'s ``vx``). A trace is a JSON-able dict; traces are small (a few kB per episode).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from .. import keys as K

#: per-frame keys a trace reads (root for an episode's first frame, ``"next"`` for every step)
TRACE_KEYS = (
    K.EGO_STATE,
    K.EGO_LANE,
    K.EGO_ACCEL,
    K.NEIGHBORS_REL,
    K.NEIGHBORS_MASK,
    K.LC_STARTED,
    K.LC_ACTIVE,
    K.BRAKING_PHASE,
    K.OUTCOME,
    K.COLLISION_KIND,
)


def _slot(value, r: int) -> str:
    """The neighbour slot (``keys.NEIGHBOR_SLOTS``) a slot code of row ``r`` names; ``""`` for -1 or no key."""
    if value is None:
        return ""
    code = int(value[r].reshape(-1)[0])
    return K.NEIGHBOR_SLOTS[code] if 0 <= code < len(K.NEIGHBOR_SLOTS) else ""


class TraceRecorder:
    """Records the first ``episodes`` episodes to finish on any row, going on (up to ``4 * episodes``) until it
    holds at least one episode with a lane change and one without, when the env gives both. ``collisions_only``:
    the first ``episodes`` episodes that end in a collision, and no other.

    Call it with each step's TensorDict of batch ``[B]`` (root = the observation acted on, ``"next"`` = the
    result), as :func:`~kddrl_trl.eval.evaluate_policy` does with ``trace=``. ``meta`` (e.g. scenario, algo,
    seed, lane width, number of lanes, section length, step length) is copied into each trace.
    """

    def __init__(self, episodes: int = 3, collisions_only: bool = False, **meta):
        self.episodes, self.meta, self.collisions_only = int(episodes), dict(meta), bool(collisions_only)
        self.lane_width = float(meta.get("lane_width", 3.2))
        self.dt = float(meta.get("step_length", 0.1))
        self.traces: list[dict] = []
        self._open: dict[int, dict] = {}
        self._x: dict[int, float] = {}

    @property
    def done(self) -> bool:
        if self.collisions_only:
            return len(self.traces) >= self.episodes
        with_lc = any(t["lane_changes"] for t in self.traces)
        without = any(not t["lane_changes"] for t in self.traces)
        return len(self.traces) >= 4 * self.episodes or (len(self.traces) >= self.episodes and with_lc and without)

    def frame(self, td: TensorDictBase, r: int, t: int, first: bool) -> dict:
        """Row ``r`` of the frame ``td`` (batch ``[B]``, raw keys at its root) as a trace frame; ``first``: an
        episode's first frame (the lateral position restarts at the lane centre)."""
        state = td.get(K.EGO_STATE)[r].tolist()
        lane = int(td.get(K.EGO_LANE)[r].reshape(-1)[0])
        active = bool(td.get(K.LC_ACTIVE)[r].reshape(-1)[0])
        centre = (lane + 0.5) * self.lane_width
        if first or not active or r not in self._x:
            self._x[r] = centre
        else:
            self._x[r] += state[2] * self.dt
        x, y = self._x[r], state[0]
        rel, mask = td.get(K.NEIGHBORS_REL)[r], td.get(K.NEIGHBORS_MASK)[r].reshape(-1)
        neighbours = {
            slot: [round(y + float(rel[i, 1]), 2), round(x + float(rel[i, 0]), 2)]
            for i, slot in enumerate(K.NEIGHBOR_SLOTS)
            if bool(mask[i])
        }
        return {
            "t": t,
            "y": round(y, 2),
            "x": round(x, 2),
            "v": round(state[1], 3),
            "lane": lane,
            "accel": round(float(td.get(K.EGO_ACCEL)[r].reshape(-1)[0]), 3),
            "lc_started": bool(td.get(K.LC_STARTED)[r].reshape(-1)[0]),
            "lc_active": active,
            "braking_phase": K.BRAKING_PHASES[int(td.get(K.BRAKING_PHASE)[r].reshape(-1)[0])],
            # the braking event's car: its leader slot in this observation ("" where it is none of them)
            "braking_slot": _slot(td.get(K.BRAKING_SLOT, None), r),
            "neighbours": neighbours,
        }

    @torch.no_grad()
    def __call__(self, step: TensorDictBase) -> None:
        if self.done:
            return
        step = step.reshape(-1)
        nxt, done = step.get("next"), step.get(("next", "done")).reshape(step.shape[0], -1).any(-1)
        for r in range(step.shape[0]):
            if r not in self._open:
                self._open[r] = {**self.meta, "row": r, "frames": [self.frame(step, r, 0, True)]}
            trace = self._open[r]
            trace["frames"].append(self.frame(nxt, r, len(trace["frames"]), False))
            if bool(done[r]):
                del self._open[r]
                outcome = int(nxt.get(K.OUTCOME)[r].reshape(-1)[0])
                trace["outcome"] = K.OUTCOMES[outcome]
                trace["collision_kind"] = K.COLLISION_KINDS[int(nxt.get(K.COLLISION_KIND)[r].reshape(-1)[0])]
                if outcome == K.COLLIDED:  # the last frame says so, with the other vehicle's slot
                    trace["frames"][-1]["collision"] = trace["collision_kind"]
                    trace["frames"][-1]["collision_with"] = _slot(nxt.get(K.COLLISION_SLOT, None), r)
                trace["lane_changes"] = sum(f["lc_started"] for f in trace["frames"])
                if self.collisions_only and outcome != K.COLLIDED:
                    continue
                if not self.done:
                    self.traces.append(trace)

    def chosen(self) -> list[dict]:
        """The first ``episodes`` traces, with one with a lane change and one without among them when held."""
        if self.collisions_only:
            return self.traces[: self.episodes]
        picked = self.traces[: self.episodes]
        for want in (True, False):
            if not any(bool(t["lane_changes"]) == want for t in picked):
                extra = next((t for t in self.traces if bool(t["lane_changes"]) == want), None)
                if extra is not None:
                    picked = picked[:-1] + [extra] if len(picked) >= self.episodes else picked + [extra]
        return picked
