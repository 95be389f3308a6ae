"""The 10 Hz longitudinal track table ("tracks10") shared by extraction and calibration.

:func:`longitudinal_tracks` resamples one HighD-format recording (25 Hz, both driving directions) to one
row per vehicle per 10 Hz frame, with both directions normalised so that every vehicle travels toward +y
and lanes / left / right are counted in the direction of travel. The column contract is
``TRACKS10.md`` in this folder. Everything is vectorised over all rows of the recording at once (numpy
index arithmetic and a single ``searchsorted``); there is no Python loop over vehicles or rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from kddrl_trl.data.highd import (
    HighDRecording,
    driving_direction,
    lane_index_in_direction,
    longitudinal_acceleration,
    longitudinal_position,
    longitudinal_speed,
)

__all__ = [
    "TRACKS10_COLUMNS",
    "TRACKS10_DTYPES",
    "NEIGHBOR_ID_COLUMNS",
    "longitudinal_tracks",
    "vehicle_num_lanes",
    "tracks_hz",
]

#: tracks10 neighbour-id column -> HighD tracks column (HighD's left/right are already in the direction
#: of travel)
NEIGHBOR_ID_COLUMNS = {
    "preceding_id": "precedingId",
    "following_id": "followingId",
    "left_preceding_id": "leftPrecedingId",
    "left_alongside_id": "leftAlongsideId",
    "left_following_id": "leftFollowingId",
    "right_preceding_id": "rightPrecedingId",
    "right_alongside_id": "rightAlongsideId",
    "right_following_id": "rightFollowingId",
}

TRACKS10_DTYPES = {
    "recording_id": "int64",
    "vehicle_id": "int64",
    "frame": "int64",
    "t": "float64",
    "y": "float64",
    "v": "float64",
    "a": "float64",
    "x_lat": "float64",
    "vx_lat": "float64",
    "lane": "int64",
    "lane_offset": "float64",
    "length": "float64",
    "driver_type": "str",
    **{c: "int64" for c in NEIGHBOR_ID_COLUMNS},
}
TRACKS10_COLUMNS = tuple(TRACKS10_DTYPES)

#: columns interpolated linearly and required to be finite
_KINEMATIC = ("y", "v", "a", "x_lat", "vx_lat")


def tracks_hz(tracks: pd.DataFrame) -> float:
    """Sampling rate of a tracks10 table, from ``frame / t`` (``tracks.attrs["hz"]`` when present)."""
    hz = tracks.attrs.get("hz") if hasattr(tracks, "attrs") else None
    if hz:
        return float(hz)
    t = tracks["t"].to_numpy(dtype=np.float64)
    nz = t > 0
    if not nz.any():
        raise ValueError("cannot infer the sampling rate of the tracks table: every t is 0 (set attrs['hz'])")
    return float(np.median(tracks["frame"].to_numpy()[nz] / t[nz]))


def vehicle_num_lanes(recording: HighDRecording) -> pd.Series:
    """Number of lanes in each vehicle's driving direction (from the lane markings), indexed by vehicle id."""
    meta = recording.tracks_meta
    n = {d: len(recording.markings(d)) - 1 for d in (1, 2)}
    values = meta["drivingDirection"].map(n).to_numpy(dtype=np.int64)
    return pd.Series(values, index=meta["id"].to_numpy(dtype=np.int64), name="num_lanes")


@dataclass
class _Rows25:
    """A recording's 25 Hz rows in the direction-free frame, sorted by (vehicle, frame), and each vehicle's
    block of rows ``[starts, ends)``."""

    ids: np.ndarray
    frames: np.ndarray
    lane: np.ndarray
    direction: np.ndarray
    cols: dict  # the kinematics: y, v, a, x_lat, vx_lat
    neighbours: dict  # the neighbour id columns
    starts: np.ndarray
    ends: np.ndarray
    vids: np.ndarray


