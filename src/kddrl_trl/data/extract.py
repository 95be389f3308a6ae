"""Naturalistic training samples for trajGAN and lcGAN, extracted from 10 Hz tracks (``TRACKS10.md``).

Two kinds of samples are cut from :func:`kddrl_trl.data.tracks.longitudinal_tracks` tables. All positions
are longitudinal FRONT-bumper positions ``y`` (m) in the direction-free frame of ``tracks10`` (every vehicle
travels toward +y; for HighD driving direction 1, ``y = -x`` is negative, so consumers should work with
*relative* positions), speeds in m/s, time steps of ``1 / hz`` s (0.1 s). ``N`` is the number of samples.
Float fields are ``float32``, ids and codes ``int64``, masks ``bool``.

``leaders`` (:func:`leader_samples`, trajGAN, paper §III.B): one sample per (ego vehicle, 10 Hz frame ``t``,
leader slot) whose leader's track covers ``t - history + 1 .. t + horizon`` and is within ``sensing_range``.

================  ===============  =======  ==========================================================
field             shape            dtype    meaning
================  ===============  =======  ==========================================================
ego               [N, 2]           float32  ego (y m, v m/s) at t
slot              [N]              int64    0 = a (left leader), 1 = b (current lane), 2 = c (right)
history           [N, H, 2]        float32  leader (y m, v m/s) at t-H+1 .. t, oldest first, last = t
ahead             [N, 3]           float32  (y m, v m/s, present 0/1) of the leader's own preceding
                                            vehicle at t (within sensing_range of the leader); zeros if
                                            absent
ahead_length      [N]              float32  length (m) of that vehicle (``IDMParams.length`` if absent),
                                            used as the IDM gap correction ``y_ahead - y - length``
prior             [N, horizon]     float32  TC^T: IDM prior positions (m) of the leader at t+1..t+horizon,
                                            ``idm_rollout(history[:, -1, 0], history[:, -1, 1],
                                            ahead[:, 0], ahead[:, 1], ahead[:, 2] > 0, horizon, 1 / hz,
                                            replace(idm, length=ahead_length))`` (Eq. 11-12)
future            [N, horizon]     float32  TR^T: true leader positions y (m) at t+1..t+horizon
leader_length     [N]              float32  leader length (m)
recording_id      [N]              int64    recording id
vehicle_id        [N]              int64    ego vehicle id
leader_id         [N]              int64    leader vehicle id
frame             [N]              int64    10 Hz frame t (t / hz seconds from the recording start)
leader_driver     [N]              int64    index of the leader's driver_type in ``DRIVER_TYPES``
================  ===============  =======  ==========================================================

``lane_changes`` (:func:`lane_change_samples`, lcGAN, paper §III.C.1, Eq. 16-19): one sample per ego
vehicle and 10 Hz frame ``t`` (every ``stride`` frames) whose track covers ``t .. t + window``.

The label (paper §IV.F: "we extracted lane-changing maneuvers using a 2-second sliding time window"): the
window is the ``window`` frames (2 s) *after* the observation time ``t``, because ``P_lcGAN^t`` is the prior
of the lane-change decision taken at ``t`` for the next 2 s (the D3QN's decision period, §III.D).
``label="within"`` (default, the reading the paper's text supports: a window is a lane-changing sample when
it contains a lane-changing manoeuvre) is the direction of the FIRST lane change (lane-index switch) in
``t+1 .. t+window``, keep if there is none; ``label="end"`` is the net change ``sign(lane(t+window) -
lane(t))``. The two differ only on windows holding two changes (e.g. left and back: "within" says left,
"end" says keep); on our default recordings none of the 7,603 lane-change windows differ (SUMO never
changes twice within 2 s), so the choice matters only for naturalistic data such as HighD.

================  ===============  =======  ==========================================================
field             shape            dtype    meaning
================  ===============  =======  ==========================================================
label             [N]              int64    0 left / 1 keep / 2 right (see above; lane 0 = rightmost,
                                            left = lane + 1); ``keys.LC_ACTIONS``
s_av              [N, 4]           float32  S_AV: ego (v m/s, vx_lat m/s + = left, lane index as float,
                                            lane_offset m from its lane's centre, + = left)
rel               [N, 6, 4]        float32  S_SV: slots a..f (left/current/right leader, left/current/
                                            right follower) x (dx lateral m, dy longitudinal m, dvx
                                            lateral m/s, dvy longitudinal m/s), neighbour minus ego, as
                                            ``keys.NEIGHBORS_REL``; zeros where absent
lane_offset       [N, 6]           float32  each neighbour's offset from its own lane's centre (m, + =
                                            left), as ``keys.NEIGHBORS_LANE_OFFSET``; zeros where absent
mask              [N, 6]           bool     slot present within sensing_range (``keys.NEIGHBORS_MASK``)
key_gaps          [N, 3, 2]        float32  true y of leaders a, b, c at t+10 and t+20 minus ego y at t
                                            (m); the real-data counterpart of ``keys.PRED_KEY_GAPS``
key_gaps_mask     [N, 3]           bool     leader present and its track reaches t+20
num_lanes         [N]              int64    lanes in the ego's driving direction
recording_id      [N]              int64    recording id
vehicle_id        [N]              int64    ego vehicle id
frame             [N]              int64    10 Hz frame t
driver            [N]              int64    index of the ego's driver_type in ``DRIVER_TYPES``
================  ===============  =======  ==========================================================

The condition vector C of Eq. 16 is left unassembled (``s_av``, ``rel``/``mask``, ``key_gaps``/
``key_gaps_mask``) so the lcGAN decides how to concatenate and normalise; these fields come from
:func:`kddrl_trl.generative.gan_inputs.lane_change_condition`, the function the RL-time predictor builds them with.

On disk (:func:`extract_dataset`): ``out_dir/<kind>/<split>/`` is ``TensorDict.memmap`` output for
``kind`` in (``leaders``, ``lane_changes``) and ``split`` in (``train``, ``val``, ``test``), read back with
:func:`load_dataset`; ``out_dir/meta.json`` holds counts, parameters, ``DRIVER_TYPES`` and the content hash
of the input recordings. Splits are by vehicle: lane-change samples by the ego ``(recording_id,
vehicle_id)``, leader samples by the *leader* ``(recording_id, leader_id)`` (the vehicle whose trajectory
is the data), using one vehicle -> split assignment for both kinds.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd
import torch
from tensordict import TensorDict
from tqdm.auto import tqdm

from kddrl_trl import keys as K
from kddrl_trl.atomic_files import write_json_atomic
from kddrl_trl.data.highd import HighDRecording
from kddrl_trl.data.tracks import TRACKS10_COLUMNS, longitudinal_tracks, tracks_hz, vehicle_num_lanes
from kddrl_trl.generative.gan_inputs import DRIVER_TYPES, KEY_STEPS, lane_change_condition
from kddrl_trl.physics.idm import IDMParams, idm_rollout

__all__ = [
    "DRIVER_TYPES",
    "KEY_STEPS",
    "SPLITS",
    "KINDS",
    "SCHEMA_VERSION",
    "driver_codes",
    "leader_samples",
    "lane_change_samples",
    "LABELS",
    "window_labels",
    "split_by_vehicle",
    "extract_dataset",
    "load_dataset",
]

SPLITS = ("train", "val", "test")
KINDS = ("leaders", "lane_changes")
SCHEMA_VERSION = 1
_IDM_CHUNK = 1 << 18

_LEADER_COLS = ("left_preceding_id", "preceding_id", "right_preceding_id")
_FOLLOWER_COLS = ("left_following_id", "following_id", "right_following_id")
_ALONGSIDE = {0: "left_alongside_id", 2: "right_alongside_id"}  # side index (0 left, 2 right) -> column


# ----------------------------------------------------------------------------------------- helpers
def driver_codes(driver_type) -> np.ndarray:
    """int64 index into :data:`DRIVER_TYPES` of each driver_type string ("" / NaN -> "unknown")."""
    s = pd.Series(np.asarray(driver_type, dtype=object)).fillna("").astype(str).replace("", "unknown")
    lookup = {name: i for i, name in enumerate(DRIVER_TYPES)}
    codes = s.map(lookup)
    if codes.isna().any():
        unknown = sorted(set(s[codes.isna()]))
        raise ValueError(f"unknown driver_type(s) {unknown}; expected one of {list(DRIVER_TYPES)} or ''")
    return codes.to_numpy(dtype=np.int64)


def _positive_int(name: str, value, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _positive_float(name: str, value) -> float:
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}") from None
    if not (np.isfinite(f) and f > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return f


class _Index:
    """Row arithmetic on a tracks10 table sorted by (recording, vehicle, frame) with consecutive frames."""

    def __init__(self, tracks: pd.DataFrame):
        missing = [c for c in TRACKS10_COLUMNS if c not in tracks.columns]
        if missing:
            raise ValueError(f"tracks table is missing column(s) {missing} (see TRACKS10.md)")
        if len(tracks) == 0:
            raise ValueError("tracks table has no rows (no vehicles)")
        self.hz = tracks_hz(tracks)
        rec = tracks["recording_id"].to_numpy(dtype=np.int64)
        vid = tracks["vehicle_id"].to_numpy(dtype=np.int64)
        frame = tracks["frame"].to_numpy(dtype=np.int64)
        order = np.lexsort((frame, vid, rec))
        if not np.array_equal(order, np.arange(len(order))):
            tracks = tracks.iloc[order].reset_index(drop=True)
            rec, vid, frame = rec[order], vid[order], frame[order]
        self.rec, self.vid, self.frame = rec, vid, frame
        new = np.r_[True, (rec[1:] != rec[:-1]) | (vid[1:] != vid[:-1])]
        bad = ~new & (np.r_[1, np.diff(frame)] != 1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"tracks: frames of vehicle {vid[i]} (recording {rec[i]}) are not consecutive "
                f"(frame {frame[i - 1]} then {frame[i]})"
            )
        self.starts = np.flatnonzero(new)
        self.lens = np.diff(np.r_[self.starts, len(rec)])
        self.first = frame[self.starts]
        self.vkey = rec[self.starts] * (1 << 32) + vid[self.starts]  # sorted
        self.veh = np.repeat(np.arange(len(self.starts)), self.lens)  # vehicle index of each row
        self.pos = np.arange(len(rec)) - self.starts[self.veh]  # position of each row in its vehicle
        self.cols = {}
        for c in ("y", "v", "x_lat", "vx_lat", "lane_offset", "length"):
            values = tracks[c].to_numpy(dtype=np.float64)
            bad = ~np.isfinite(values)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"tracks: column {c!r} of vehicle {vid[i]} (recording {rec[i]}) is not finite "
                    f"({values[i]}) at frame {frame[i]}"
                )
            self.cols[c] = values
        for c in ("lane", *_LEADER_COLS, *_FOLLOWER_COLS, "left_alongside_id", "right_alongside_id"):
            self.cols[c] = tracks[c].to_numpy(dtype=np.int64)
        self.driver = driver_codes(tracks["driver_type"].to_numpy(dtype=object))

    def rows_at(self, rec: np.ndarray, vid: np.ndarray, frame: np.ndarray) -> np.ndarray:
        """Row of vehicle (rec, vid) at ``frame``, or -1 where there is none (vid 0 = no vehicle)."""
        key = rec * (1 << 32) + vid
        j = np.clip(np.searchsorted(self.vkey, key), 0, len(self.vkey) - 1)
        off = frame - self.first[j]
        ok = (vid != 0) & (self.vkey[j] == key) & (off >= 0) & (off < self.lens[j])
        return np.where(ok, self.starts[j] + off, -1)

    def covers(self, rows: np.ndarray, back: int, ahead: int) -> np.ndarray:
        """Whether the vehicle of each row (>= 0) has rows ``back`` before and ``ahead`` after it."""
        r = np.maximum(rows, 0)
        return (rows >= 0) & (self.pos[r] >= back) & (self.pos[r] + ahead < self.lens[self.veh[r]])

    def side_neighbor(self, ego: np.ndarray, side: int, leader: bool) -> np.ndarray:
        """Row of the ego's neighbour in a side lane (0 left, 1 current, 2 right), leader or follower.

        For the side lanes, an empty preceding/following slot is filled with the alongside vehicle when its
        front is ahead of (leader) / not ahead of (follower) the ego's front.
        """
        col = (_LEADER_COLS if leader else _FOLLOWER_COLS)[side]
        rec, frame = self.rec[ego], self.frame[ego]
        rows = self.rows_at(rec, self.cols[col][ego], frame)
        if side in _ALONGSIDE:
            along = self.rows_at(rec, self.cols[_ALONGSIDE[side]][ego], frame)
            ahead = self.cols["y"][np.maximum(along, 0)] > self.cols["y"][ego]
            use = (rows < 0) & (along >= 0) & (ahead if leader else ~ahead)
            rows = np.where(use, along, rows)
        return rows


def _check_idm(idm) -> None:
    if not isinstance(idm, IDMParams):
        raise ValueError(f"idm must be an IDMParams, got {type(idm).__name__}")
    for f in dataclasses.fields(idm):
        value = getattr(idm, f.name)
        if torch.is_tensor(value) and value.numel() != 1:
            raise ValueError(f"idm.{f.name} must be a scalar here (one parameter set for all leaders)")
        value = float(value)
        if not (np.isfinite(value) and (value > 0 or (f.name == "length" and value >= 0))):
            raise ValueError(f"idm.{f.name} must be finite and > 0, got {value}")


def _f32(x) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(x), dtype=torch.float32)


def _i64(x) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(x), dtype=torch.int64)


def _prior(y0, v0, ahead, ahead_length, horizon, dt, idm: IDMParams) -> torch.Tensor:
    """Batched ``idm_rollout`` in chunks (float32)."""
    out = []
    for s in range(0, max(len(y0), 1), _IDM_CHUNK):
        sl = slice(s, s + _IDM_CHUNK)
        params = dataclasses.replace(idm, length=ahead_length[sl])
        out.append(
            idm_rollout(
                y0[sl], v0[sl], ahead[sl, 0], ahead[sl, 1], ahead[sl, 2] > 0, steps=horizon, dt=dt, params=params
            )
        )
    return torch.cat(out).reshape(len(y0), horizon)


# ------------------------------------------------------------------------------------ leader samples
def leader_samples(
    tracks: pd.DataFrame,
    history: int = 10,
    horizon: int = 20,
    stride: int = 1,
    idm: IDMParams = IDMParams(),
    sensing_range: float = 200.0,
) -> TensorDict:
    """trajGAN samples: leader history, IDM prior TC^T and true future TR^T (module docstring schema).

    The ego is every vehicle at every 10 Hz frame ``t`` with ``t % stride == 0``; its leaders are read from
    ``left_preceding_id`` / ``preceding_id`` / ``right_preceding_id`` (slots a, b, c), a left/right alongside
    vehicle whose front is ahead of the ego's front filling an empty side slot. Leaders farther than
    ``sensing_range`` (|dy|) or whose track does not cover ``t - history + 1 .. t + horizon`` are skipped.
    """
    history = _positive_int("history", history)
    horizon = _positive_int("horizon", horizon)
    stride = _positive_int("stride", stride)
    sensing_range = _positive_float("sensing_range", sensing_range)
    _check_idm(idm)
    ix = _Index(tracks)
    c = ix.cols
    egos = np.flatnonzero(ix.frame % stride == 0)
    ego_l, slot_l, lead_l = [], [], []
    for slot in range(3):
        lr = ix.side_neighbor(egos, slot, leader=True)
        ok = ix.covers(lr, history - 1, horizon)
        ok &= np.abs(c["y"][np.maximum(lr, 0)] - c["y"][egos]) <= sensing_range
        ego_l.append(egos[ok])
        lead_l.append(lr[ok])
        slot_l.append(np.full(int(ok.sum()), slot, dtype=np.int64))
    ego, slot, lead = np.concatenate(ego_l), np.concatenate(slot_l), np.concatenate(lead_l)
    order = np.lexsort((slot, ego))  # by ego row, then slot
    ego, slot, lead = ego[order], slot[order], lead[order]
    n = len(ego)

    hist_rows = lead[:, None] + np.arange(-history + 1, 1)
    fut_rows = lead[:, None] + np.arange(1, horizon + 1)
    hist = np.stack([c["y"][hist_rows], c["v"][hist_rows]], -1).reshape(n, history, 2)
    # the leader's own preceding vehicle at t, within sensing range of the leader
    ar = ix.rows_at(ix.rec[lead], c["preceding_id"][lead], ix.frame[lead])
    has = ar >= 0
    has &= np.abs(c["y"][np.maximum(ar, 0)] - c["y"][lead]) <= sensing_range
    a_safe = np.maximum(ar, 0)
    ahead = np.stack(
        [np.where(has, c["y"][a_safe], 0.0), np.where(has, c["v"][a_safe], 0.0), has.astype(np.float64)], -1
    ).reshape(n, 3)
    ahead_length = np.where(has, c["length"][a_safe], float(idm.length))

    hist_t, ahead_t, alen_t = _f32(hist), _f32(ahead), _f32(ahead_length)
    prior = _prior(hist_t[:, -1, 0], hist_t[:, -1, 1], ahead_t, alen_t, horizon, 1.0 / ix.hz, idm)
    return TensorDict(
        {
            "ego": _f32(np.stack([c["y"][ego], c["v"][ego]], -1).reshape(n, 2)),
            "slot": _i64(slot),
            "history": hist_t,
            "ahead": ahead_t,
            "ahead_length": alen_t,
            "prior": prior,
            "future": _f32(c["y"][fut_rows].reshape(n, horizon)),
            "leader_length": _f32(c["length"][lead]),
            "recording_id": _i64(ix.rec[ego]),
            "vehicle_id": _i64(ix.vid[ego]),
            "leader_id": _i64(ix.vid[lead]),
            "frame": _i64(ix.frame[ego]),
            "leader_driver": _i64(ix.driver[lead]),
        },
        batch_size=[n],
    )


# ------------------------------------------------------------------------------- lane-change samples
def _num_lanes_per_row(ix: _Index, tracks: pd.DataFrame, rows: np.ndarray, num_lanes) -> np.ndarray:
    if num_lanes is None:
        num_lanes = tracks.attrs.get("num_lanes")
    if num_lanes is None:  # fallback: lanes seen in the recording (both directions have equally many in HighD)
        rec = ix.rec
        uniq, inv = np.unique(rec, return_inverse=True)
        top = np.zeros(len(uniq), dtype=np.int64)
        np.maximum.at(top, inv, ix.cols["lane"])
        return (top[inv] + 1)[rows]
    if isinstance(num_lanes, (int, np.integer)):
        return np.full(len(rows), int(num_lanes), dtype=np.int64)
    series = num_lanes if isinstance(num_lanes, pd.Series) else pd.Series(dict(num_lanes))
    if not isinstance(series.index, pd.MultiIndex):
        raise ValueError("num_lanes must be an int, or a mapping / Series keyed by (recording_id, vehicle_id)")
    idx = pd.MultiIndex.from_arrays([ix.rec[rows], ix.vid[rows]])
    values = series.reindex(idx).to_numpy(dtype=np.float64)
    if np.isnan(values).any():
        i = int(np.flatnonzero(np.isnan(values))[0])
        raise ValueError(f"num_lanes has no entry for vehicle {ix.vid[rows][i]} (recording {ix.rec[rows][i]})")
    return values.astype(np.int64)


#: the lcGAN window labels (``label=``), as stated in the metrics shipped with the weights
LABELS = {
    "within": "direction of the first lane change (lane-index switch) in the window of `window` frames after t; "
    "keep if none",
    "end": "sign of lane(t + window) - lane(t) (the net change over the window)",
}


def _check_label(label) -> str:
    if label not in LABELS:
        raise ValueError(f"label must be one of {list(LABELS)}, got {label!r}")
    return label


def window_labels(lane_now: np.ndarray, lanes_after: np.ndarray, label: str = "within") -> np.ndarray:
    """0 left / 1 keep / 2 right of windows: ``lane_now [N]`` at ``t`` and ``lanes_after [N, window]`` at
    ``t+1 .. t+window``; ``label`` "within" (first change in the window) or "end" (net change), module doc."""
    diff = lanes_after - lane_now[:, None]
    if _check_label(label) == "end":
        change = diff[:, -1]
    else:
        first = (diff != 0).argmax(axis=1)
        change = diff[np.arange(len(diff)), first] if len(diff) else np.zeros(0, dtype=np.int64)
    return (1 - np.sign(change)).astype(np.int64)  # +1 (left) -> 0, 0 -> 1, -1 (right) -> 2


def lane_change_samples(
    tracks: pd.DataFrame,
    window: int = 20,
    stride: int = 1,
    sensing_range: float = 200.0,
    num_lanes=None,
    label: str = "within",
) -> TensorDict:
    """lcGAN samples: 2 s sliding windows labelled left / keep / right, with the condition C of Eq. 16.

    ``num_lanes``: an int, or a Series / mapping keyed by ``(recording_id, vehicle_id)``; by default
    ``tracks.attrs["num_lanes"]`` if set, else the number of lanes seen in each recording. ``label``:
    "within" (first lane change in the window) or "end" (net change over it), see the module docstring.
    """
    _check_label(label)
    window = _positive_int("window", window)
    stride = _positive_int("stride", stride)
    sensing_range = _positive_float("sensing_range", sensing_range)
    ix = _Index(tracks)
    c = ix.cols
    egos = np.flatnonzero((ix.frame % stride == 0) & ix.covers(np.arange(len(ix.frame)), 0, window))
    n = len(egos)
    labels = window_labels(c["lane"][egos], c["lane"][egos[:, None] + np.arange(1, window + 1)], label)

    rel = np.zeros((n, 6, 4))
    nb_offset = np.zeros((n, 6))
    mask = np.zeros((n, 6), dtype=bool)
    key_gaps = np.full((n, 3, 2), np.nan)  # NaN: the leader's track ends before the key step
    ey = c["y"][egos]
    for s in range(6):
        rows = ix.side_neighbor(egos, s % 3, leader=s < 3)
        r = np.maximum(rows, 0)
        mask[:, s] = (rows >= 0) & (np.abs(c["y"][r] - ey) <= sensing_range)
        rel[:, s] = np.stack(
            [
                c["x_lat"][r] - c["x_lat"][egos],
                c["y"][r] - ey,
                c["vx_lat"][r] - c["vx_lat"][egos],
                c["v"][r] - c["v"][egos],
            ],
            -1,
        ).reshape(n, 4)
        nb_offset[:, s] = c["lane_offset"][r]
        if s < 3:
            reach = ix.covers(rows, 0, max(KEY_STEPS))
            for j, step in enumerate(KEY_STEPS):
                key_gaps[reach, s, j] = c["y"][r[reach] + step] - ey[reach]
    condition = lane_change_condition(
        _f32(c["v"][egos]),
        _f32(c["vx_lat"][egos]),
        _i64(c["lane"][egos]),
        _f32(c["lane_offset"][egos]),
        _f32(rel),
        torch.as_tensor(mask),
        _f32(nb_offset),
        _f32(key_gaps),
    )
    return TensorDict(
        {
            "label": _i64(labels),
            **condition,
            "num_lanes": _i64(_num_lanes_per_row(ix, tracks, egos, num_lanes)),
            "recording_id": _i64(ix.rec[egos]),
            "vehicle_id": _i64(ix.vid[egos]),
            "frame": _i64(ix.frame[egos]),
            "driver": _i64(ix.driver[egos]),
        },
        batch_size=[n],
    )


# ----------------------------------------------------------------------------------------- splitting
def _check_fractions(fractions) -> tuple[float, float, float]:
    try:
        f = tuple(float(x) for x in fractions)
    except (TypeError, ValueError):
        raise ValueError(f"fractions must be 3 numbers, got {fractions!r}") from None
    if len(f) != 3 or not all(np.isfinite(x) and x >= 0 for x in f) or abs(sum(f) - 1.0) > 1e-6:
        raise ValueError(f"fractions must be 3 non-negative numbers summing to 1 (train, val, test), got {fractions!r}")
    return f


def _assign(vehicles: np.ndarray, fractions, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Sorted unique vehicle keys and their split index (0/1/2), a seeded permutation cut by fractions."""
    keys = np.unique(vehicles)
    perm = np.random.default_rng(seed).permutation(len(keys))
    cut1 = int(round(fractions[0] * len(keys)))
    cut2 = cut1 + int(round(fractions[1] * len(keys)))
    split = np.empty(len(keys), dtype=np.int64)
    split[perm[:cut1]], split[perm[cut1:cut2]], split[perm[cut2:]] = 0, 1, 2
    return keys, split


