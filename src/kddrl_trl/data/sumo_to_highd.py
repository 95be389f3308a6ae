"""Record the simulator's heterogeneous background traffic as naturalistic data in the HighD format.

:func:`record_traffic` runs :class:`~kddrl_trl.envs.sim.HighwaySim` with no ego (after the simulator's own
warm-up) and turns each road into one HighD recording (``XX_tracks.csv``, ``XX_tracksMeta.csv``,
``XX_recordingMeta.csv``, 25 Hz) of the 420 m study section, plus the true per-vehicle driver parameters
(``XX_driverParams.csv``, not part of HighD; the HighD reader ignores it).

Return value: a list of :class:`RecordedTraffic`, one per road (recording ids 1..K for roads 0..K-1), each
holding the :class:`~kddrl_trl.data.highd.HighDRecording`, the ``driver_params`` DataFrame (columns
``id, driverType, v0, T, s0, a, b``), the mapping ``sumo_ids`` (HighD id -> SUMO vehicle id) and
``sim_lane`` (SUMO's lane index behind every tracks row). ``RecordedTraffic.write(directory)`` writes the
four files.

Conventions (HighD, ``kddrl_trl.data.highd``):

* Our road is driving direction 2: it travels toward +x in the lower half of the image, with y pointing
  down. The field of view is the study section: a vehicle is in a frame while its bounding box overlaps
  [0, section_length] longitudinally (front bumper > 0 and rear bumper < section_length).
* ``x`` is the box's rear (``x + width`` = front bumper = ``HighwaySim.longitudinal``), ``width`` the
  vehicle length, ``height`` 1.8 m. The lower lane markings are ``y0, y0 + w, ..., y0 + n w`` (y0 = 21.0
  for the default road); the box centre is ``y0 + n w - x_lat`` with x_lat the lateral position of the
  centre measured from the right edge of the road, so the rightmost lane (SUMO lane 0) has the largest y.
  The upper markings describe a mirrored carriageway (direction 1) without vehicles.
* ``laneId`` numbers lanes across the image like HighD: upper carriageway 2..n+1, lower n+3..2n+2 from top
  to bottom, so SUMO lane i is ``laneId = 2n + 2 - i`` and ``lane_index_in_direction`` gives back i.

Sampling: SUMO is sampled at every step (0.1 s) and interpolated to 25 Hz. Positions are interpolated
linearly in time; SUMO's default Euler update (x' = x + v' dt) makes them piecewise linear, so this is
exact for x and for the lateral position (constant lateral speed during a 2 s lane change). Speeds and
accelerations are interpolated linearly too (an approximation: SUMO holds them constant over a step).
Lane and neighbour ids come from the latest 0.1 s sample at or before the frame. The lateral acceleration
is the backward difference of SUMO's lateral speed. ``xVelocity``/``xAcceleration`` are the longitudinal
speed/acceleration (>= 0 speed, direction 2), ``yVelocity``/``yAcceleration`` are minus the lateral ones
(lateral + = left = up the image).

Lanes: SUMO moves a vehicle to its target lane exactly when the box centre reaches the lane marking (half
way through the 2 s manoeuvre, which falls on a 0.1 s sample), so SUMO's lane agrees with the lane of the
box centre everywhere except on a frame whose centre lies *on* the marking; there ``y`` is moved by at
most 1e-6 m into SUMO's lane, so that ``laneId``, :func:`~kddrl_trl.data.highd.lane_index_in_direction`
and the neighbour ids all agree on every row.

Neighbours (0 = none) are computed per 0.1 s sample from the lanes and positions of every vehicle on the
road (in view or not), but written only when the neighbour is in view at that frame. ``precedingId`` /
``followingId``: nearest ahead / behind in the same lane. ``left*`` / ``right*``: on the lane to the left
(lane + 1) / right in the direction of travel; ``*Alongside`` a vehicle whose box overlaps longitudinally
with this one (the one with the nearest centre if two do), ``*Preceding`` the nearest fully ahead,
``*Following`` the nearest fully behind. ``dhw`` is the bumper-to-bumper gap to ``precedingId``,
``thw = dhw / v``, ``ttc = dhw / (v - v_preceding)`` when closing in; -1 where undefined (no preceding
vehicle in view, v = 0, or not closing in). ``precedingXVelocity`` is 0 without a preceding vehicle.
``frontSightDistance`` = section_length - front bumper, ``backSightDistance`` = rear bumper - 0.

Vehicle ids are 1..N per recording in order of first appearance (then front-most first).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..atomic_files import write_text_atomic
from ..envs.network import ROAD_SPACING
from ..envs.observe import lane_and_offset
from ..highway_config import HighwayConfig
from .highd import (
    NEIGHBOUR_ID_COLUMNS,
    TRACKS_COLUMNS,
    TRACKS_META_COLUMNS,
    HighDRecording,
    format_markings,
    parse_markings,
    write_recording,
)

log = logging.getLogger(__name__)

__all__ = [
    "DRIVER_PARAMS_COLUMNS",
    "FRAME_RATE",
    "VEHICLE_HEIGHT",
    "RecordedTraffic",
    "driver_params_path",
    "lane_markings",
    "read_driver_params",
    "record_traffic",
    "recording_steps",
    "write_driver_params",
]

FRAME_RATE = 25  # Hz, HighD
VEHICLE_HEIGHT = 1.8  # m, box extent across the road (HighD "height")
DRIVER_PARAMS_COLUMNS = ("id", "driverType", "v0", "T", "s0", "a", "b")
_UPPER_Y0 = 8.0  # y of the top marking of the (empty) upper carriageway
_MEDIAN = 3.4  # m between the two carriageways
_TIE = 1e-6  # m: a box centre this close to a marking is moved into SUMO's lane
# neighbour columns, in the order of the arrays computed by _neighbours
_NEIGHBOUR_COLUMNS = NEIGHBOUR_ID_COLUMNS


@dataclass
class RecordedTraffic:
    """One recorded road: the HighD recording plus what HighD does not carry.

    Attributes:
        recording: the three HighD tables (``tracksMeta`` has the extra ``driverType`` column).
        driver_params: true per-vehicle parameters, columns ``id, driverType, v0, T, s0, a, b`` (SI units:
            m/s, s, m, m/s², m/s²), one row per vehicle of the recording, sorted by id.
        sumo_ids: HighD vehicle id -> SUMO vehicle id.
        sim_lane: SUMO's lane index (0 = rightmost) of the 0.1 s sample behind each ``recording.tracks`` row.
        road: the simulator road this recording comes from.
    """

    recording: HighDRecording
    driver_params: pd.DataFrame
    sumo_ids: dict[int, str] = field(default_factory=dict)
    sim_lane: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    road: int = 0

    @property
    def recording_id(self) -> int:
        return self.recording.recording_id

    def write(self, directory: str | Path) -> dict[str, Path]:
        """Write ``XX_tracks.csv``, ``XX_tracksMeta.csv``, ``XX_recordingMeta.csv`` and ``XX_driverParams.csv``
        (each atomically); returns the paths by kind (``"driverParams"`` for the last one)."""
        paths = write_recording(self.recording, directory)
        paths["driverParams"] = write_driver_params(self.recording_id, self.driver_params, directory)
        return paths


# -------------------------------------------------------------------------------------- driver params
def driver_params_path(directory: str | Path, recording_id: int) -> Path:
    return Path(directory) / f"{int(recording_id):02d}_driverParams.csv"


def write_driver_params(recording_id: int, params_df: pd.DataFrame, directory: str | Path) -> Path:
    """Write ``XX_driverParams.csv`` (columns ``id, driverType, v0, T, s0, a, b``) atomically; returns its path."""
    missing = [c for c in DRIVER_PARAMS_COLUMNS if c not in params_df.columns]
    if missing:
        raise ValueError(f"driver params of recording {recording_id}: missing column(s) {missing}")
    table = params_df.loc[:, list(DRIVER_PARAMS_COLUMNS)]
    path = driver_params_path(directory, recording_id)
    return write_text_atomic(path, table.to_csv(index=False, lineterminator="\n"))


def read_driver_params(directory: str | Path, recording_id: int) -> pd.DataFrame:
    """Read ``XX_driverParams.csv`` back (exact floats, ``id`` int64, ``driverType`` str)."""
    path = driver_params_path(directory, recording_id)
    dtypes = {"id": "int64", "driverType": str, **{c: "float64" for c in DRIVER_PARAMS_COLUMNS[2:]}}
    return pd.read_csv(path, dtype=dtypes, na_filter=False)


# -------------------------------------------------------------------------------------------- geometry
def lane_markings(cfg: HighwayConfig) -> tuple[np.ndarray, np.ndarray]:
    """(upper, lower) lane markings, top to bottom, as they are written (and read back) in recordingMeta."""
    n, w = cfg.num_lanes, cfg.lane_width
    lower0 = round(max(21.0, _UPPER_Y0 + n * w + _MEDIAN), 6)
    upper = parse_markings(format_markings(_UPPER_Y0 + np.arange(n + 1) * w))
    lower = parse_markings(format_markings(lower0 + np.arange(n + 1) * w))
    return upper, lower


def _geometric_lane(y: np.ndarray, marks: np.ndarray) -> np.ndarray:
    """Direction-2 lane index of box tops ``y`` (centre ``y + height / 2``), exactly as
    :func:`~kddrl_trl.data.highd.lane_index_in_direction` computes it."""
    n = len(marks) - 1
    from_top = np.clip(np.searchsorted(marks, y + VEHICLE_HEIGHT / 2.0, side="right") - 1, 0, n - 1)
    return n - 1 - from_top


# ------------------------------------------------------------------------------------------ neighbours
def _neighbours(
    k: np.ndarray, lane: np.ndarray, front: np.ndarray, length: np.ndarray, num_lanes: int, span: float
) -> np.ndarray:
    """Neighbour row indices (-1 = none) of every sample row, shape [n, 8] in ``_NEIGHBOUR_COLUMNS`` order.

    Rows are (sample index ``k``, lane, front bumper ``front``, ``length``) of all vehicles of one road; a
    neighbour is searched among the rows with the same ``k``. Fully vectorised: rows are grouped by
    (k, lane) into one sort key ``group * big + position``.
    """
    n = len(k)
    out = np.full((n, 8), -1, np.int64)
    if n == 0:
        return out
    rear = front - length
    group = k.astype(np.int64) * (num_lanes + 2) + lane.astype(np.int64) + 1  # lanes -1 and n: empty groups
    off = span + 10.0 * float(length.max()) + 10.0
    big = 4.0 * off
    # same lane: neighbours in (group, front) order
    order = np.lexsort((front, group))
    g_s = group[order]
    same_next = np.r_[g_s[1:] == g_s[:-1], False]
    same_prev = np.r_[False, g_s[1:] == g_s[:-1]]
    out[order[same_next], 0] = order[1:][same_next[:-1]]
    out[order[same_prev], 1] = order[:-1][same_prev[1:]]
    key_front = g_s * big + (front[order] + off)
    order_r = np.lexsort((rear, group))
    g_r = group[order_r]
    key_rear = g_r * big + (rear[order_r] + off)
    centre = front - length / 2.0
    for side, (col_p, col_a, col_f) in ((1, (2, 3, 4)), (-1, (5, 6, 7))):
        target = group + side
        # nearest fully ahead: smallest rear >= own front
        i = np.searchsorted(key_rear, target * big + (front + off), side="left")
        ok = i < n
        ok[ok] = g_r[i[ok]] == target[ok]
        out[ok, col_p] = order_r[i[ok]]
        # nearest fully behind: largest front <= own rear
        j = np.searchsorted(key_front, target * big + (rear + off), side="right") - 1
        ok = j >= 0
        ok[ok] = g_s[j[ok]] == target[ok]
        out[ok, col_f] = order[j[ok]]
        # alongside: the first rows after j in front order overlap if their rear < own front
        best = np.full(n, -1, np.int64)
        best_d = np.full(n, np.inf)
        for step in (1, 2):
            c = j + step
            ok = c < n
            ok[ok] = g_s[c[ok]] == target[ok]
            rows = np.flatnonzero(ok)
            cand = order[c[rows]]
            overlap = (rear[cand] < front[rows]) & (front[cand] > rear[rows])
            rows, cand = rows[overlap], cand[overlap]
            d = np.abs(centre[cand] - centre[rows])
            better = d < best_d[rows]
            best[rows[better]] = cand[better]
            best_d[rows[better]] = d[better]
        out[:, col_a] = best
    return out


# -------------------------------------------------------------------------------------------- recorder
class _Sampler:
    """Subscribes to every vehicle of a running :class:`~kddrl_trl.envs.sim.HighwaySim` and keeps their samples:
    ``chunks`` (per sample ``[g, k, front, x_lat, v, v_lat, a, lane]``, ``g`` the vehicle's index in
    ``vid_names``), each vehicle's road (``vid_road``) and its drawn driver parameters (``params``: the
    simulation forgets those of vehicles that left)."""

    def __init__(self, ls, sim):
        c = ls.constants
        self.ls, self.sim = ls, sim
        self.variables = [c.VAR_POSITION, c.VAR_SPEED, c.VAR_SPEED_LAT, c.VAR_ACCELERATION, c.VAR_LANE_INDEX]
        self.vid_index: dict[str, int] = {}  # SUMO id -> global vehicle index g
        self.vid_road: list[int] = []
        self.vid_names: list[str] = []
        self.chunks: list[np.ndarray] = []
        self.params: dict[str, dict] = {}

    def subscribe(self, ids) -> None:
        for vid in ids:
            self.ls.vehicle.subscribe(vid, self.variables)
            if vid not in self.vid_index:
                if vid in self.sim.vehicle_params:
                    self.params[vid] = self.sim.vehicle_params[vid]
                road = int(self.params[vid]["road"]) if vid in self.params else int(vid[1:].split(".")[0])
                self.vid_index[vid] = len(self.vid_names)
                self.vid_names.append(vid)
                self.vid_road.append(road)

    def sample(self, k: int) -> None:
        res = self.ls.vehicle.getAllSubscriptionResults()
        if not res:
            return
        pos_, speed_, lat_, acc_, lane_ = self.variables
        rows = [
            (self.vid_index[v], k, d[pos_][0], d[pos_][1], d[speed_], d[lat_], d[acc_], d[lane_])
            for v, d in res.items()
        ]
        self.chunks.append(np.array(rows, np.float64))


def recording_steps(duration_s: float, num_roads: int, dt: float) -> tuple[int, int]:
    """(simulation steps of ``dt`` after the first sample, 25 Hz frames) of a recording of ``duration_s``: enough
    steps to cover the last frame. Refuses a ``duration_s`` that is not a finite number > 0 and a ``num_roads``
    that is not an integer >= 1."""
    duration_s = float(duration_s)
    if not math.isfinite(duration_s) or duration_s <= 0:
        raise ValueError(f"duration_s must be a finite number > 0, got {duration_s!r}")
    if not isinstance(num_roads, (int, np.integer)) or num_roads < 1:
        raise ValueError(f"num_roads must be an integer >= 1, got {num_roads!r}")
    num_steps = round(duration_s / dt)
    num_frames = round(duration_s * FRAME_RATE)
    if num_steps * dt < (num_frames - 1) / FRAME_RATE - 1e-9:
        num_steps += 1
    return num_steps, num_frames


def record_traffic(
    cfg: HighwayConfig, duration_s: float, num_roads: int = 4, seed: int = 0, progress: bool = True
) -> list[RecordedTraffic]:
    """Record ``duration_s`` simulated seconds of background traffic on ``num_roads`` roads.

    Runs ``HighwaySim(cfg, num_roads, seed)`` (its warm-up included, no ego) and returns one
    :class:`RecordedTraffic` per road, recording ids 1..K, in the HighD format at 25 Hz (module docstring).
    The default 4 roads x 900 s are one hour of traffic in four ~15-minute recordings, like HighD's.
    Only one SUMO simulation can be open per process: no other ``HighwaySim``/``SumoHighwayEnv`` may be open.
    """
    from tqdm.auto import tqdm

    from ..envs.sim import HighwaySim, _libsumo

    dt = cfg.step_length
    num_steps, num_frames = recording_steps(duration_s, num_roads, dt)
    sim = HighwaySim(cfg, int(num_roads), seed=seed)
    try:
        x_off = cfg.entry_length
        y_off = cfg.num_lanes * cfg.lane_width
        sampler = _Sampler(_libsumo(), sim)
        sampler.subscribe(sampler.ls.vehicle.getIDList())
        sampler.sample(0)
        keep, no_accel = np.full(sim.num_roads, 1), np.zeros(sim.num_roads)
        with tqdm(
            total=round(num_steps * dt, 6),
            unit="s",
            desc="recording",
            disable=not progress,
            bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} simulated s [{elapsed}<{remaining}]",
        ) as bar:
            for k in range(1, num_steps + 1):
                sim.step(keep, no_accel)
                sampler.subscribe(sampler.ls.simulation.getDepartedIDList())
                sampler.sample(k)
                if k % 10 == 0 or k == num_steps:
                    bar.update(round(k * dt - bar.n, 6))
    finally:
        sim.close()

    chunks, vid_road, vid_names, params = sampler.chunks, sampler.vid_road, sampler.vid_names, sampler.params
    data = np.concatenate(chunks) if chunks else np.zeros((0, 8))
    data[:, 2] -= x_off  # front bumper from the start of the study section
    road_of = np.asarray(vid_road, np.int64)
    out = []
    for r in range(int(num_roads)):
        rows = data[road_of[data[:, 0].astype(np.int64)] == r] if len(data) else data
        out.append(
            _build_recording(
                cfg, r, rows, vid_names, params, duration_s, num_frames, seed, y_lat_offset=y_off - (-r * ROAD_SPACING)
            )
        )
    return out


@dataclass
class _Samples:
    """The 0.1 s samples of one road sorted by (vehicle, step), contiguous in step per vehicle."""

    k: np.ndarray  # simulation step of each sample
    front: np.ndarray  # x of the vehicle's front (m)
    lat_pos: np.ndarray  # x_lat from the right edge of the road (m)
    v: np.ndarray
    v_lat: np.ndarray
    acc: np.ndarray
    a_lat: np.ndarray
    lane: np.ndarray  # SUMO's lane index
    vehicles: np.ndarray  # the vehicle numbers, sorted
    start: np.ndarray  # each vehicle's first sample row
    count: np.ndarray  # each vehicle's number of samples
    k_first: np.ndarray
    k_last: np.ndarray


@dataclass
class _Frames:
    """The 25 Hz frames of every vehicle inside its own sampled time span, interpolated between samples."""

    f_lo: np.ndarray  # each vehicle's first frame
    f_start: np.ndarray  # each vehicle's first row among the frames
    veh_of: np.ndarray  # frame row -> vehicle index
    f: np.ndarray  # frame row -> frame number
    r0: np.ndarray  # frame row -> the sample row at or before it
    front: np.ndarray
    lat: np.ndarray
    v: np.ndarray
    vlat: np.ndarray
    a: np.ndarray
    alat: np.ndarray
    in_view: np.ndarray


@dataclass
class _View:
    """Each vehicle's in-view frame interval and its HighD id (0: never in view)."""

    first: np.ndarray
    last: np.ndarray
    rec_id: np.ndarray
    ranked: np.ndarray  # vehicle indices in HighD id order