def _rows25(recording: HighDRecording, rid: int, fr: float, hz: float) -> _Rows25:
    """The 25 Hz rows of ``recording`` (id ``rid``, frame rate ``fr``); refuses a vehicle missing from
    tracksMeta, non-finite kinematics and repeated frames, naming the vehicle."""
    raw = recording.tracks
    direction = driving_direction(recording).to_numpy()
    if np.isnan(direction.astype(np.float64)).any():
        bad = int(raw["id"].to_numpy()[np.isnan(direction.astype(np.float64))][0])
        raise ValueError(f"recording {rid}: vehicle {bad} is in tracks but not in tracksMeta")
    centre = (raw["y"] + raw["height"] / 2.0).to_numpy(dtype=np.float64)
    upper, lower = recording.upper_markings, recording.lower_markings
    # direction 2 (toward +x): the right side is at larger image y -> right edge = last lower marking;
    # direction 1 (toward -x): the right side is at smaller image y -> right edge = first upper marking.
    d2 = direction == 2
    x_lat = np.where(d2, lower[-1] - centre, centre - upper[0])
    vy_img = raw["yVelocity"].to_numpy(dtype=np.float64)
    vx_lat = np.where(d2, -vy_img, vy_img)
    cols25 = {
        "y": longitudinal_position(recording).to_numpy(dtype=np.float64),
        "v": longitudinal_speed(recording).to_numpy(dtype=np.float64),
        "a": longitudinal_acceleration(recording).to_numpy(dtype=np.float64),
        "x_lat": x_lat,
        "vx_lat": vx_lat,
    }
    ids25 = raw["id"].to_numpy(dtype=np.int64)
    frames25 = raw["frame"].to_numpy(dtype=np.int64)
    lane25 = lane_index_in_direction(recording).to_numpy(dtype=np.int64)
    nb25 = {c: raw[h].to_numpy(dtype=np.int64) for c, h in NEIGHBOR_ID_COLUMNS.items()}

    for name, values in cols25.items():  # non-finite 25 Hz inputs would poison the interpolation
        _check_finite(values, name, rid, ids25, frames25 / fr * hz)

    # sorted by (vehicle, frame), each vehicle's block of rows
    order = np.lexsort((frames25, ids25))
    ids25, frames25, lane25, dir25 = ids25[order], frames25[order], lane25[order], direction[order]
    cols25 = {k: v[order] for k, v in cols25.items()}
    nb25 = {k: v[order] for k, v in nb25.items()}
    new_vehicle = np.r_[True, ids25[1:] != ids25[:-1]]
    dup = ~new_vehicle & (np.r_[1, np.diff(frames25)] <= 0)
    if dup.any():
        i = int(np.flatnonzero(dup)[0])
        raise ValueError(f"recording {rid}: vehicle {ids25[i]} has repeated 25 Hz frame {frames25[i]}")
    starts = np.flatnonzero(new_vehicle)
    ends = np.r_[starts[1:], len(ids25)]  # exclusive
    vids = ids25[starts]
    return _Rows25(ids25, frames25, lane25, dir25, cols25, nb25, starts, ends, vids)


def _sample_points(r: _Rows25, fr: float, hz: float):
    """The ``hz`` frames ``k`` with ``k / hz`` inside each vehicle's first..last 25 Hz timestamps: for each,
    its vehicle index, ``k``, the 25 Hz rows at or before (``lo``) and after (``hi``) it and the weight ``w``
    of ``hi`` in the linear interpolation."""
    frames25, starts, ends, vids = r.frames, r.starts, r.ends, r.vids
    f0, f1 = frames25[starts], frames25[ends - 1]
    eps = 1e-9
    k_first = np.ceil(f0 * (hz / fr) - eps).astype(np.int64)
    k_last = np.floor(f1 * (hz / fr) + eps).astype(np.int64)
    n10 = np.maximum(k_last - k_first + 1, 0)
    veh = np.repeat(np.arange(len(vids)), n10)
    offsets = np.r_[0, np.cumsum(n10)[:-1]]
    k = k_first[veh] + (np.arange(len(veh)) - offsets[veh])
    p = np.clip(k * (fr / hz), f0[veh], f1[veh])  # fractional 25 Hz frame

    # one searchsorted over (vehicle block, frame) keys for all rows at once
    span = float(frames25.max() - frames25.min() + 2)
    base = frames25.min()
    block = np.repeat(np.arange(len(vids)), ends - starts)
    key25 = block * span + (frames25 - base)
    key10 = veh * span + (p - base)
    lo = np.searchsorted(key25, key10 + 1e-6, side="right") - 1  # last 25 Hz row at or before t
    lo = np.clip(lo, starts[veh], ends[veh] - 1)
    hi = np.minimum(lo + 1, ends[veh] - 1)
    df_ = (frames25[hi] - frames25[lo]).astype(np.float64)
    w = np.where(hi > lo, (p - frames25[lo]) / np.where(df_ > 0, df_, 1.0), 0.0)
    w = np.clip(w, 0.0, 1.0)
    return veh, k, lo, hi, w