def _vehicle_keys(rec, vid) -> np.ndarray:
    return np.asarray(rec, dtype=np.int64) * (1 << 32) + np.asarray(vid, dtype=np.int64)


def split_by_vehicle(
    td: TensorDict,
    fractions: Sequence[float] = (0.8, 0.1, 0.1),
    seed: int = 0,
    key: str | None = None,
    vehicles: np.ndarray | None = None,
) -> dict[str, TensorDict]:
    """Split samples into ``{"train", "val", "test"}`` so that no vehicle is in two splits.

    The vehicle of a sample is ``(recording_id, key)``; ``key`` defaults to ``"leader_id"`` when ``td`` has it
    (trajGAN samples: the leader's trajectory is the data) and to ``"vehicle_id"`` otherwise. ``vehicles``
    (int64 keys ``recording_id * 2**32 + vehicle_id``) fixes the universe that is permuted, so two sample
    kinds drawn from the same recordings get the same vehicle -> split assignment; by default it is the
    vehicles present in ``td``. Deterministic for a seed; samples keep their order within a split.
    """
    fractions = _check_fractions(fractions)
    if key is None:
        key = "leader_id" if "leader_id" in td.keys() else "vehicle_id"
    for k in ("recording_id", key):
        if k not in td.keys():
            raise ValueError(f"split_by_vehicle: td has no {k!r} field")
    sample_keys = _vehicle_keys(td["recording_id"].numpy(), td[key].numpy())
    universe = sample_keys if vehicles is None else np.asarray(vehicles, dtype=np.int64)
    keys, split = _assign(universe, fractions, int(seed))
    j = np.clip(np.searchsorted(keys, sample_keys), 0, max(len(keys) - 1, 0))
    if len(sample_keys) and not np.array_equal(keys[j], sample_keys):
        raise ValueError("split_by_vehicle: some samples' vehicles are not in `vehicles`")
    which = split[j] if len(sample_keys) else np.zeros(0, dtype=np.int64)
    return {name: td[torch.as_tensor(np.flatnonzero(which == i))] for i, name in enumerate(SPLITS)}