def _samples(rows: np.ndarray, road: int, dt: float, y_lat_offset: float) -> _Samples:
    order = np.lexsort((rows[:, 1], rows[:, 0]))
    rows = rows[order]
    g = rows[:, 0].astype(np.int64)
    k = rows[:, 1].astype(np.int64)
    vehicles, start, count = np.unique(g, return_index=True, return_counts=True)
    k_first = k[start]
    k_last = k[start + count - 1]
    if np.any(k_last - k_first + 1 != count):
        raise RuntimeError(f"road {road}: a vehicle left and re-entered the simulation (non-contiguous samples)")
    v_lat = rows[:, 5]
    new_vehicle = np.zeros(len(g), bool)
    new_vehicle[start] = True
    a_lat = np.zeros(len(g))
    a_lat[1:] = np.diff(v_lat) / dt
    a_lat[new_vehicle] = 0.0
    return _Samples(
        k=k,
        front=rows[:, 2],
        lat_pos=rows[:, 3] + y_lat_offset,
        v=rows[:, 4],
        v_lat=v_lat,
        acc=rows[:, 6],
        a_lat=a_lat,
        lane=rows[:, 7].astype(np.int64),
        vehicles=vehicles,
        start=start,
        count=count,
        k_first=k_first,
        k_last=k_last,
    )


