"""Observation building of :class:`~kddrl_trl.envs.sim.HighwaySim`: the raw keys of ``kddrl_trl.keys`` of each
road's ego, read from libsumo in the paper's road coordinates (``y`` along the road from the start of the study
section, ``x`` lateral).

Per ego (paper §III.G, Fig. 6, Eq. 24-25): its state and lane; the six neighbours a-f (leader and follower in
the left, current and right lanes) within ``sensing_range``, as relative and absolute kinematics; for the leaders
a-c, the vehicle ahead of each and their last ``history_len`` positions and speeds (the trajGAN inputs); and the
lane-change action mask (a command is executed only between manoeuvres and toward an existing lane).
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from .. import keys as K
from .config import HighwayConfig
from .network import road_y
from .specs import observation_spec


def _libsumo():
    import libsumo

    return libsumo


def longitudinal(vid: str, cfg: HighwayConfig) -> float:
    """Front-bumper position of ``vid`` along its road, metres from the start of the study section."""
    return _libsumo().vehicle.getPosition(vid)[0] - cfg.entry_length


def observation_arrays(cfg: HighwayConfig, num_roads: int) -> dict:
    """Zeroed numpy arrays ``[K, ...]`` of every raw key, shaped and typed by the env's observation spec (so the
    simulator's output always matches the spec); ``LC_ACTION_MASK`` all true, ``COLLISION_SLOT`` -1 (none)."""
    zero = observation_spec(cfg, (num_roads,)).zero()
    obs = {key: zero.get(key).numpy() for key in zero.keys(True, True)}
    obs[K.LC_ACTION_MASK][:] = True
    obs[K.COLLISION_SLOT][:] = -1
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
                    "a NaN / inf; the frame is refused before it reaches a transform or a network)")


