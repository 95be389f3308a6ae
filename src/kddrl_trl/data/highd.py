"""Reading, writing and validating recordings in the HighD file format.

HighD (Krajewski et al., 2018, https://www.highd-dataset.com) ships every recording ``XX`` as three CSV files:
``XX_tracks.csv`` (one row per vehicle and frame), ``XX_tracksMeta.csv`` (one row per vehicle) and
``XX_recordingMeta.csv`` (one row).  This module keeps the published column names, column order and
conventions unchanged:

* frames are sampled at ``frameRate`` (25 Hz);
* ``x, y`` is the *upper-left* corner of the bounding box and ``y`` points *down* the image;
* ``width`` is the vehicle length (along x) and ``height`` its width (along y);
* ``drivingDirection`` 1 travels toward -x in the upper half of the image, 2 toward +x in the lower half;
* neighbour ids (``precedingId`` ...) use 0 for "no vehicle";
* ``dhw``/``thw``/``ttc`` use -1 (``ttc`` sometimes 0) for "undefined";
* ``upperLaneMarkings`` / ``lowerLaneMarkings`` are ``;``-separated y coordinates of the lane markings of
  direction 1 / direction 2.

Our own recordings add one optional tracksMeta column, ``driverType`` (e.g. ``"timid"``).

Helpers :func:`lane_index_in_direction`, :func:`longitudinal_position` and :func:`longitudinal_speed` map
both directions to a common frame in which vehicles travel toward +, lanes are counted from the right.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from kddrl_trl.atomic_files import write_atomic

__all__ = [
    "TRACKS_COLUMNS",
    "TRACKS_META_COLUMNS",
    "RECORDING_META_COLUMNS",
    "OPTIONAL_META_COLUMNS",
    "TRACKS_DTYPES",
    "TRACKS_META_DTYPES",
    "RECORDING_META_DTYPES",
    "HighDFormatError",
    "HighDRecording",
    "recording_paths",
    "read_recording",
    "list_recordings",
    "write_recording",
    "parse_markings",
    "format_markings",
    "driving_direction",
    "lane_index_in_direction",
    "longitudinal_position",
    "longitudinal_speed",
    "longitudinal_acceleration",
]

# --------------------------------------------------------------------------------------------- schema
#: the eight neighbour-id columns of a tracks file, in HighD's order
NEIGHBOUR_ID_COLUMNS = (
    "precedingId",
    "followingId",
    "leftPrecedingId",
    "leftAlongsideId",
    "leftFollowingId",
    "rightPrecedingId",
    "rightAlongsideId",
    "rightFollowingId",
)
TRACKS_COLUMNS = (
    "frame",
    "id",
    "x",
    "y",
    "width",
    "height",
    "xVelocity",
    "yVelocity",
    "xAcceleration",
    "yAcceleration",
    "frontSightDistance",
    "backSightDistance",
    "dhw",
    "thw",
    "ttc",
    "precedingXVelocity",
    *NEIGHBOUR_ID_COLUMNS,
    "laneId",
)
TRACKS_META_COLUMNS = (
    "id",
    "width",
    "height",
    "initialFrame",
    "finalFrame",
    "numFrames",
    "class",
    "drivingDirection",
    "traveledDistance",
    "minXVelocity",
    "maxXVelocity",
    "meanXVelocity",
    "minDHW",
    "minTHW",
    "minTTC",
    "numLaneChanges",
)
RECORDING_META_COLUMNS = (
    "id",
    "frameRate",
    "locationId",
    "speedLimit",
    "month",
    "weekDay",
    "startTime",
    "duration",
    "totalDrivenDistance",
    "totalDrivenTime",
    "numVehicles",
    "numCars",
    "numTrucks",
    "upperLaneMarkings",
    "lowerLaneMarkings",
)
#: optional trailing tracksMeta columns (ours, not in the published dataset)
OPTIONAL_META_COLUMNS = ("driverType",)

_INT = "int64"
_FLOAT = "float64"
_STR = str  # pandas' default string dtype ("str" in pandas >= 3)

_TRACKS_INT = {"frame", "id", *NEIGHBOUR_ID_COLUMNS, "laneId"}
TRACKS_DTYPES = {c: (_INT if c in _TRACKS_INT else _FLOAT) for c in TRACKS_COLUMNS}

_META_INT = {"id", "initialFrame", "finalFrame", "numFrames", "drivingDirection", "numLaneChanges"}
TRACKS_META_DTYPES = {c: (_STR if c == "class" else _INT if c in _META_INT else _FLOAT) for c in TRACKS_META_COLUMNS}
TRACKS_META_DTYPES["driverType"] = _STR

_REC_INT = {"id", "frameRate", "locationId", "numVehicles", "numCars", "numTrucks"}
_REC_STR = {"month", "weekDay", "startTime", "upperLaneMarkings", "lowerLaneMarkings"}
RECORDING_META_DTYPES = {
    c: (_STR if c in _REC_STR else _INT if c in _REC_INT else _FLOAT) for c in RECORDING_META_COLUMNS
}

_KINDS = ("tracks", "tracksMeta", "recordingMeta")
_SCHEMA = {  # kind -> (required columns, optional columns, dtypes)
    "tracks": (TRACKS_COLUMNS, (), TRACKS_DTYPES),
    "tracksMeta": (TRACKS_META_COLUMNS, OPTIONAL_META_COLUMNS, TRACKS_META_DTYPES),
    "recordingMeta": (RECORDING_META_COLUMNS, (), RECORDING_META_DTYPES),
}
_FILE_RE = re.compile(r"^(\d+)_(tracks|tracksMeta|recordingMeta)\.csv$")


class HighDFormatError(ValueError):
    """A HighD file is missing or malformed; the message names the file, the column and (if any) the row."""


def _where(file: str | os.PathLike, column: str | None = None, row: int | None = None) -> str:
    """``"file 01_tracks.csv, column 'x', data row 3 (line 4)"`` — rows are 0-based, lines 1-based."""
    parts = [f"file {Path(file).name}"]
    if column is not None:
        parts.append(f"column {column!r}")
    if row is not None:
        parts.append(f"data row {row} (line {row + 2})")
    return ", ".join(parts)


# ------------------------------------------------------------------------------------------ recording
def parse_markings(text: str) -> np.ndarray:
    """Parse ``"8.5;12.1;15.8"`` into a float array (raises ``ValueError`` on malformed text)."""
    values = np.array([float(part) for part in str(text).split(";")], dtype=np.float64)
    if len(values) < 2 or not np.all(np.isfinite(values)) or not np.all(np.diff(values) > 0):
        raise ValueError(f"expected >= 2 finite, strictly increasing y values, got {text!r}")
    return values


def format_markings(values) -> str:
    """Inverse of :func:`parse_markings`: join floats with ``;`` at round-trip (repr) precision."""
    return ";".join(repr(float(v)) for v in values)


@dataclass
class HighDRecording:
    """One HighD recording: the three tables, with the published column names and dtypes.

    ``recording_meta`` is the one-row recordingMeta table (a DataFrame, so dtypes round-trip exactly).
    """

    recording_id: int
    tracks: pd.DataFrame
    tracks_meta: pd.DataFrame
    recording_meta: pd.DataFrame

    @property
    def meta(self) -> pd.Series:
        """The single recordingMeta row as a Series."""
        return self.recording_meta.iloc[0]

    @property
    def frame_rate(self) -> int:
        """Frames per second (25 in HighD)."""
        return int(self.meta["frameRate"])

    @property
    def upper_markings(self) -> np.ndarray:
        """y coordinates (top to bottom) of the lane markings of driving direction 1."""
        return parse_markings(self.meta["upperLaneMarkings"])

    @property
    def lower_markings(self) -> np.ndarray:
        """y coordinates (top to bottom) of the lane markings of driving direction 2."""
        return parse_markings(self.meta["lowerLaneMarkings"])

    def markings(self, direction: int) -> np.ndarray:
        """Lane markings of driving direction 1 (upper) or 2 (lower)."""
        return {1: self.upper_markings, 2: self.lower_markings}[direction]


def recording_paths(directory: str | os.PathLike, recording_id: int) -> dict[str, Path]:
    """``{"tracks": .../XX_tracks.csv, "tracksMeta": ..., "recordingMeta": ...}``."""
    directory = Path(directory)
    return {kind: directory / f"{int(recording_id):02d}_{kind}.csv" for kind in _KINDS}


def list_recordings(directory: str | os.PathLike) -> list[int]:
    """Sorted ids of every recording with at least one HighD file in ``directory``.

    A recording with a missing file is still listed, so :func:`read_recording` reports what is missing.
    """
    ids = {int(m.group(1)) for p in Path(directory).iterdir() if (m := _FILE_RE.match(p.name))}
    return sorted(ids)


# -------------------------------------------------------------------------------------------- reading
def _check_columns(file, present, kind: str) -> None:
    """Raise unless ``present`` holds every required column of ``kind`` and nothing unknown."""
    required, optional, _ = _SCHEMA[kind]
    missing = [c for c in required if c not in present]
    unexpected = [c for c in present if c not in required and c not in optional]
    duplicated = sorted({c for c in present if list(present).count(c) > 1})
    if missing or unexpected or duplicated:
        problems = []
        if missing:
            problems.append(f"missing expected column(s) {missing}")
        if unexpected:
            problems.append(f"unexpected column(s) {unexpected}")
        if duplicated:
            problems.append(f"duplicated column(s) {duplicated}")
        raise HighDFormatError(
            f"{_where(file)}: {'; '.join(problems)} (expected {list(required)}"
            + (f", optionally {list(optional)}" if optional else "")
            + ")"
        )


def _diagnose_numeric(path: Path, dtypes: dict, error: Exception) -> HighDFormatError:
    """Locate the first cell that made the typed ``read_csv`` fail, re-reading the file as text."""
    try:
        raw = pd.read_csv(path, dtype=str, na_filter=False)
    except (ValueError, pd.errors.ParserError) as text_error:  # e.g. a row with too many fields
        return HighDFormatError(f"{_where(path)}: could not be parsed: {text_error}")
    for column in raw.columns:
        if dtypes.get(column) not in (_INT, _FLOAT):
            continue
        values = pd.to_numeric(raw[column], errors="coerce").to_numpy(dtype=np.float64)
        bad = ~np.isfinite(values)
        if dtypes[column] == _INT:
            bad |= np.isfinite(values) & (values != np.round(values))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            cell, value = raw[column].iloc[row], values[row]
            what = (
                "non-integer value"
                if np.isfinite(value)
                else "infinite value"
                if np.isinf(value)
                else "NaN/missing value"
                if cell.strip().lower() in {"", "nan", "na", "n/a", "null", "none"}
                else "non-numeric value"
            )
            return HighDFormatError(
                f"{_where(path, column, row)}: {what} {cell!r} in a "
                f"{'integer' if dtypes[column] == _INT else 'numeric'} column"
            )
    return HighDFormatError(f"{_where(path)}: could not be parsed: {error}")


def _read_table(path: Path, kind: str) -> pd.DataFrame:
    """Read one HighD CSV with explicit dtypes and validate header, cells and finiteness."""
    if not path.is_file():
        raise HighDFormatError(f"{_where(path)}: file not found (looked for {path})")
    if path.stat().st_size == 0:
        raise HighDFormatError(f"{_where(path)}: file is empty (no header, no rows)")
    try:
        header = pd.read_csv(path, nrows=0).columns.tolist()
    except pd.errors.EmptyDataError:
        raise HighDFormatError(f"{_where(path)}: file is empty (no header, no rows)") from None
    _check_columns(path, header, kind)
    required, optional, dtypes = _SCHEMA[kind]
    try:
        # na_filter=False: every cell is parsed literally, so "NaN" or "" in a numeric column is an error.
        df = pd.read_csv(path, dtype={c: dtypes[c] for c in header}, na_filter=False)
    except (ValueError, OverflowError) as error:
        raise _diagnose_numeric(path, dtypes, error) from error
    if len(df) == 0:
        raise HighDFormatError(f"{_where(path)}: file is empty (header but no data rows)")
    for column in header:
        if dtypes[column] == _FLOAT:
            finite = np.isfinite(df[column].to_numpy())
            if not finite.all():
                row = int(np.flatnonzero(~finite)[0])
                raise HighDFormatError(f"{_where(path, column, row)}: non-finite value {df[column].iloc[row]!r}")
    return df[[*required, *[c for c in optional if c in header]]]


def read_recording(directory: str | os.PathLike, recording_id: int) -> HighDRecording:
    """Read and validate ``XX_tracks.csv``, ``XX_tracksMeta.csv`` and ``XX_recordingMeta.csv``.

    Raises :class:`HighDFormatError` (naming file, column and row) on any deviation from the format.
    """
    paths = recording_paths(directory, recording_id)
    tracks = _read_table(paths["tracks"], "tracks")
    tracks_meta = _read_table(paths["tracksMeta"], "tracksMeta")
    recording_meta = _read_table(paths["recordingMeta"], "recordingMeta")

    rec_path = paths["recordingMeta"]
    if len(recording_meta) != 1:
        raise HighDFormatError(f"{_where(rec_path)}: expected exactly 1 data row, found {len(recording_meta)}")
    if int(recording_meta["id"].iloc[0]) != int(recording_id):
        raise HighDFormatError(
            f"{_where(rec_path, 'id', 0)}: id {recording_meta['id'].iloc[0]} does not match "
            f"the file name's recording id {int(recording_id)}"
        )
    for column in ("upperLaneMarkings", "lowerLaneMarkings"):
        try:
            parse_markings(recording_meta[column].iloc[0])
        except ValueError as error:
            raise HighDFormatError(f"{_where(rec_path, column, 0)}: bad lane markings: {error}") from None

    meta_path = paths["tracksMeta"]
    dup = tracks_meta["id"].duplicated().to_numpy()
    if dup.any():
        row = int(np.flatnonzero(dup)[0])
        raise HighDFormatError(f"{_where(meta_path, 'id', row)}: duplicated vehicle id {tracks_meta['id'].iloc[row]}")
    bad_dir = ~tracks_meta["drivingDirection"].isin([1, 2]).to_numpy()
    if bad_dir.any():
        row = int(np.flatnonzero(bad_dir)[0])
        raise HighDFormatError(
            f"{_where(meta_path, 'drivingDirection', row)}: drivingDirection must be 1 or 2, "
            f"got {tracks_meta['drivingDirection'].iloc[row]}"
        )
    unknown = np.setdiff1d(tracks["id"].unique(), tracks_meta["id"].to_numpy())
    if len(unknown):
        shown = ", ".join(str(i) for i in unknown[:10]) + (", ..." if len(unknown) > 10 else "")
        raise HighDFormatError(
            f"{_where(paths['tracks'], 'id')}: {len(unknown)} vehicle id(s) not in {meta_path.name}: {shown}"
        )
    return HighDRecording(int(recording_id), tracks, tracks_meta, recording_meta)


# -------------------------------------------------------------------------------------------- writing
def _coerce(df: pd.DataFrame, path: Path, kind: str) -> pd.DataFrame:
    """Columns in published order (+ present optional ones), cast to the schema dtypes without loss."""
    _check_columns(path, df.columns.tolist(), kind)
    required, optional, dtypes = _SCHEMA[kind]
    out = {}
    for column in [*required, *[c for c in optional if c in df.columns]]:
        series, dtype = df[column], dtypes[column]
        if dtype == _STR:
            if series.isna().any():
                row = int(np.flatnonzero(series.isna().to_numpy())[0])
                raise HighDFormatError(f"{_where(path, column, row)}: missing value in a text column")
            out[column] = series.astype(str)
            continue
        values = pd.to_numeric(series, errors="coerce").to_numpy(dtype=np.float64)
        bad = ~np.isfinite(values)
        if dtype == _INT:
            bad |= np.isfinite(values) & (values != np.round(values))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise HighDFormatError(f"{_where(path, column, row)}: cannot write {series.iloc[row]!r} as {dtype}")
        out[column] = series.astype(dtype)
    return pd.DataFrame(out, index=df.index)


def _atomic_write_csv(df: pd.DataFrame, path: Path) -> None:
    """Write ``df`` atomically (:func:`kddrl_trl.atomic_files.write_atomic`).

    ``float_format=None`` writes the shortest repr, which read_csv parses back to the identical float."""
    write_atomic(path, lambda fh: df.to_csv(fh, index=False, lineterminator="\n"), newline="")


def write_recording(recording: HighDRecording, directory: str | os.PathLike) -> dict[str, Path]:
    """Write the three HighD files of ``recording`` into ``directory`` (created if needed).

    Columns are written in the published order (``driverType`` last, only if present); each file is
    written atomically, and ``read_recording(write_recording(r))`` reproduces values and dtypes exactly.
    All three tables are validated before any file is written. Returns the written paths.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = recording_paths(directory, recording.recording_id)
    tables = {
        "tracks": _coerce(recording.tracks, paths["tracks"], "tracks"),
        "tracksMeta": _coerce(recording.tracks_meta, paths["tracksMeta"], "tracksMeta"),
        "recordingMeta": _coerce(recording.recording_meta, paths["recordingMeta"], "recordingMeta"),
    }
    for kind, table in tables.items():
        _atomic_write_csv(table, paths[kind])
    return paths