def _frames(s: _Samples, dt: float, num_frames: int, section_length: float, length_m: float) -> _Frames:
    per_frame = 1.0 / (FRAME_RATE * dt)  # steps per 25 Hz frame
    f_lo = np.ceil(s.k_first / per_frame - 1e-9).astype(np.int64)
    f_hi = np.minimum(np.floor(s.k_last / per_frame + 1e-9).astype(np.int64), num_frames - 1)
    n_f = np.maximum(f_hi - f_lo + 1, 0)
    veh_of = np.repeat(np.arange(len(s.vehicles)), n_f)
    f_start = np.r_[0, np.cumsum(n_f)[:-1]]
    f = f_lo[veh_of] + (np.arange(n_f.sum()) - f_start[veh_of])
    step = f * per_frame
    k0 = np.floor(step + 1e-9).astype(np.int64)
    alpha = np.clip(step - k0, 0.0, 1.0)
    alpha[alpha < 1e-9] = 0.0
    r0 = s.start[veh_of] + (k0 - s.k_first[veh_of])
    r1 = r0 + (alpha > 0)

    def lerp(x: np.ndarray) -> np.ndarray:
        return x[r0] + alpha * (x[r1] - x[r0])

    front = lerp(s.front)
    return _Frames(
        f_lo=f_lo,
        f_start=f_start,
        veh_of=veh_of,
        f=f,
        r0=r0,
        front=front,
        lat=lerp(s.lat_pos),
        v=lerp(s.v),
        vlat=lerp(s.v_lat),
        a=lerp(s.acc),
        alat=lerp(s.a_lat),
        in_view=(front > 0.0) & (front - length_m < section_length),
    )