# ------------------------------------------------------------------------------------- the data set
def _hash_recordings(recordings: Sequence[HighDRecording]) -> str:
    h = hashlib.sha256(f"kddrl_trl.extract v{SCHEMA_VERSION}".encode())
    for rec in recordings:
        h.update(f"recording {int(rec.recording_id)}".encode())
        for df in (rec.tracks, rec.tracks_meta, rec.recording_meta):
            h.update(repr((list(df.columns), [str(d) for d in df.dtypes], df.shape)).encode())
            h.update(pd.util.hash_pandas_object(df, index=False).to_numpy().tobytes())
    return h.hexdigest()


def _params_json(**params) -> dict:
    """Parameters as plain JSON values (IDMParams fields as floats)."""
    out = {}
    for k, v in params.items():
        if isinstance(v, IDMParams):
            v = {f.name: float(getattr(v, f.name)) for f in dataclasses.fields(v)}
        elif isinstance(v, tuple):
            v = list(v)
        out[k] = v
    return json.loads(json.dumps(out))


def _extraction_params(
    recordings, seed, stride, hz, history, horizon, window, label, sensing_range, idm, fractions
) -> dict:
    """The checked parameters of :func:`extract_dataset` (a ``ValueError`` names the first bad one):
    ``(seed, stride, history, horizon, window, sensing_range, fractions)`` and all of them as ``meta.json``
    stores them."""
    if not recordings:
        raise ValueError("extract_dataset: no recordings given")
    if not all(isinstance(r, HighDRecording) for r in recordings):
        raise ValueError("extract_dataset: recordings must be HighDRecording objects")
    ids = [int(r.recording_id) for r in recordings]
    if len(set(ids)) != len(ids):
        raise ValueError(f"extract_dataset: duplicate recording ids {sorted(ids)}")
    seed = _positive_int("seed", seed, minimum=0)
    stride = _positive_int("stride", stride)
    _positive_float("hz", hz)
    fractions = _check_fractions(fractions)
    history, horizon, window = (
        _positive_int(n, v) for n, v in (("history", history), ("horizon", horizon), ("window", window))
    )
    sensing_range = _positive_float("sensing_range", sensing_range)
    _check_label(label)
    _check_idm(idm)
    checked = (seed, stride, history, horizon, window, sensing_range, fractions)
    return checked, _params_json(
        seed=seed,
        stride=stride,
        hz=float(hz),
        history=history,
        horizon=horizon,
        window=window,
        label=label,
        sensing_range=float(sensing_range),
        idm=idm,
        fractions=fractions,
        key_steps=KEY_STEPS,
        schema_version=SCHEMA_VERSION,
    )


