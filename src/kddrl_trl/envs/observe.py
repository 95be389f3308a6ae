"""Observation building of :class:`~kddrl_trl.envs.sim.HighwaySim`: the raw keys of ``kddrl_trl.keys`` of each
road's ego, read from libsumo in the paper's road coordinates (``y`` along the road from the start of the study
section, ``x`` lateral).

Per ego (paper §III.G, Fig. 6, Eq. 24-25): its state and lane; the six neighbours a-f (leader and follower in
the left, current and right lanes) within ``sensing_range``, as relative and absolute kinematics; for the leaders
a-c, the vehicle ahead of each and their last ``history_len`` positions and speeds (the trajGAN inputs); and the
lane-change action mask (a command is executed only between manoeuvres and toward an existing lane); the
lateral offsets of the ego and the neighbours from their lanes' centres (lcGAN's condition C, Eq. 16).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from .. import keys as K
from ..highway_config import HighwayConfig
from .network import road_y
from .specs import observation_spec

#: whether the simulation runs in sumo-gui over TraCI (:func:`use_traci`) instead of libsumo
_TRACI = False


def _libsumo():
    """The SUMO client of this process: libsumo (in-process, fast), or TraCI while a live view runs sumo-gui
    (libsumo can start sumo-gui but not reload or close it). Both have the same API."""
    if _TRACI:
        import traci

        return traci
    import libsumo

    return libsumo


def use_traci(on: bool) -> None:
    """Route this process's SUMO calls through TraCI (``on``, the live view) or libsumo."""
    global _TRACI
    _TRACI = bool(on)


def longitudinal(vid: str, cfg: HighwayConfig) -> float:
    """Front-bumper position of ``vid`` along its road, metres from the start of the study section."""
    return _libsumo().vehicle.getPosition(vid)[0] - cfg.entry_length


def lane_and_offset(lat, lane_width: float, num_lanes: int) -> tuple[np.ndarray, np.ndarray]:
    """The lane holding a lateral position and the offset from that lane's centre (``keys.EGO_LANE_OFFSET``,
    ``keys.NEIGHBORS_LANE_OFFSET``): ``lat`` in metres from the right edge of the carriageway, growing to the left
    -> (lane index, 0 = rightmost, int64; offset in m, + = left of the centre). Positions beyond the edges count
    to the outer lanes."""
    lane = np.clip(np.floor(lat / lane_width), 0, num_lanes - 1)
    return lane.astype(np.int64), lat - (lane + 0.5) * lane_width


def observation_arrays(cfg: HighwayConfig, num_roads: int) -> dict:
    """Zeroed numpy arrays ``[K, ...]`` of every raw key, shaped and typed by the env's observation spec (so the
    simulator's output always matches the spec); ``LC_ACTION_MASK`` all true, ``COLLISION_SLOT`` -1 (none)."""
    zero = observation_spec(cfg, (num_roads,)).zero()
    obs = {key: zero.get(key).numpy() for key in zero.keys(True, True)}
    obs[K.LC_ACTION_MASK][:] = True
    obs[K.COLLISION_SLOT][:] = -1
    obs[K.BRAKING_SLOT][:] = -1
    return obs


class NonFiniteObservation(ValueError):
    """A NaN or infinity in an env output (the message names the key, the roads and the values)."""


class FiniteCheck:
    """Raises :class:`NonFiniteObservation` when a float array of ``arrays`` (an env's output arrays by key,
    which the simulator overwrites in place every frame) holds a NaN or an infinity, naming the key, the roads and
    the values: a NaN never reaches a network. Per frame, one sum per float array (nine: seven observed, two
    rewards), their total tested once; ``benchmarks/soak.py`` measures the cost against a frame (0.4 %)."""

    def __init__(self, arrays: dict):
        self.floats = [(key, arr) for key, arr in arrays.items() if arr.dtype.kind == "f"]

    def __call__(self) -> None:
        if math.isfinite(sum(arr.sum() for _, arr in self.floats)):  # the fast path: one sum per array
            return
        for key, arr in self.floats:
            if not np.isfinite(arr).all():
                bad = ~np.isfinite(arr.reshape(len(arr), -1)).all(axis=1)
                roads = np.flatnonzero(bad).tolist()
                raise NonFiniteObservation(
                    f"non-finite value in env output {key} on road(s) {roads}: {arr[roads].tolist()} (SUMO returned "
                    "a NaN / inf; the frame is refused before it reaches a transform or a network)"
                )