def _view(fr: _Frames, nveh: int, road: int) -> _View:
    """In-view intervals (a front is non-decreasing, so each is contiguous) and HighD ids: the order of first
    appearance, the front-most first among simultaneous ones."""
    view_first = np.full(nveh, -1, np.int64)
    view_last = np.full(nveh, -2, np.int64)
    vi = fr.veh_of[fr.in_view]
    fi = fr.f[fr.in_view]
    np.maximum.at(view_last, vi, fi)
    first_tmp = np.full(nveh, np.iinfo(np.int64).max)
    np.minimum.at(first_tmp, vi, fi)
    seen = first_tmp != np.iinfo(np.int64).max
    view_first[seen] = first_tmp[seen]
    if np.any(np.bincount(vi, minlength=nveh)[seen] != (view_last - view_first + 1)[seen]):
        raise RuntimeError(f"road {road}: a vehicle left the view and came back")
    seen_idx = np.flatnonzero(seen)
    first_front = fr.front[fr.f_start[seen_idx] + (view_first[seen_idx] - fr.f_lo[seen_idx])]
    ranked = seen_idx[np.lexsort((-first_front, view_first[seen_idx]))]
    rec_id = np.zeros(nveh, np.int64)
    rec_id[ranked] = np.arange(1, len(ranked) + 1)
    return _View(view_first, view_last, rec_id, ranked)