# ----------------------------------------------------------------------------- direction-free views
def driving_direction(recording: HighDRecording) -> pd.Series:
    """``drivingDirection`` (1 or 2) of every tracks row, aligned with ``recording.tracks``."""
    by_id = recording.tracks_meta.set_index("id")["drivingDirection"]
    return recording.tracks["id"].map(by_id).rename("drivingDirection")


def lane_index_in_direction(recording: HighDRecording) -> pd.Series:
    """Lane of every tracks row counted from the right in its direction of travel (0 = rightmost).

    Derived from the lane markings and the bounding-box centre ``y + height / 2`` (not from ``laneId``).
    With y pointing down, direction 2 (toward +x) has its right side at larger y, so its rightmost lane is
    the lowest one in the image; direction 1 (toward -x) has its rightmost lane at the smallest y.
    A centre outside the outer markings is assigned to the nearest lane.
    """
    tracks = recording.tracks
    direction = driving_direction(recording).to_numpy()
    centre = (tracks["y"] + tracks["height"] / 2.0).to_numpy()
    index = np.zeros(len(tracks), dtype=np.int64)
    for d in (1, 2):
        marks = recording.markings(d)
        n_lanes = len(marks) - 1
        rows = direction == d
        from_top = np.clip(np.searchsorted(marks, centre[rows], side="right") - 1, 0, n_lanes - 1)
        index[rows] = from_top if d == 1 else n_lanes - 1 - from_top
    return pd.Series(index, index=tracks.index, name="laneIndex")


