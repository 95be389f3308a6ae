"""``EpisodeTracker``: the per-episode driving metrics of paper Tables II-V from collected frames.

The one episode-metrics path: training (:class:`~kddrl_trl.training.Trainer`), evaluation
(:func:`~kddrl_trl.eval.evaluate_policy`) and the Gymnasium env feed it the TensorDicts the env wrote, so every
env writing the raw keys and episode events of ``kddrl_trl.keys`` (``SumoHighwayEnv``, ``FakeHighwayEnv``) gets
the same metrics.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase

from .. import keys as K
from ..highway_config import HighwayConfig
from ..physics.rss import RSSParams
from .fault import breaches, fault, held
from .specs import lc_command

#: running sums per row, in column order
SUMS = (
    "frames",
    "speed",
    "speed_sq",
    "accel",
    "accel_sq",
    "abs_accel",
    "lane_changes",
    "return_lc",
    "return_cf",
    "shield",
)
#: episode field written at the first frame of each braking phase (the braking distance with the first one)
PHASE_FIELDS = {
    K.BRAKE_BRAKING: "braking_start_frame",
    K.BRAKE_STANDING: "braking_stop_frame",
    K.BRAKE_RESUMED: "braking_resume_frame",
}
#: the per-episode driving metrics of Tables II-V that every evaluation record and ``test/`` log carries
METRIC_FIELDS = (
    "mean_speed_kmh",
    "mean_accel",
    "mean_abs_accel",
    "lane_changes",
    "frames",
    "return_lc",
    "return_cf",
    "collision",
)
#: label of an episode whose done flag the env did not set (a transform or a collector truncated it)
TRUNCATED_OUTSIDE = "truncated"
#: the entries of a frame the tracker reads, all under "next"
IN_KEYS = tuple(
    ("next", *(key if isinstance(key, tuple) else (key,)))
    for key in (
        K.EGO_STATE,
        K.EGO_ACCEL,
        K.LC_STARTED,
        K.LC_ACTIVE,
        K.LC_REWARD,
        K.CF_REWARD,
        "done",
        K.OUTCOME,
        K.COLLISION_KIND,
        K.COLLISION_SLOT,
        K.BRAKING_PHASE,
        K.BRAKING_DISTANCE,
    )
)
#: the observation the frame's action was taken in, at the frames' root: what the collision's fault class reads
#: (:mod:`kddrl_trl.envs.fault`; ``collision_fault`` is ``unknown`` where the frames lack any of them)
FAULT_KEYS = (K.EGO_STATE, K.NEIGHBORS_KIN, K.NEIGHBORS_MASK, K.LC_ACTIVE)
#: entries read when present (0 where absent): the car-following shield's interventions (``keys.CF_SHIELD``), the
#: braking event's car (gap, speed, lane changes, contact: envs without the event need not write them), the
#: neighbours' states (the other vehicle of a crash), and the
#: frame's commands at its root (the policy's; the crash fields ``crash_lc_command`` ... are empty without them)
OPTIONAL_KEYS = (
    ("next", *K.CF_SHIELD),
    ("next", *K.BRAKING_GAP),
    ("next", *K.BRAKING_SPEED),
    ("next", *K.BRAKING_LANE_CHANGES),
    ("next", *K.BRAKING_CONTACT),
    ("next", *K.NEIGHBORS_REL),
    ("next", *K.NEIGHBORS_KIN),
    K.LC_ACTION,
    K.CF_ACTION,
    *FAULT_KEYS,
)
#: the onset and crash fields of an episode (empty: NaN, or "" for the lane command and the event-car contact, where
#: the episode had no braking event or no crash)
ONSET_FIELDS = ("onset_gap", "onset_speed", "onset_leader_speed", "onset_headway", "onset_ttc")
CRASH_FIELDS = (
    "crash_speed",
    "crash_accel",
    "crash_cf_command",
    "crash_lc_command",
    "crash_lc_command_frame",
    "crash_lane_change_frame",
    "crash_with_event_car",
    "crash_event_gap",
    "crash_event_speed",
    "crash_other_dy",
    "crash_other_speed",
    "crash_other_accel",
)


class EpisodeTracker:
    """Per-episode metrics from frame batches ``[B, T]`` (B rows, e.g. the roads of a batched env, T consecutive
    frames each, as TorchRL collectors give them); returns the episodes that finished in each batch, in the
    order they finished.

    Reads :data:`IN_KEYS` (under ``"next"`` of each frame): ``EGO_STATE`` (speed), ``EGO_ACCEL``,
    ``LC_STARTED``, the two rewards, ``done`` and the episode events ``OUTCOME``, ``COLLISION_KIND``,
    ``COLLISION_SLOT``, ``BRAKING_PHASE``, ``BRAKING_DISTANCE``; and :data:`OPTIONAL_KEYS` where present
    (``CF_SHIELD``, written by :class:`~kddrl_trl.transforms.SafetyShield`). The row order of successive batches
    must be the same, and a row's episode goes on across batches until a frame has ``done`` set.

    Each episode is a dict of:

    - ``index`` (numbered in the order they finish, from :attr:`finished`), ``start`` (numbered in the order they
      start: all B rows at the first batch, then the rows reset after a done frame, row order within a frame),
      ``road`` (the row);
    - ``frames``; ``mean_speed`` (m/s), ``mean_speed_kmh``, ``mean_accel``, ``mean_abs_accel`` (m/s²),
      ``mean_sq_speed``, ``mean_sq_accel`` (for frame-level spreads); ``lane_changes`` (manoeuvres started);
      ``return_lc``, ``return_cf`` (undiscounted sums of the two rewards, Eq. 26 and 32);
      ``shield_interventions`` (frames in which the car-following shield lowered the command; 0 without a
      shield) and ``shield_rate`` (their fraction of the episode's frames);
    - ``outcome`` (a ``keys.OUTCOMES`` label, or ``"truncated"`` when the done flag came from outside the env),
      ``collision`` (outcome is a collision), ``collision_kind`` (``keys.COLLISION_KINDS`` label),
      ``collision_with`` (the other vehicle's neighbour slot ``"a"``-``"f"``, ``""`` if none or unknown; its
      role: leaders a/b/c, followers d/e/f), ``ended_changing_lane`` (the ego's lane-change manoeuvre was under
      way at the last frame);
    - ``braking_distance`` (m, NaN without a braking event) and, once reached, ``braking_start_frame``,
      ``braking_stop_frame``, ``braking_resume_frame`` (the episode's frame count at which each phase began);
    - at the braking event's onset (:data:`ONSET_FIELDS`, NaN without one): ``onset_gap`` (m, the ego's front to
      the braking car's rear), ``onset_speed`` and ``onset_leader_speed`` (m/s, the ego's and the braking car's),
      ``onset_headway`` (s, gap / ego speed) and ``onset_ttc`` (s, gap / closing speed; ``inf`` when not closing);
      ``event_car_lane_changes`` (the released car's own lane changes by the episode's end);
    - at a crash (:data:`CRASH_FIELDS`, empty otherwise): ``crash_speed`` (m/s, the ego's in the last observation
      before the contact), ``crash_accel`` (m/s², executed in the crash frame), ``crash_cf_command`` (m/s²) and
      ``crash_lc_command`` (a ``keys.LC_ACTIONS`` label) of the crash frame, ``crash_lc_command_frame`` (the
      episode's frame count since which that lane command was held), ``crash_lane_change_frame`` (the frame count at
      which the ego's last lane change started, NaN if none), ``crash_with_event_car`` (the other vehicle was the
      braking event's car), ``crash_event_gap`` and ``crash_event_speed`` (that car's, NaN without an event),
      ``crash_other_dy`` (m, the other vehicle's longitudinal offset from the ego), ``crash_other_speed`` and
      ``crash_other_accel`` (m/s, m/s²) in the last observation (NaN when it was not a neighbour). The commands are
      read from the frames' root (``keys.LC_ACTION``, ``CF_ACTION``) when there;
    - ``collision_fault``: who is at fault under RSS's proper response (:mod:`kddrl_trl.envs.fault`: ``ego``,
      ``other``, ``unknown``; ``""`` without a collision), from the observations at the frames' root
      (:data:`FAULT_KEYS`) and the executed accelerations.

    ``highway``: the env's config, for the vehicles' length and the hardest braking the fault class assumes
    (default: Table A.1's).
    """

    def __init__(self, highway: HighwayConfig | None = None):
        highway = highway if highway is not None else HighwayConfig()
        self.length, self.low = float(highway.vehicle_length), float(highway.accel_low)
        self.rss = RSSParams(horizon=highway.sensing_range)
        self.finished = 0  # episodes returned so far (a resumed training run sets it)
        self.started = 0
        self._carry: torch.Tensor | None = None  # [B, len(SUMS)] sums of the open episodes before this batch
        self._start: torch.Tensor | None = None  # [B] start number of each row's open episode
        self._phase: torch.Tensor | None = None  # [B] braking phase of each row's last frame
        self._events: list[dict] = []  # per row: braking fields of the open episode
        self._seen: torch.Tensor | None = None  # [B] frames seen per row before this batch (a row's frame numbers)
        # [B] per row: frame number of the last lane-change start and of the last change of the lane command, and
        # the last frame's command (frame numbers count every frame the row has had, across episodes)
        self._last_lc: torch.Tensor | None = None
        self._last_cmd_change: torch.Tensor | None = None
        self._last_cmd: torch.Tensor | None = None
        # [B, 4] per row: the (doubled) frame numbers of the last longitudinal breach, its last clearing, the last
        # lateral breach and its last clearing (:func:`kddrl_trl.envs.fault.held`; an episode start clears both)
        self._fault: torch.Tensor | None = None
        self._last_done: torch.Tensor | None = None  # [B] the last frame of the previous batch ended its episode

    def _breaches(self, frames: TensorDictBase, nxt: TensorDictBase, cmd: torch.Tensor, number: torch.Tensor):
        """``[B, T]`` each: whether a longitudinal and a lateral breach of the proper response is held at each
        frame (None where the frames lack :data:`FAULT_KEYS`)."""
        obs = [frames.get(key, None) for key in FAULT_KEYS]
        if any(x is None for x in obs):
            return None
        b, t = frames.batch_size
        ego, kin, mask, active = (x.reshape(b, t, *x.shape[len(frames.batch_size) :]).cpu() for x in obs)
        col = self._column
        out = breaches(
            ego,
            kin,
            mask,
            active.reshape(b, t, 1),
            col(nxt, K.EGO_ACCEL),
            col(nxt, K.EGO_STATE, 1),
            col(nxt, K.LC_STARTED).bool(),
            cmd,
            col(nxt, K.LC_ACTIVE).bool(),
            self.rss,
            self.length,
            self.low,
        )
        # doubled numbers: an episode's start clears at 2n - 1, so a breach in its first frame (2n) still counts
        done = col(nxt, "done").bool()
        first = torch.cat([self._last_done[:, None], done[:, :-1]], 1)
        two, zero = 2 * number, torch.zeros_like(number)
        result = []
        for i, kind in enumerate(("lon", "lat")):
            breach = torch.where(out[kind], two, zero)
            clear = torch.where(out[f"{kind}_clear"], two, torch.where(first, two - 1, zero))
            on, self._fault[:, 2 * i], self._fault[:, 2 * i + 1] = held(
                breach, clear, self._fault[:, 2 * i], self._fault[:, 2 * i + 1]
            )
            result.append(on)
        return result

    @staticmethod
    def _column(nxt: TensorDictBase, key, index: int = 0, optional: bool = False, fill: float = 0.0) -> torch.Tensor:
        value = nxt.get(key, None)
        if value is None and optional:
            return torch.full(nxt.batch_size, fill)
        if value is None:
            raise KeyError(
                f"EpisodeTracker: the frames have no ('next', {key!r}) entry; the env must write the raw "
                "keys and episode events of kddrl_trl/keys.py (SumoHighwayEnv, FakeHighwayEnv)"
            )
        return value.reshape(*nxt.batch_size, -1)[..., index].cpu()

    def __call__(self, frames: TensorDictBase) -> list[dict]:
        if frames.batch_dims != 2:
            raise ValueError(f"EpisodeTracker: expected frames of batch shape [B, T], got {tuple(frames.batch_size)}")
        b, t = frames.batch_size
        nxt = frames.get("next")
        col = self._column
        speed, accel = col(nxt, K.EGO_STATE, 1).double(), col(nxt, K.EGO_ACCEL).double()
        values = torch.stack(
            [
                torch.ones(b, t, dtype=torch.float64),
                speed,
                speed * speed,
                accel,
                accel * accel,
                accel.abs(),
                col(nxt, K.LC_STARTED).double(),
                col(nxt, K.LC_REWARD).double(),
                col(nxt, K.CF_REWARD).double(),
                col(nxt, K.CF_SHIELD, optional=True).double(),
            ],
            -1,
        )
        done, phase = col(nxt, "done").bool(), col(nxt, K.BRAKING_PHASE).long()
        codes = torch.stack(
            [col(nxt, K.OUTCOME), col(nxt, K.COLLISION_KIND), col(nxt, K.COLLISION_SLOT), col(nxt, K.LC_ACTIVE).long()],
            -1,
        ).long()
        distance = col(nxt, K.BRAKING_DISTANCE).double()
        event = {
            "gap": col(nxt, K.BRAKING_GAP, optional=True).double(),
            "speed": col(nxt, K.BRAKING_SPEED, optional=True).double(),
            "lane_changes": col(nxt, K.BRAKING_LANE_CHANGES, optional=True).double(),
            "contact": col(nxt, K.BRAKING_CONTACT, optional=True).bool(),
        }
        neighbors = {  # [B, T, 6] each: the neighbours' longitudinal offsets, speeds, accelerations
            name: None if value is None else value[..., feature].cpu()
            for name, value, feature in (
                ("dy", nxt.get(K.NEIGHBORS_REL, None), 1),
                ("speed", nxt.get(K.NEIGHBORS_KIN, None), 1),
                ("accel", nxt.get(K.NEIGHBORS_KIN, None), 2),
            )
        }
        has_cmd = frames.get(K.LC_ACTION, None) is not None
        cmd = lc_command(frames.get(K.LC_ACTION).reshape(b, t, -1).cpu()) if has_cmd else torch.full((b, t), K.KEEP)
        cf_cmd = col(frames, K.CF_ACTION, optional=True, fill=math.nan).double()
        if self._carry is None:
            self._carry = torch.zeros(b, len(SUMS), dtype=torch.float64)
            self._start = torch.arange(b) + self.finished
            self._phase = torch.zeros(b, dtype=torch.long)
            self._events = [{} for _ in range(b)]
            self.started = self.finished + b
            self._seen = torch.zeros(b, dtype=torch.long)
            self._last_lc = torch.zeros(b, dtype=torch.long)
            self._last_cmd_change = torch.zeros(b, dtype=torch.long)
            self._last_cmd = torch.full((b,), -1, dtype=torch.long)
            self._fault = torch.zeros(b, 4, dtype=torch.long)
            self._last_done = torch.ones(b, dtype=torch.bool)
        elif self._carry.shape[0] != b:
            raise ValueError(f"EpisodeTracker: the batch has {b} rows, earlier batches had {self._carry.shape[0]}")
        # frame numbers of the row (1 = its first frame ever), and per frame the number of the last lane-change start
        # and of the last change of the lane command at or before it (0: none yet)
        number = self._seen[:, None] + torch.arange(1, t + 1)
        zero = torch.zeros_like(number)
        last_lc = torch.where(col(nxt, K.LC_STARTED).bool(), number, zero).cummax(1).values
        last_lc = torch.maximum(last_lc, self._last_lc[:, None])
        cmd_changed = cmd != torch.cat([self._last_cmd[:, None], cmd[:, :-1]], 1)
        last_cmd = torch.maximum(
            torch.where(cmd_changed, number, zero).cummax(1).values, self._last_cmd_change[:, None]
        )
        held_breaches = self._breaches(frames, nxt, cmd, number)
        # a braking phase change within an episode (a new episode starts from phase "none")
        before = torch.cat([self._phase[:, None], phase[:, :-1]], 1)
        before[:, 1:][done[:, :-1]] = K.BRAKE_NONE
        changed = phase != before
        csum = values.cumsum(1)
        base = -self._carry  # per row: the cumulative sum just before the open episode's first frame
        out = []
        steps, rows = (changed | done).T.nonzero(as_tuple=True)  # in frame order, row order within a frame
        for j, r in zip(steps.tolist(), rows.tolist()):
            sums = csum[r, j] - base[r]
            if changed[r, j]:
                self._braking_event(r, int(phase[r, j]), int(sums[0]), float(distance[r, j]))
                if int(phase[r, j]) == K.BRAKE_BRAKING:
                    self._onset(r, float(event["gap"][r, j]), float(speed[r, j]), float(event["speed"][r, j]))
            if done[r, j]:
                first = int(number[r, j] - sums[0]) + 1  # the row's frame number of the episode's first frame
                at_end = {name: value[r, j] for name, value in event.items()}
                if int(codes[r, j, 0]) == K.COLLIDED:
                    self._events[r].update(
                        crash_speed=float(speed[r, j]),
                        crash_accel=float(accel[r, j]),
                        crash_cf_command=float(cf_cmd[r, j]),
                        crash_lc_command=K.LC_ACTIONS[int(cmd[r, j])] if has_cmd else "",
                        crash_lc_command_frame=(max(int(last_cmd[r, j]), first) - first + 1) if has_cmd else math.nan,
                        crash_lane_change_frame=int(last_lc[r, j]) - first + 1 if last_lc[r, j] >= first else math.nan,
                        crash_with_event_car=bool(at_end["contact"]),
                    )
                    if "braking_start_frame" in self._events[r]:
                        self._events[r].update(
                            crash_event_gap=float(at_end["gap"]), crash_event_speed=float(at_end["speed"])
                        )
                    slot = int(codes[r, j, 2])
                    self._events[r]["collision_fault"] = (
                        "unknown"
                        if held_breaches is None
                        else fault(slot, bool(held_breaches[0][r, j]), bool(held_breaches[1][r, j]))
                    )
                    if slot >= 0:
                        self._events[r].update(
                            {
                                f"crash_other_{name}": float(v[r, j, slot])
                                for name, v in neighbors.items()
                                if v is not None
                            }
                        )
                if "braking_start_frame" in self._events[r]:
                    self._events[r]["event_car_lane_changes"] = int(at_end["lane_changes"])
                out.append(self._episode(r, sums, codes[r, j].tolist()))
                base[r] = csum[r, j]
        self._carry = csum[:, -1] - base
        self._phase = torch.where(done[:, -1], K.BRAKE_NONE, phase[:, -1])
        self._seen += t
        self._last_done = done[:, -1].clone()
        self._last_lc, self._last_cmd_change, self._last_cmd = last_lc[:, -1], last_cmd[:, -1], cmd[:, -1]
        return out

    def _onset(self, r: int, gap: float, speed: float, leader_speed: float) -> None:
        """The braking event's onset on row ``r``: the gap, both speeds, the time headway and the time to collision."""
        closing = speed - leader_speed
        self._events[r].update(
            onset_gap=gap,
            onset_speed=speed,
            onset_leader_speed=leader_speed,
            onset_headway=gap / speed if speed > 0 else math.inf,
            onset_ttc=gap / closing if closing > 0 else math.inf,
        )

    def _braking_event(self, r: int, phase: int, frame: int, distance: float) -> None:
        if phase == K.BRAKE_NONE:
            return
        events = self._events[r]
        events.setdefault("braking_distance", distance)
        if phase in PHASE_FIELDS:
            events.setdefault(PHASE_FIELDS[phase], frame)

    def _episode(self, r: int, sums: torch.Tensor, codes: list[int]) -> dict:
        total = dict(zip(SUMS, sums.tolist()))
        n = max(total["frames"], 1.0)
        outcome, kind, slot, changing = codes
        label = K.OUTCOMES[outcome] if outcome != K.RUNNING else TRUNCATED_OUTSIDE
        events = self._events[r]
        ep = {
            "index": self.finished,
            "start": int(self._start[r]),
            "road": r,
            "frames": int(total["frames"]),
            "mean_speed": total["speed"] / n,
            "mean_speed_kmh": 3.6 * total["speed"] / n,
            "mean_accel": total["accel"] / n,
            "mean_abs_accel": total["abs_accel"] / n,
            "mean_sq_speed": total["speed_sq"] / n,
            "mean_sq_accel": total["accel_sq"] / n,
            "lane_changes": int(total["lane_changes"]),
            "collision": outcome == K.COLLIDED,
            "outcome": label,
            "collision_kind": K.COLLISION_KINDS[kind],
            "collision_with": K.NEIGHBOR_SLOTS[slot] if slot >= 0 else "",
            "collision_fault": events.pop("collision_fault", ""),
            "ended_changing_lane": bool(changing),
            "return_lc": total["return_lc"],
            "return_cf": total["return_cf"],
            "shield_interventions": int(total["shield"]),
            "shield_rate": total["shield"] / n,
            "braking_distance": events.pop("braking_distance", math.nan),
            **{name: events.pop(name, math.nan) for name in ONSET_FIELDS},
            "event_car_lane_changes": events.pop("event_car_lane_changes", math.nan),
            **{
                name: events.pop(name, "" if name in ("crash_lc_command", "crash_with_event_car") else math.nan)
                for name in CRASH_FIELDS
            },
            **events,
        }
        self.finished += 1
        self._start[r] = self.started
        self.started += 1
        self._events[r] = {}
        return ep