def _neighbour_gaps(s: _Samples, fr: _Frames, view: _View, neighbours: np.ndarray, sel: np.ndarray, length_m: float):
    """Of each recording row ``sel``: the HighD ids of its 8 neighbours in view (0: none), and the gap, time
    gap, time to collision (-1: undefined) and speed of its preceding vehicle."""
    veh_of_row = np.repeat(np.arange(len(s.vehicles)), s.count)  # sample row -> vehicle index
    sf, sr0 = fr.f[sel], fr.r0[sel]
    nb_ids = np.zeros((len(sel), 8), np.int64)
    for j in range(8):
        nb_row = neighbours[sr0, j]
        has = nb_row >= 0
        nb_veh = np.where(has, veh_of_row[np.maximum(nb_row, 0)], 0)
        visible = has & (view.first[nb_veh] <= sf) & (sf <= view.last[nb_veh])
        nb_ids[:, j] = np.where(visible, view.rec_id[nb_veh], 0)
    prec_veh = np.where(nb_ids[:, 0] > 0, veh_of_row[np.maximum(neighbours[sr0, 0], 0)], 0)
    has_prec = nb_ids[:, 0] > 0
    prec_row = fr.f_start[prec_veh[has_prec]] + (sf[has_prec] - fr.f_lo[prec_veh[has_prec]])
    x_front = fr.front[sel]
    speed = fr.v[sel]
    dhw = np.full(len(sel), -1.0)
    thw = np.full(len(sel), -1.0)
    ttc = np.full(len(sel), -1.0)
    prec_v = np.zeros(len(sel))
    dhw[has_prec] = (fr.front[prec_row] - length_m) - x_front[has_prec]
    prec_v[has_prec] = fr.v[prec_row]
    moving = has_prec & (speed > 0)
    thw[moving] = dhw[moving] / speed[moving]
    closing = has_prec & (speed > prec_v)
    ttc[closing] = dhw[closing] / (speed[closing] - prec_v[closing])
    return nb_ids, dhw, thw, ttc, prec_v