def _vehicle_meta(recording: HighDRecording, vids: np.ndarray):
    """Each vehicle's length and driver type (``""`` where the recording has no ``driverType``)."""
    meta = recording.tracks_meta.set_index("id")
    length = meta["width"].reindex(vids).to_numpy(dtype=np.float64)
    if "driverType" in meta.columns:
        driver = meta["driverType"].reindex(vids).astype(str).to_numpy(dtype=object)
    else:
        driver = np.full(len(vids), "", dtype=object)
    return length, driver


def longitudinal_tracks(recording: HighDRecording, hz: float = 10.0) -> pd.DataFrame:
    """Resample ``recording`` to ``hz`` and normalise both driving directions (``TRACKS10.md``).

    Kinematics (``y, v, a, x_lat, vx_lat``) are linearly interpolated at ``t = frame / hz`` inside each
    vehicle's own first..last 25 Hz timestamps; ``lane`` and the neighbour ids come from the last 25 Hz row
    at or before ``t``. ``x_lat`` is the box centre measured from the right edge of the carriageway in the
    direction of travel (the outermost lane marking), growing to the left; ``vx_lat`` is + to the left;
    ``lane_offset`` is ``x_lat`` minus the centre of ``lane`` (from the lane markings), + = left of the centre.

    Raises:
        ValueError: ``hz`` not finite and > 0, no vehicles in the recording, a vehicle with repeated 25 Hz
            frames, or a non-finite value in a required column (the message names column and vehicle).
    """
    if not (isinstance(hz, (int, float, np.floating, np.integer)) and np.isfinite(hz) and hz > 0):
        raise ValueError(f"hz must be a finite number > 0, got {hz!r}")
    rid = int(recording.recording_id)
    raw = recording.tracks
    if len(raw) == 0 or len(recording.tracks_meta) == 0:
        raise ValueError(f"recording {rid} has no vehicles (empty tracks or tracksMeta table)")
    fr = float(recording.frame_rate)
    if not (np.isfinite(fr) and fr > 0):
        raise ValueError(f"recording {rid}: frameRate must be > 0, got {fr}")

    r = _rows25(recording, rid, fr, hz)
    veh, k, lo, hi, w = _sample_points(r, fr, hz)
    vids = r.vids
    length, driver = _vehicle_meta(recording, vids)
    lane25, dir25, cols25, nb25 = r.lane, r.direction, r.cols, r.neighbours

    out = {
        "recording_id": np.full(len(veh), rid, dtype=np.int64),
        "vehicle_id": vids[veh],
        "frame": k,
        "t": k / float(hz),
    }
    for name in _KINEMATIC:
        v = cols25[name]
        out[name] = v[lo] + w * (v[hi] - v[lo])
    out["lane"] = lane25[lo]
    out["lane_offset"] = out["x_lat"] - _lane_centres(recording, dir25[lo], out["lane"])
    out["length"] = length[veh]
    out["driver_type"] = driver[veh]
    for c in NEIGHBOR_ID_COLUMNS:
        out[c] = nb25[c][lo]
    for name in (*_KINEMATIC, "length"):
        _check_finite(out[name], name, rid, out["vehicle_id"], k)
    tracks = pd.DataFrame(out, columns=list(TRACKS10_COLUMNS))
    tracks = tracks.astype({c: d for c, d in TRACKS10_DTYPES.items()})
    tracks.attrs["hz"] = float(hz)
    return tracks


def _lane_centres(recording: HighDRecording, direction: np.ndarray, lane: np.ndarray) -> np.ndarray:
    """Centre of lane ``lane`` (0 = rightmost) of driving ``direction``, in ``x_lat`` coordinates (m from the
    right edge of the carriageway), from the recording's lane markings."""
    out = np.zeros(len(lane), dtype=np.float64)
    for d in (1, 2):
        marks = recording.markings(d)
        marks = marks - marks[0] if d == 1 else marks[-1] - marks[::-1]  # distances from the right edge
        centres = (marks[1:] + marks[:-1]) / 2.0
        rows = direction == d
        out[rows] = centres[np.clip(lane[rows], 0, len(centres) - 1)]
    return out


def _check_finite(values: np.ndarray, column: str, rid: int, vehicle: np.ndarray, frame: np.ndarray) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"recording {rid}: column {column!r} of vehicle {int(vehicle[i])} is not finite "
            f"({values[i]}) at 10 Hz frame ~{float(frame[i]):.0f} ({int(bad.sum())} bad value(s) "
            f"in this column)"
        )