def _sign(recording: HighDRecording) -> np.ndarray:
    """+1 for direction 2 (toward +x), -1 for direction 1 (toward -x), per tracks row."""
    return np.where(driving_direction(recording).to_numpy() == 2, 1.0, -1.0)


def longitudinal_position(recording: HighDRecording) -> pd.Series:
    """Front-bumper position along the direction of travel (increases as the vehicle moves).

    Direction 2: ``x + width`` (front is the right edge); direction 1: ``-x`` (front is the left edge).
    """
    tracks = recording.tracks
    pos = np.where(_sign(recording) > 0, tracks["x"] + tracks["width"], -tracks["x"])
    return pd.Series(pos, index=tracks.index, name="longitudinalPosition")


def longitudinal_speed(recording: HighDRecording) -> pd.Series:
    """Speed along the direction of travel: ``xVelocity`` (direction 2) or ``-xVelocity`` (direction 1)."""
    tracks = recording.tracks
    return pd.Series(_sign(recording) * tracks["xVelocity"].to_numpy(), index=tracks.index, name="longitudinalSpeed")


def longitudinal_acceleration(recording: HighDRecording) -> pd.Series:
    """Acceleration along the direction of travel: ``xAcceleration`` signed like :func:`longitudinal_speed`."""
    tracks = recording.tracks
    return pd.Series(
        _sign(recording) * tracks["xAcceleration"].to_numpy(), index=tracks.index, name="longitudinalAcceleration"
    )