def _image_y(centre: np.ndarray, sim_lane: np.ndarray, lower: np.ndarray, n_lanes: int, road: int) -> np.ndarray:
    """Image y of each row's box: a box centre within ``_TIE`` of a marking is moved into SUMO's lane (module
    docstring); any other centre outside SUMO's lane is logged."""
    y = centre - VEHICLE_HEIGHT / 2.0
    bad = _geometric_lane(y, lower) != sim_lane
    if bad.any():
        lo_c = lower[n_lanes - 1 - sim_lane[bad]] + _TIE  # centre range of SUMO's lane
        hi_c = lower[n_lanes - sim_lane[bad]] - _TIE
        near = np.min(np.abs(centre[bad, None] - lower[None, :]), axis=1) <= _TIE
        fixed = np.clip(centre[bad], lo_c, hi_c)
        centre[np.flatnonzero(bad)[near]] = fixed[near]
        y = centre - VEHICLE_HEIGHT / 2.0
        left = _geometric_lane(y, lower) != sim_lane
        if left.any():
            log.warning(
                "road %d: %d of %d rows have their box centre outside SUMO's lane by more than %g m",
                road,
                int(left.sum()),
                len(y),
                _TIE,
            )
    return y


def _tracks_meta(
    ids: np.ndarray,
    starts: np.ndarray,
    sf: np.ndarray,
    lane_id: np.ndarray,
    x_front: np.ndarray,
    speed: np.ndarray,
    gaps: tuple[np.ndarray, np.ndarray, np.ndarray],
    driver: list[str],
    length_m: float,
) -> pd.DataFrame:
    """HighD's ``tracksMeta`` of the recording rows (those of one id contiguous from ``starts``, sorted by frame);
    ``gaps``: the rows' dhw, thw and ttc (-1: undefined)."""
    dhw, thw, ttc = gaps
    n = len(ids)
    ends = np.r_[starts[1:], n] - 1
    frames_n = ends - starts + 1

    def seg_min_defined(x: np.ndarray, defined: np.ndarray) -> np.ndarray:
        if not len(x):
            return np.zeros(0)
        m = np.minimum.reduceat(np.where(defined, x, np.inf), starts)
        return np.where(np.isfinite(m), m, -1.0)

    lane_change = np.r_[False, (lane_id[1:] != lane_id[:-1]) & (ids[1:] == ids[:-1])]
    return pd.DataFrame(
        {
            "id": ids[starts] if n else np.zeros(0, np.int64),
            "width": length_m,
            "height": VEHICLE_HEIGHT,
            "initialFrame": sf[starts] if n else np.zeros(0, np.int64),
            "finalFrame": sf[ends] if n else np.zeros(0, np.int64),
            "numFrames": frames_n,
            "class": "Car",
            "drivingDirection": 2,
            "traveledDistance": x_front[ends] - x_front[starts] if n else np.zeros(0),
            "minXVelocity": np.minimum.reduceat(speed, starts) if n else np.zeros(0),
            "maxXVelocity": np.maximum.reduceat(speed, starts) if n else np.zeros(0),
            "meanXVelocity": np.add.reduceat(speed, starts) / frames_n if n else np.zeros(0),
            "minDHW": seg_min_defined(dhw, dhw >= 0),
            "minTHW": seg_min_defined(thw, thw >= 0),
            "minTTC": seg_min_defined(ttc, ttc >= 0),
            "numLaneChanges": np.add.reduceat(lane_change.astype(np.int64), starts) if n else np.zeros(0, np.int64),
            "driverType": driver,
        },
        columns=[*TRACKS_META_COLUMNS, "driverType"],
    )