class Observer:
    """Writes the raw observation of the roads asked into ``obs`` (the simulator's ``[K, ...]`` arrays).

    Keeps, per road, the recent positions of the vehicles seen as leaders (for ``LEADERS_HISTORY``) and the
    neighbour ids of the last observation in slot order a-f (:attr:`slots`; ``None`` for an empty slot), which
    the simulator reads to tell which neighbour a collision involved.
    """

    def __init__(self, cfg: HighwayConfig, obs: dict, num_roads: int):
        self.cfg, self.obs = cfg, obs
        self.history: list[dict[str, deque]] = [{} for _ in range(num_roads)]
        self.slots: list[list[str | None]] = [[None] * len(K.NEIGHBOR_SLOTS) for _ in range(num_roads)]

    def _kin(self, vid: str) -> tuple[float, float, float, float, float]:
        """(y, x_lateral, v, v_lateral, a) of a vehicle in road coordinates."""
        vmod = _libsumo().vehicle
        px, py = vmod.getPosition(vid)
        return px - self.cfg.entry_length, py, vmod.getSpeed(vid), vmod.getLateralSpeed(vid), vmod.getAcceleration(vid)

    def _neighbours(self, ego: str) -> list[str | None]:
        """Ids of the nearest vehicles in slots a-f (before the sensing-range check)."""
        vmod = _libsumo().vehicle
        rng_ = self.cfg.sensing_range
        found: list[str | None] = [None] * 6
        lead = vmod.getLeader(ego, rng_)
        if lead and lead[0]:
            found[K.SLOT["b"]] = lead[0]
        follow = vmod.getFollower(ego, rng_)
        if follow and follow[0]:
            found[K.SLOT["e"]] = follow[0]
        # getNeighbors mode: bit 0 set = right side, bit 1 set = leaders (checked in tests/test_env_sumo.py)
        for slot, mode in (("a", 2), ("c", 3), ("d", 0), ("f", 1)):
            near = vmod.getNeighbors(ego, mode)
            if near:
                found[K.SLOT[slot]] = min(near, key=lambda item: item[1])[0]
        return found

    def observe(self, r: int, ego: str, t: int, lc_active: bool) -> None:
        """Fill road ``r``'s raw observation of ``ego`` at simulation step ``t``; ``lc_active``: a lane-change
        manoeuvre is in progress. A neighbour SUMO cannot answer for (``TraCIException``) is treated as not seen;
        a failing query of the ego itself propagates (the simulator truncates the road as lost)."""
        vmod = _libsumo().vehicle
        cfg, o = self.cfg, self.obs
        rng_ = cfg.sensing_range
        y, px_lat, v, vx, _ = self._kin(ego)
        lane = vmod.getLaneIndex(ego)
        o[K.EGO_STATE][r] = (y, v, vx)
        o[K.EGO_LANE][r, 0] = lane
        found = self._neighbours(ego)
        rel, kin, mask = o[K.NEIGHBORS_REL][r], o[K.NEIGHBORS_KIN][r], o[K.NEIGHBORS_MASK][r]
        rel[:] = 0.0
        kin[:] = 0.0
        mask[:] = False
        hist = self.history[r]
        ls = _libsumo()
        for slot, nid in enumerate(found):
            if nid is None:
                continue
            try:
                ny, nlat, nv, nvx, na = self._kin(nid)
            except ls.TraCIException:  # SUMO cannot answer for this neighbour (gone mid-query): not seen
                ny = np.inf
            if abs(ny - y) > rng_:
                found[slot] = None
                continue
            rel[slot] = (nlat - px_lat, ny - y, nvx - vx, nv - v)
            kin[slot] = (ny, nv, na)
            mask[slot] = True
            if slot < 3:
                self._remember(hist, nid, ny, nv, t)
        self.slots[r] = found
        self._lane_offsets(r, px_lat)
        # vehicles ahead of the leaders, and the leaders' history
        ahead, history = o[K.LEADERS_AHEAD][r], o[K.LEADERS_HISTORY][r]
        ahead[:] = 0.0
        history[:] = 0.0
        for slot in range(3):
            nid = found[slot]
            if nid is None:
                continue
            try:
                nxt = vmod.getLeader(nid, rng_)
                if nxt and nxt[0]:
                    ahead[slot] = (longitudinal(nxt[0], cfg), vmod.getSpeed(nxt[0]), 1.0)
            except ls.TraCIException:  # the vehicle ahead of this leader cannot be queried: none seen
                ahead[slot] = 0.0
            self._fill_history(history[slot], hist[nid], t)
        o[K.LC_ACTIVE][r, 0] = lc_active
        am = o[K.LC_ACTION_MASK][r]
        am[K.KEEP] = True
        am[K.LEFT] = (not lc_active) and lane < cfg.num_lanes - 1
        am[K.RIGHT] = (not lc_active) and lane > 0

    def _lane_offsets(self, r: int, px_lat: float) -> None:
        """``EGO_LANE_OFFSET`` and ``NEIGHBORS_LANE_OFFSET`` of road ``r`` from the lateral positions already
        read (the ego's network ``px_lat`` and ``NEIGHBORS_REL``'s dx): each vehicle's offset from the centre
        of the lane holding its centre (SUMO's lane, see ``data/recorder.py``), + = left; 0 for absent slots.
        No extra SUMO query."""
        cfg, o = self.cfg, self.obs
        w, n = cfg.lane_width, cfg.num_lanes
        x = px_lat - road_y(r) + n * w  # the ego centre's distance from the right road edge
        lat = x + np.r_[0.0, o[K.NEIGHBORS_REL][r][:, 0]]
        offset = lat - (np.clip(np.floor(lat / w), 0, n - 1) + 0.5) * w
        o[K.EGO_LANE_OFFSET][r, 0] = offset[0]
        o[K.NEIGHBORS_LANE_OFFSET][r] = np.where(o[K.NEIGHBORS_MASK][r], offset[1:], 0.0)

    def _remember(self, hist: dict, vid: str, y: float, v: float, t: int) -> None:
        d = hist.get(vid)
        if d is None:
            d = hist[vid] = deque(maxlen=self.cfg.history_len)
        if not d or d[-1][0] != t:
            d.append((t, y, v))

    def _fill_history(self, out: np.ndarray, samples: deque, t: int) -> None:
        """Positions and speeds over the last h frames up to step ``t``, oldest first. Frames in which the vehicle
        was not observed (it only just came into view as a leader) are filled by constant-speed
        back-extrapolation from the next known sample."""
        h = self.cfg.history_len
        known = {s: (y, v) for s, y, v in samples}
        nxt_y, nxt_v = samples[-1][1], samples[-1][2]
        for j in range(h - 1, -1, -1):
            step = t - (h - 1 - j)
            if step in known:
                nxt_y, nxt_v = known[step]
            else:
                nxt_y = nxt_y - nxt_v * self.cfg.step_length
            out[j, 0], out[j, 1] = nxt_y, nxt_v

    def forget_old(self, t: int) -> None:
        """Drop the history of vehicles not seen as a leader in the last ``history_len`` steps."""
        horizon = t - self.cfg.history_len - 1
        for hist in self.history:
            for vid in [v for v, d in hist.items() if d[-1][0] < horizon]:
                del hist[vid]