def _cached_meta(out_dir: Path, digest: str, params: dict) -> dict | None:
    """``out_dir``'s stored meta (with ``"cached": True``) when it was made from the same input and parameters
    and its split folders exist; else None."""
    meta_path = out_dir / "meta.json"
    if not meta_path.is_file():
        return None
    try:
        old = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        old = None
    if (
        old
        and old.get("input_hash") == digest
        and old.get("params") == params
        and all((out_dir / k / s).is_dir() for k in KINDS for s in SPLITS)
    ):
        return {**old, "cached": True}
    return None


def _samples_of(recordings, hz, history, horizon, window, label, sensing_range, idm, stride, progress):
    """Both sample kinds of every recording, concatenated; the keys of every vehicle; the number of lane
    changers."""
    leaders, changes, vehicles, changers = [], [], [], []
    for rec in tqdm(recordings, desc="extract", unit="rec", disable=not progress):
        tracks = longitudinal_tracks(rec, hz=hz)
        lanes = vehicle_num_lanes(rec)
        lanes.index = pd.MultiIndex.from_arrays([np.full(len(lanes), int(rec.recording_id)), lanes.index])
        leaders.append(
            leader_samples(
                tracks, history=history, horizon=horizon, stride=stride, idm=idm, sensing_range=sensing_range
            )
        )
        changes.append(
            lane_change_samples(
                tracks, window=window, stride=stride, sensing_range=sensing_range, num_lanes=lanes, label=label
            )
        )
        vehicles.append(np.unique(_vehicle_keys(tracks["recording_id"], tracks["vehicle_id"])))
        changers.append(int((tracks.groupby("vehicle_id")["lane"].nunique() > 1).sum()))
    data = {"leaders": torch.cat(leaders), "lane_changes": torch.cat(changes)}
    universe = np.concatenate(vehicles)
    return data, universe, int(sum(changers))