def _recording_meta(
    cfg: HighwayConfig, road: int, duration_s: float, num_frames: int, meta: pd.DataFrame, upper, lower
) -> pd.DataFrame:
    """HighD's ``recordingMeta``: road ``road``'s recording starts ``road * duration_s`` after 08:00."""
    hh, mm = divmod(8 * 60 + round(road * duration_s / 60.0), 60)
    n_rec = len(meta)
    return pd.DataFrame(
        [
            {
                "id": road + 1,
                "frameRate": FRAME_RATE,
                "locationId": 0,
                "speedLimit": float(cfg.v_max),
                "month": "06.2024",
                "weekDay": "Tue",
                "startTime": f"{hh % 24:02d}:{mm:02d}",
                "duration": float(num_frames / FRAME_RATE),
                "totalDrivenDistance": float(meta["traveledDistance"].sum()),
                "totalDrivenTime": float(meta["numFrames"].to_numpy().sum() / FRAME_RATE),
                "numVehicles": n_rec,
                "numCars": n_rec,
                "numTrucks": 0,
                "upperLaneMarkings": format_markings(upper),
                "lowerLaneMarkings": format_markings(lower),
            }
        ]
    )


def _build_recording(
    cfg: HighwayConfig,
    road: int,
    rows: np.ndarray,
    vid_names: list[str],
    params: dict,
    duration_s: float,
    num_frames: int,
    seed: int,
    y_lat_offset: float,
    lanes_from_position: bool = False,
) -> RecordedTraffic:
    """Turn the 0.1 s samples of one road into one HighD recording (see the module docstring), in steps: the
    samples per vehicle (:func:`_samples`), their 25 Hz frames (:func:`_frames`), who is in view and their HighD
    ids (:func:`_view`), each recording row's neighbours and gaps (:func:`_neighbour_gaps`) and image y
    (:func:`_image_y`); then the four tables: tracks, tracksMeta (:func:`_tracks_meta`), the drivers' parameters
    and recordingMeta (:func:`_recording_meta`). ``lanes_from_position``: a frame's lane is the lane its
    interpolated box centre is in (for a simulator whose lane switches fall between samples, HighwayEnv), not
    the lane of the sample at or before it (SUMO, whose switches fall on samples)."""
    dt, n_lanes = cfg.step_length, cfg.num_lanes
    length_m = float(cfg.vehicle_length)
    upper, lower = lane_markings(cfg)
    s = _samples(rows, road, dt, y_lat_offset)
    neighbours = _neighbours(s.k, s.lane, s.front, np.full(len(s.k), length_m), n_lanes, cfg.road_length)
    fr = _frames(s, dt, num_frames, cfg.section_length, length_m)
    view = _view(fr, len(s.vehicles), road)

    sel = np.flatnonzero(fr.in_view)  # the recording's rows, sorted by (id, frame)
    sel = sel[np.lexsort((fr.f[sel], view.rec_id[fr.veh_of[sel]]))]
    sv, sf = fr.veh_of[sel], fr.f[sel]
    nb_ids, dhw, thw, ttc, prec_v = _neighbour_gaps(s, fr, view, neighbours, sel, length_m)
    sim_lane = s.lane[fr.r0[sel]]
    if lanes_from_position:
        sim_lane = lane_and_offset(fr.lat[sel], cfg.lane_width, n_lanes)[0]
    y = _image_y(lower[-1] - fr.lat[sel], sim_lane, lower, n_lanes, road)
    lane_id = 2 * n_lanes + 2 - sim_lane
    ids = view.rec_id[sv]
    x_front, speed = fr.front[sel], fr.v[sel]
    tracks = pd.DataFrame(
        {
            "frame": sf,
            "id": ids,
            "x": x_front - length_m,
            "y": y,
            "width": length_m,
            "height": VEHICLE_HEIGHT,
            "xVelocity": speed,
            "yVelocity": 0.0 - fr.vlat[sel],
            "xAcceleration": fr.a[sel],
            "yAcceleration": 0.0 - fr.alat[sel],
            "frontSightDistance": cfg.section_length - x_front,
            "backSightDistance": x_front - length_m,
            "dhw": dhw,
            "thw": thw,
            "ttc": ttc,
            "precedingXVelocity": prec_v,
            **{col: nb_ids[:, j] for j, col in enumerate(_NEIGHBOUR_COLUMNS)},
            "laneId": lane_id,
        },
        columns=list(TRACKS_COLUMNS),
    )

    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]]) if len(sel) else np.zeros(0, np.int64)
    names = [vid_names[s.vehicles[i]] for i in (sv[starts] if len(sel) else np.zeros(0, np.int64))]
    driver = [params.get(nm, {}).get("driver", "inserted") for nm in names]
    meta = _tracks_meta(ids, starts, sf, lane_id, x_front, speed, (dhw, thw, ttc), driver, length_m)
    assert len(meta) == len(view.ranked)
    driver_params = pd.DataFrame(
        {
            "id": meta["id"].to_numpy(),
            "driverType": driver,
            **{p: [float(params.get(nm, {}).get(p, np.nan)) for nm in names] for p in ("v0", "T", "s0", "a", "b")},
        },
        columns=list(DRIVER_PARAMS_COLUMNS),
    )
    recording_meta = _recording_meta(cfg, road, duration_s, num_frames, meta, upper, lower)
    recording = HighDRecording(road + 1, tracks, meta, recording_meta)
    return RecordedTraffic(
        recording=recording,
        driver_params=driver_params,
        sumo_ids={int(i): nm for i, nm in zip(meta["id"], names)},
        sim_lane=sim_lane.astype(np.int64),
        road=road,
    )