class Observer:
    """Writes the raw observation of the roads asked into ``obs`` (the simulator's ``[K, ...]`` arrays).

    One call per frame for all the roads (:meth:`observe`): a lean per-road loop asks libsumo only what SUMO alone
    knows (the ego's and its neighbours' kinematics, SUMO's leader / follower / neighbour search: about 35 calls per
    road), keeps the answers as Python floats, and then writes every raw key
    of all the roads with one numpy assignment per key. Relative kinematics are computed in float64 and rounded to
    the arrays' float32 once, as the per-road code before it did, so the output is bit-for-bit the same
    (``tests/envs/test_env_reference.py``).

    Why not libsumo subscriptions: ``vehicle.getAllSubscriptionResults()`` builds a dict of every vehicle's
    variables on each call, which at K = 32 costs about as much as asking the ~10 vehicles each ego sees for their
    four values, and ``getSubscriptionResults`` per vehicle saves only a part of that while every subscribed vehicle
    adds work to each simulation step (``benchmarks/env_throughput.py`` measures the env's frames/s).

    Keeps, per road, the recent positions of the vehicles seen as leaders (for ``LEADERS_HISTORY``) and the
    neighbour ids of the last observation in slot order a-f (:attr:`slots`; ``None`` for an empty slot), which
    the simulator reads to tell which neighbour a collision involved.
    """

    def __init__(self, cfg: HighwayConfig, obs: dict, num_roads: int):
        self.cfg, self.obs = cfg, obs
        self.history: list[dict[str, deque]] = [{} for _ in range(num_roads)]
        self.slots: list[list[str | None]] = [[None] * len(K.NEIGHBOR_SLOTS) for _ in range(num_roads)]
        self.road_y = np.array([road_y(r) for r in range(num_roads)])  # each road's lateral network coordinate

    def observe(self, roads, egos, t: int, lc_active) -> dict[int, str]:
        """Fill the raw observation of ``egos[i]`` on road ``roads[i]`` at simulation step ``t``; ``lc_active[i]``:
        a lane-change manoeuvre is in progress there. A neighbour SUMO cannot answer for (``TraCIException``) is
        treated as not seen; a road whose ego SUMO cannot answer for is left as it was and returned, road -> the
        error (the simulator truncates it as lost)."""
        ls = _libsumo()
        vmod = ls.vehicle  # looked up per call: the fault-injection tests patch its functions
        position, speed, lat_speed, accel = vmod.getPosition, vmod.getSpeed, vmod.getLateralSpeed, vmod.getAcceleration
        lane_index, leader, follower, neighbors = (
            vmod.getLaneIndex,
            vmod.getLeader,
            vmod.getFollower,
            vmod.getNeighbors,
        )
        error = ls.TraCIException
        cfg = self.cfg
        rng_, entry, h = cfg.sensing_range, cfg.entry_length, cfg.history_len
        slot_b, slot_e = K.SLOT["b"], K.SLOT["e"]
        side = [(K.SLOT[name], mode) for name, mode in (("a", 2), ("c", 3), ("d", 0), ("f", 1))]
        # getNeighbors mode: bit 0 set = right side, bit 1 set = leaders (checked in tests/envs/test_env_sumo.py)
        failed: dict[int, str] = {}
        rows, ego_rows, lanes, active = [], [], [], []  # per observed road
        nb_at, nb_rows = [], []  # (row, slot), (ny, nlat, nv, nvx, na)
        ahead_at, ahead_rows = [], []  # (row, slot), (y, v)
        hist_at, hist_rows = [], []  # (row, slot), [h, 2]
        for r, ego, lc_on in zip(roads, egos, lc_active):
            try:
                px, py = position(ego)
                ego_kin = (px - entry, py, speed(ego), lat_speed(ego))
                lane = lane_index(ego)
                found: list[str | None] = [None] * 6
                lead = leader(ego, rng_)
                if lead and lead[0]:
                    found[slot_b] = lead[0]
                follow = follower(ego, rng_)
                if follow and follow[0]:
                    found[slot_e] = follow[0]
                for slot, mode in side:
                    near = neighbors(ego, mode)
                    if near:
                        found[slot] = min(near, key=lambda item: item[1])[0]
            except error as err:
                failed[r] = f"observation: {err}"
                continue
            i = len(rows)
            rows.append(r)
            ego_rows.append(ego_kin)
            lanes.append(lane)
            active.append(bool(lc_on))
            y = ego_kin[0]
            hist = self.history[r]
            for slot, nid in enumerate(found):
                if nid is None:
                    continue
                try:
                    nx_, nlat = position(nid)
                    ny = nx_ - entry
                    kin = (ny, nlat, speed(nid), lat_speed(nid), accel(nid))
                except error:  # SUMO cannot answer for this neighbour (gone mid-query): not seen
                    ny = np.inf
                if abs(ny - y) > rng_:
                    found[slot] = None
                    continue
                nb_at.append((i, slot))
                nb_rows.append(kin)
                if slot < 3:
                    self._remember(hist, nid, ny, kin[2], t)
            self.slots[r] = found
            for slot in range(3):  # the vehicle ahead of each leader, and the leaders' history
                nid = found[slot]
                if nid is None:
                    continue
                try:
                    nxt = leader(nid, rng_)
                    if nxt and nxt[0]:
                        ahead_rows.append((position(nxt[0])[0] - entry, speed(nxt[0])))
                        ahead_at.append((i, slot))
                except error:  # the vehicle ahead of this leader cannot be queried: none seen
                    pass
                hist_at.append((i, slot))
                hist_rows.append(self._history(hist[nid], t, h))
        if rows:
            self._write(
                np.asarray(rows),
                np.asarray(ego_rows),
                np.asarray(lanes),
                np.asarray(active),
                nb_at,
                nb_rows,
                ahead_at,
                ahead_rows,
                hist_at,
                hist_rows,
            )
        return failed

    def _write(self, rows, ego, lanes, active, nb_at, nb_rows, ahead_at, ahead_rows, hist_at, hist_rows) -> None:
        """Every raw key of the observed ``rows`` at once (``ego`` [n, 4]: y, lateral position, v, v_lateral)."""
        o, cfg = self.obs, self.cfg
        o[K.EGO_STATE][rows] = ego[:, (0, 2, 3)]
        o[K.EGO_LANE][rows, 0] = lanes
        rel, kin, mask = o[K.NEIGHBORS_REL], o[K.NEIGHBORS_KIN], o[K.NEIGHBORS_MASK]
        rel[rows] = 0.0
        kin[rows] = 0.0
        mask[rows] = False
        if nb_at:
            at = np.asarray(nb_at)
            i, slot = at[:, 0], at[:, 1]
            n = np.asarray(nb_rows)  # y, lateral position, v, v_lateral, a
            e = ego[i]
            r = rows[i]
            rel[r, slot] = np.stack((n[:, 1] - e[:, 1], n[:, 0] - e[:, 0], n[:, 3] - e[:, 3], n[:, 2] - e[:, 2]), -1)
            kin[r, slot] = n[:, (0, 2, 4)]
            mask[r, slot] = True
        self._lane_offsets(rows, ego[:, 1])
        ahead, history = o[K.LEADERS_AHEAD], o[K.LEADERS_HISTORY]
        ahead[rows] = 0.0
        history[rows] = 0.0
        if ahead_at:
            at = np.asarray(ahead_at)
            a = np.asarray(ahead_rows)
            ahead[rows[at[:, 0]], at[:, 1]] = np.concatenate((a, np.ones((len(a), 1))), -1)
        if hist_at:
            at = np.asarray(hist_at)
            history[rows[at[:, 0]], at[:, 1]] = np.asarray(hist_rows)
        o[K.LC_ACTIVE][rows, 0] = active
        am = o[K.LC_ACTION_MASK]
        am[rows, K.KEEP] = True
        am[rows, K.LEFT] = ~active & (lanes < cfg.num_lanes - 1)
        am[rows, K.RIGHT] = ~active & (lanes > 0)

    def _lane_offsets(self, rows: np.ndarray, ego_lat: np.ndarray) -> None:
        """``EGO_LANE_OFFSET`` and ``NEIGHBORS_LANE_OFFSET`` of ``rows`` (:func:`lane_and_offset`) from the lateral
        positions already read (the egos' network lateral positions ``ego_lat`` and ``NEIGHBORS_REL``'s dx): each
        vehicle's offset from the centre of the lane holding its centre (SUMO's lane, see ``data/sumo_to_highd.py``);
        0 for absent slots. No extra SUMO query."""
        cfg, o = self.cfg, self.obs
        x = ego_lat - self.road_y[rows] + cfg.num_lanes * cfg.lane_width  # ego centres' distance from the right edge
        lat = x[:, None] + np.concatenate((np.zeros((len(rows), 1)), o[K.NEIGHBORS_REL][rows][:, :, 0]), 1)
        _, offset = lane_and_offset(lat, cfg.lane_width, cfg.num_lanes)
        o[K.EGO_LANE_OFFSET][rows, 0] = offset[:, 0]
        o[K.NEIGHBORS_LANE_OFFSET][rows] = np.where(o[K.NEIGHBORS_MASK][rows], offset[:, 1:], 0.0)

    def _remember(self, hist: dict, vid: str, y: float, v: float, t: int) -> None:
        d = hist.get(vid)
        if d is None:
            d = hist[vid] = deque(maxlen=self.cfg.history_len)
        if not d or d[-1][0] != t:
            d.append((t, y, v))

    def _history(self, samples: deque, t: int, h: int) -> list[tuple[float, float]]:
        """Positions and speeds over the last ``h`` frames up to step ``t``, oldest first. Frames in which the vehicle
        was not observed (it only just came into view as a leader) are filled by constant-speed
        back-extrapolation from the next known sample."""
        if len(samples) == h and samples[0][0] == t - h + 1 and samples[-1][0] == t:  # seen in each of the h frames
            return [(y, v) for _, y, v in samples]
        known = {s: (y, v) for s, y, v in samples}
        nxt_y, nxt_v = samples[-1][1], samples[-1][2]
        out = [(0.0, 0.0)] * h
        for j in range(h - 1, -1, -1):
            step = t - (h - 1 - j)
            if step in known:
                nxt_y, nxt_v = known[step]
            else:
                nxt_y = nxt_y - nxt_v * self.cfg.step_length
            out[j] = (nxt_y, nxt_v)
        return out

    def forget_old(self, t: int) -> None:
        """Drop the history of vehicles not seen as a leader in the last ``history_len`` steps."""
        horizon = t - self.cfg.history_len - 1
        for hist in self.history:
            for vid in [v for v, d in hist.items() if d[-1][0] < horizon]:
                del hist[vid]