def extract_dataset(
    recordings: Sequence[HighDRecording],
    out_dir: str | os.PathLike,
    seed: int = 0,
    stride: int = 1,
    progress: bool = True,
    force: bool = False,
    *,
    hz: float = 10.0,
    history: int = 10,
    horizon: int = 20,
    window: int = 20,
    label: str = "within",
    sensing_range: float = 200.0,
    idm: IDMParams = IDMParams(),
    fractions: Sequence[float] = (0.8, 0.1, 0.1),
) -> dict:
    """Extract, split and save both sample kinds; return the contents of ``out_dir/meta.json``.

    Tracks are built per recording (:func:`longitudinal_tracks`), samples cut with :func:`leader_samples` and
    :func:`lane_change_samples`, and split with one vehicle -> split assignment over all vehicles of all
    recordings (:func:`split_by_vehicle`). Each split is saved with ``TensorDict.memmap`` under
    ``out_dir/<kind>/<split>``; ``meta.json`` is written last and atomically. If ``meta.json`` already holds
    the same input hash and parameters (and the split folders exist), nothing is recomputed and the stored
    meta is returned with ``"cached": True`` added (``force=True`` recomputes).
    """
    recordings = list(recordings)
    checked, params = _extraction_params(
        recordings, seed, stride, hz, history, horizon, window, label, sensing_range, idm, fractions
    )
    seed, stride, history, horizon, window, sensing_range, fractions = checked
    out_dir = Path(out_dir)
    ids = [int(r.recording_id) for r in recordings]
    digest = _hash_recordings(recordings)
    meta_path = out_dir / "meta.json"
    cached = None if force else _cached_meta(out_dir, digest, params)
    if cached is not None:
        return cached

    data, universe, changers = _samples_of(
        recordings, hz, history, horizon, window, label, sensing_range, idm, stride, progress
    )

    out_dir.mkdir(parents=True, exist_ok=True)
    if meta_path.exists():
        meta_path.unlink()  # invalidate the cache before touching the data
    counts: dict = {"vehicles": int(len(universe)), "lane_changers": changers}
    for kind, td in data.items():
        key = "leader_id" if kind == "leaders" else "vehicle_id"
        splits = split_by_vehicle(td, fractions, seed=seed, key=key, vehicles=universe)
        kind_dir = out_dir / kind
        if kind_dir.exists():
            shutil.rmtree(kind_dir)
        counts[kind] = {}
        for name, part in splits.items():
            part.memmap(prefix=str(kind_dir / name))
            entry = {
                "samples": int(part.batch_size[0]),
                "vehicles": int(len(np.unique(_vehicle_keys(part["recording_id"].numpy(), part[key].numpy())))),
            }
            if kind == "lane_changes":
                per = torch.bincount(part["label"], minlength=3).tolist()
                entry["per_class"] = dict(zip(K.LC_ACTIONS, (int(x) for x in per)))
            counts[kind][name] = entry
    meta = {
        "schema_version": SCHEMA_VERSION,
        "input_hash": digest,
        "recording_ids": ids,
        "params": params,
        "driver_types": list(DRIVER_TYPES),
        "counts": counts,
        "kinds": list(KINDS),
        "splits": list(SPLITS),
        "split_keys": {"leaders": ["recording_id", "leader_id"], "lane_changes": ["recording_id", "vehicle_id"]},
    }
    write_json_atomic(meta_path, meta)
    return {**meta, "cached": False}


def load_dataset(out_dir: str | os.PathLike, kind: str, split: str) -> TensorDict:
    """Memory-mapped samples of ``kind`` (``leaders`` / ``lane_changes``) and ``split`` (``train`` / ...)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {list(KINDS)}, got {kind!r}")
    if split not in SPLITS:
        raise ValueError(f"split must be one of {list(SPLITS)}, got {split!r}")
    path = Path(out_dir) / kind / split
    if not (Path(out_dir) / "meta.json").is_file() or not path.is_dir():
        raise FileNotFoundError(f"no extracted data set at {path} (run extract_dataset first)")
    return TensorDict.load_memmap(path)