# ------------------------------------------------------------------------------------------ to disk
#: paper (naturalistic data used for KDDRL's trajGAN / lcGAN): vehicles in one hour, share of lane changers
PAPER_VEHICLES_PER_HOUR = 2325
PAPER_LANE_CHANGER_SHARE = 0.158


def summarize_recorded(recorded: list[RecordedTraffic]) -> dict:
    """Vehicle count, lane changers and driver types over all recordings."""
    metas = [r.recording.tracks_meta for r in recorded]
    meta = pd.concat(metas, ignore_index=True) if metas else pd.DataFrame(columns=["numLaneChanges", "driverType"])
    n = len(meta)
    changers = int((meta["numLaneChanges"] > 0).sum())
    return {
        "vehicles": n,
        "lane_changers": changers,
        "lane_changer_share": changers / n if n else float("nan"),
        "driver_types": {str(k): int(v) for k, v in meta["driverType"].value_counts().sort_index().items()},
        "simulated_hours": sum(float(r.recording.meta["duration"]) for r in recorded) / 3600.0,
    }


def record_to_directory(
    cfg: HighwayConfig,
    out_dir: str | Path,
    duration_s: float,
    num_roads: int = 4,
    seed: int = 0,
    progress: bool = True,
    recorder: Callable[..., list[RecordedTraffic]] | None = None,
) -> dict:
    """``recorder`` (default :func:`record_traffic`, our SUMO traffic; HighwayEnv's:
    :func:`kddrl_trl.data.synthetic.traffic_recorder`), then write every non-empty recording into ``out_dir``;
    returns :func:`summarize_recorded` plus ``wall_s``, ``wall_record_s``, ``out_dir`` and ``skipped`` (ids of
    roads where no vehicle entered the view, which HighD's format cannot hold)."""
    import time

    t0 = time.perf_counter()
    recorded = (recorder or record_traffic)(cfg, duration_s, num_roads=num_roads, seed=seed, progress=progress)
    wall_record = time.perf_counter() - t0
    skipped = []
    for rec in recorded:
        if len(rec.recording.tracks) == 0:
            skipped.append(rec.recording_id)
            continue
        rec.write(out_dir)
    summary = summarize_recorded(recorded)
    summary.update(wall_s=time.perf_counter() - t0, wall_record_s=wall_record, out_dir=str(out_dir), skipped=skipped)
    return summary
