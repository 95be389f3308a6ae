"""Tests of the HighD file-format layer (:mod:`kddrl_trl.data.highd`) on small synthesised recordings."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

try:  # the package is used from the source tree when it is not installed
    import kddrl_trl.data  # noqa: F401
except ImportError:  # pragma: no cover
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "src"))

from kddrl_trl.data import (
    RECORDING_META_COLUMNS,
    TRACKS_COLUMNS,
    TRACKS_META_COLUMNS,
    HighDFormatError,
    HighDRecording,
    format_markings,
    lane_index_in_direction,
    list_recordings,
    longitudinal_acceleration,
    longitudinal_position,
    longitudinal_speed,
    parse_markings,
    read_recording,
    recording_paths,
    write_recording,
)

UPPER = "8.5;12.1;15.8;19.5"  # direction 1 (toward -x): lanes [8.5,12.1], [12.1,15.8], [15.8,19.5]
LOWER = "21.3;25.0;28.7;32.4"  # direction 2 (toward +x): lanes [21.3,25.0], [25.0,28.7], [28.7,32.4]
N_FRAMES = 50

# (id, drivingDirection, lane number from the TOP of the image within that direction, class, driverType)
VEHICLES = [
    (1, 2, 0, "Car", "timid"),  # dir 2, top lane of the lower half   -> leftmost  -> laneIndex 2
    (2, 2, 1, "Truck", "normal"),  # dir 2, middle lane               -> laneIndex 1
    (3, 2, 2, "Car", "aggressive"),  # dir 2, bottom lane (largest y) -> rightmost -> laneIndex 0
    (4, 1, 0, "Car", "normal"),  # dir 1, top lane (smallest y)       -> rightmost -> laneIndex 0
    (5, 1, 1, "Car", "timid"),  # dir 1, middle lane                  -> laneIndex 1
    (6, 1, 2, "Truck", "aggressive"),  # dir 1, bottom lane of upper half -> leftmost -> laneIndex 2
]
EXPECTED_LANE_INDEX = {1: 2, 2: 1, 3: 0, 4: 0, 5: 1, 6: 2}


def make_recording(recording_id: int = 1, driver_type: bool = True, seed: int = 0) -> HighDRecording:
    """Synthesise a small recording: 3 vehicles per direction (one per lane) over 50 frames at 25 Hz."""
    rng = np.random.default_rng(seed)
    markings = {1: parse_markings(UPPER), 2: parse_markings(LOWER)}
    track_rows, meta_rows = [], []
    for vid, direction, lane_from_top, cls, driver in VEHICLES:
        length, width = (12.0 + rng.random(), 2.5) if cls == "Truck" else (4.3 + rng.random(), 1.9)
        marks = markings[direction]
        centre = 0.5 * (marks[lane_from_top] + marks[lane_from_top + 1]) + rng.normal(0.0, 0.2)
        sign = 1.0 if direction == 2 else -1.0
        speed = 25.0 + 10.0 * rng.random()
        x0 = 20.0 + 30.0 * rng.random() if direction == 2 else 380.0 - 30.0 * rng.random()
        first = int(rng.integers(0, 5))
        frames = np.arange(first, first + N_FRAMES)
        t = (frames - first) / 25.0
        accel = rng.normal(0.0, 0.3, N_FRAMES)
        lane_id = (2 + lane_from_top) if direction == 1 else (6 + lane_from_top)
        for k, frame in enumerate(frames):
            track_rows.append(
                {
                    "frame": frame,
                    "id": vid,
                    "x": x0 + sign * speed * t[k],
                    "y": centre - width / 2,
                    "width": length,
                    "height": width,
                    "xVelocity": sign * speed + rng.normal(0.0, 0.1),
                    "yVelocity": rng.normal(0.0, 0.05),
                    "xAcceleration": sign * accel[k],
                    "yAcceleration": rng.normal(0.0, 0.02),
                    "frontSightDistance": 300.0 * rng.random(),
                    "backSightDistance": 100.0 * rng.random(),
                    "dhw": -1.0 if k % 3 else 35.0 + rng.random(),
                    "thw": -1.0 if k % 3 else 1.2 + rng.random(),
                    "ttc": [-1.0, 0.0, 12.5 + rng.random()][k % 3],
                    "precedingXVelocity": 0.0,
                    "precedingId": 0,
                    "followingId": 0,
                    "leftPrecedingId": 0,
                    "leftAlongsideId": 0,
                    "leftFollowingId": 0,
                    "rightPrecedingId": 0,
                    "rightAlongsideId": 0,
                    "rightFollowingId": 0,
                    "laneId": lane_id,
                }
            )
        vx = np.array([r["xVelocity"] for r in track_rows[-N_FRAMES:]])
        row = {
            "id": vid,
            "width": length,
            "height": width,
            "initialFrame": first,
            "finalFrame": first + N_FRAMES - 1,
            "numFrames": N_FRAMES,
            "class": cls,
            "drivingDirection": direction,
            "traveledDistance": speed * t[-1],
            "minXVelocity": float(vx.min()),
            "maxXVelocity": float(vx.max()),
            "meanXVelocity": float(vx.mean()),
            "minDHW": -1.0,
            "minTHW": -1.0,
            "minTTC": -1.0,
            "numLaneChanges": 0,
        }
        if driver_type:
            row["driverType"] = driver
        meta_rows.append(row)
    tracks = pd.DataFrame(track_rows, columns=list(TRACKS_COLUMNS))
    tracks_meta = pd.DataFrame(meta_rows)
    recording_meta = pd.DataFrame(
        [
            {
                "id": recording_id,
                "frameRate": 25,
                "locationId": 2,
                "speedLimit": -1.0,
                "month": "09.2017",
                "weekDay": "Wed",
                "startTime": "08:38",
                "duration": N_FRAMES / 25.0,
                "totalDrivenDistance": float(tracks_meta["traveledDistance"].sum()),
                "totalDrivenTime": len(VEHICLES) * N_FRAMES / 25.0,
                "numVehicles": len(VEHICLES),
                "numCars": int((tracks_meta["class"] == "Car").sum()),
                "numTrucks": int((tracks_meta["class"] == "Truck").sum()),
                "upperLaneMarkings": UPPER,
                "lowerLaneMarkings": LOWER,
            }
        ]
    )
    return HighDRecording(recording_id, tracks, tracks_meta, recording_meta)


def assert_same(a: HighDRecording, b: HighDRecording) -> None:
    assert a.recording_id == b.recording_id
    for name in ("tracks", "tracks_meta", "recording_meta"):
        pd.testing.assert_frame_equal(getattr(a, name), getattr(b, name), check_exact=True, check_dtype=True)


# ------------------------------------------------------------------------------------------ round trip
@pytest.mark.parametrize("driver_type", [True, False])
def test_round_trip_is_exact(tmp_path, driver_type):
    rec = make_recording(driver_type=driver_type)
    write_recording(rec, tmp_path)
    back = read_recording(tmp_path, 1)
    assert_same(rec, back)
    assert ("driverType" in back.tracks_meta.columns) == driver_type
    # a second round trip is byte-identical
    first = {k: p.read_bytes() for k, p in recording_paths(tmp_path, 1).items()}
    write_recording(back, tmp_path / "again")
    assert {k: p.read_bytes() for k, p in recording_paths(tmp_path / "again", 1).items()} == first


def test_layout_dtypes_and_file_names(tmp_path):
    rec = make_recording()
    paths = write_recording(rec, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["01_recordingMeta.csv", "01_tracks.csv", "01_tracksMeta.csv"]
    assert paths["tracks"].read_text().splitlines()[0] == ",".join(TRACKS_COLUMNS)
    assert paths["tracksMeta"].read_text().splitlines()[0] == ",".join((*TRACKS_META_COLUMNS, "driverType"))
    assert paths["recordingMeta"].read_text().splitlines()[0] == ",".join(RECORDING_META_COLUMNS)
    # ints are written as ints, markings verbatim, month stays text
    first_track = paths["tracks"].read_text().splitlines()[1].split(",")
    assert first_track[TRACKS_COLUMNS.index("laneId")] == "6"
    assert UPPER in paths["recordingMeta"].read_text()
    back = read_recording(tmp_path, 1)
    assert back.tracks["frame"].dtype == np.int64 and back.tracks["x"].dtype == np.float64
    assert back.tracks_meta["numLaneChanges"].dtype == np.int64
    assert pd.api.types.is_string_dtype(back.tracks_meta["class"])
    assert back.meta["month"] == "09.2017" and back.meta["startTime"] == "08:38"
    assert back.frame_rate == 25
    np.testing.assert_array_equal(back.upper_markings, [8.5, 12.1, 15.8, 19.5])
    np.testing.assert_array_equal(back.lower_markings, [21.3, 25.0, 28.7, 32.4])
    assert not list(tmp_path.glob(".*tmp"))  # no temp files left behind


def test_awkward_floats_round_trip(tmp_path):
    rec = make_recording()
    values = np.array([1 / 3, 0.1, 1e-300, -2.5e300, 123456789.123456789, -0.0, np.pi, np.nextafter(1.0, 2.0)])
    rec.tracks.loc[: len(values) - 1, "x"] = values
    rec.tracks_meta["minTTC"] = np.e
    write_recording(rec, tmp_path)
    back = read_recording(tmp_path, 1)
    assert_same(rec, back)
    np.testing.assert_array_equal(back.tracks["x"].to_numpy()[: len(values)], values)


def test_reordered_columns_are_read_in_published_order(tmp_path):
    rec = make_recording()
    rec.tracks = rec.tracks[list(reversed(TRACKS_COLUMNS))]
    write_recording(rec, tmp_path)  # writer restores the published order
    assert list(read_recording(tmp_path, 1).tracks.columns) == list(TRACKS_COLUMNS)
    path = recording_paths(tmp_path, 1)["tracks"]
    pd.read_csv(path)[list(reversed(TRACKS_COLUMNS))].to_csv(path, index=False)
    assert list(read_recording(tmp_path, 1).tracks.columns) == list(TRACKS_COLUMNS)


def test_list_recordings(tmp_path):
    for rid in (3, 1, 12):
        write_recording(make_recording(rid), tmp_path)
    (tmp_path / "notes.txt").write_text("x")
    assert list_recordings(tmp_path) == [1, 3, 12]
    assert (tmp_path / "03_tracks.csv").exists()


# ------------------------------------------------------------------------------ direction-free views
def test_lane_index_both_directions():
    rec = make_recording()
    lane = lane_index_in_direction(rec)
    assert lane.name == "laneIndex" and lane.index.equals(rec.tracks.index)
    per_vehicle = lane.groupby(rec.tracks["id"]).agg(["min", "max"])
    for vid, expected in EXPECTED_LANE_INDEX.items():
        assert per_vehicle.loc[vid, "min"] == per_vehicle.loc[vid, "max"] == expected, vid


def test_lane_index_follows_a_lane_change():
    rec = make_recording()
    rows = rec.tracks.index[rec.tracks["id"] == 3]  # direction 2, rightmost lane (largest y)
    h = rec.tracks.loc[rows, "height"]
    rec.tracks.loc[rows[25:], "y"] = 26.85 - h[rows[25:]] / 2  # move up the image into the middle lane
    lane = lane_index_in_direction(rec)
    assert (lane[rows[:25]] == 0).all() and (lane[rows[25:]] == 1).all()  # moved one lane to the left


def test_lane_index_uses_markings_not_lane_id():
    rec = make_recording()
    rec.tracks["laneId"] = 99
    lane = lane_index_in_direction(rec)
    assert lane.groupby(rec.tracks["id"]).first().to_dict() == EXPECTED_LANE_INDEX


def test_longitudinal_views_go_forward_in_both_directions():
    rec = make_recording()
    pos, speed, acc = longitudinal_position(rec), longitudinal_speed(rec), longitudinal_acceleration(rec)
    assert (speed > 0).all()
    for vid, direction, *_ in VEHICLES:
        rows = rec.tracks["id"] == vid
        t = rec.tracks[rows]
        assert (np.diff(pos[rows].to_numpy()) > 0).all(), vid
        if direction == 2:
            np.testing.assert_array_equal(pos[rows], t["x"] + t["width"])
            np.testing.assert_array_equal(speed[rows], t["xVelocity"])
            np.testing.assert_array_equal(acc[rows], t["xAcceleration"])
        else:
            np.testing.assert_array_equal(pos[rows], -t["x"])
            np.testing.assert_array_equal(speed[rows], -t["xVelocity"])
            np.testing.assert_array_equal(acc[rows], -t["xAcceleration"])


def test_markings_helpers():
    np.testing.assert_array_equal(parse_markings(UPPER), [8.5, 12.1, 15.8, 19.5])
    assert format_markings(parse_markings(LOWER)) == LOWER
    for bad in ("8.5", "8.5;abc", "12.1;8.5", "8.5;nan"):
        with pytest.raises(ValueError):
            parse_markings(bad)


# ------------------------------------------------------------------------------------------ bad input
def _written(tmp_path) -> dict[str, Path]:
    write_recording(make_recording(), tmp_path)
    return recording_paths(tmp_path, 1)


def _set_cell(path: Path, column: str, row: int, value: str) -> None:
    """Overwrite one cell of a CSV, keeping every other cell's text unchanged."""
    df = pd.read_csv(path, dtype=str, na_filter=False)
    df.loc[row, column] = value
    df.to_csv(path, index=False)


def _raises(tmp_path, *fragments: str) -> str:
    with pytest.raises(HighDFormatError) as info:
        read_recording(tmp_path, 1)
    message = str(info.value)
    for fragment in fragments:
        assert fragment in message, (fragment, message)
    return message


@pytest.mark.parametrize("kind", ["tracks", "tracksMeta", "recordingMeta"])
def test_missing_file(tmp_path, kind):
    paths = _written(tmp_path)
    paths[kind].unlink()
    _raises(tmp_path, paths[kind].name, "not found")


@pytest.mark.parametrize("content", ["", "\n"])
@pytest.mark.parametrize("kind", ["tracks", "tracksMeta", "recordingMeta"])
def test_empty_file(tmp_path, kind, content):
    paths = _written(tmp_path)
    paths[kind].write_text(content)
    _raises(tmp_path, paths[kind].name, "empty")


def test_header_only_file(tmp_path):
    paths = _written(tmp_path)
    paths["tracks"].write_text(",".join(TRACKS_COLUMNS) + "\n")
    _raises(tmp_path, "01_tracks.csv", "no data rows")


def test_renamed_column(tmp_path):
    paths = _written(tmp_path)
    text = paths["tracks"].read_text().splitlines(keepends=True)
    paths["tracks"].write_text(text[0].replace("xVelocity", "xVel", 1) + "".join(text[1:]))
    _raises(tmp_path, "01_tracks.csv", "missing expected column(s) ['xVelocity']", "unexpected column(s) ['xVel']")


def test_missing_column_in_meta(tmp_path):
    paths = _written(tmp_path)
    pd.read_csv(paths["tracksMeta"]).drop(columns=["minTTC"]).to_csv(paths["tracksMeta"], index=False)
    _raises(tmp_path, "01_tracksMeta.csv", "'minTTC'")


def test_unexpected_extra_column(tmp_path):
    paths = _written(tmp_path)
    df = pd.read_csv(paths["recordingMeta"], dtype=str)
    df["weather"] = "sunny"
    df.to_csv(paths["recordingMeta"], index=False)
    _raises(tmp_path, "01_recordingMeta.csv", "unexpected column(s) ['weather']")


@pytest.mark.parametrize(
    "kind, column, row, value, what",
    [
        ("tracks", "dhw", 7, "abc", "non-numeric value 'abc'"),
        ("tracks", "x", 11, "NaN", "NaN/missing value"),
        ("tracks", "thw", 4, "", "NaN/missing value"),
        ("tracks", "ttc", 30, "inf", "non-finite value"),
        ("tracks", "laneId", 5, "", "NaN/missing value"),
        ("tracks", "frame", 3, "3.5", "non-integer value '3.5'"),
        ("tracks", "precedingId", 2, "x12", "non-numeric value 'x12'"),
        ("tracksMeta", "minTTC", 2, "-inf", "non-finite value"),
        ("tracksMeta", "numFrames", 1, "fifty", "non-numeric value 'fifty'"),
        ("recordingMeta", "duration", 0, "nan", "NaN/missing value"),
        ("recordingMeta", "frameRate", 0, "25.5", "non-integer value"),
    ],
)
def test_bad_numeric_cell(tmp_path, kind, column, row, value, what):
    paths = _written(tmp_path)
    _set_cell(paths[kind], column, row, value)
    _raises(tmp_path, paths[kind].name, f"column '{column}'", f"data row {row} (line {row + 2})", what)


def test_track_ids_missing_from_meta(tmp_path):
    paths = _written(tmp_path)
    meta = pd.read_csv(paths["tracksMeta"], dtype=str)
    meta[~meta["id"].isin(["2", "5"])].to_csv(paths["tracksMeta"], index=False)
    message = _raises(tmp_path, "01_tracks.csv", "column 'id'", "01_tracksMeta.csv", ": 2, 5")
    assert "..." not in message


def test_many_track_ids_missing_from_meta_are_capped(tmp_path):
    rec = make_recording()
    extra = pd.concat([rec.tracks.iloc[:1].assign(id=100 + k) for k in range(15)], ignore_index=True)
    rec.tracks = pd.concat([rec.tracks, extra], ignore_index=True)
    write_recording(rec, tmp_path)
    message = _raises(tmp_path, "01_tracks.csv", "15 vehicle id(s)", "100, 101", "109, ...")
    assert "110" not in message


def test_bad_markings(tmp_path):
    paths = _written(tmp_path)
    _set_cell(paths["recordingMeta"], "upperLaneMarkings", 0, "8.5;oops;15.8")
    _raises(tmp_path, "01_recordingMeta.csv", "column 'upperLaneMarkings'", "data row 0")


def test_bad_driving_direction(tmp_path):
    paths = _written(tmp_path)
    _set_cell(paths["tracksMeta"], "drivingDirection", 4, "3")
    _raises(tmp_path, "01_tracksMeta.csv", "column 'drivingDirection'", "data row 4")


def test_recording_id_mismatch(tmp_path):
    paths = _written(tmp_path)
    _set_cell(paths["recordingMeta"], "id", 0, "7")
    _raises(tmp_path, "01_recordingMeta.csv", "column 'id'")


def test_ragged_row(tmp_path):
    paths = _written(tmp_path)
    with paths["tracks"].open("a") as fh:
        fh.write("1,2,3\n" + ",".join(["1"] * (len(TRACKS_COLUMNS) + 2)) + "\n")
    _raises(tmp_path, "01_tracks.csv")


def test_write_rejects_bad_tables(tmp_path):
    rec = make_recording()
    rec.tracks = rec.tracks.drop(columns=["laneId"])
    with pytest.raises(HighDFormatError, match=r"01_tracks\.csv.*laneId"):
        write_recording(rec, tmp_path)
    rec = make_recording()
    rec.tracks.loc[9, "dhw"] = np.nan
    with pytest.raises(HighDFormatError, match=r"01_tracks\.csv, column 'dhw', data row 9"):
        write_recording(rec, tmp_path)
    assert not any(tmp_path.iterdir())  # nothing written when validation fails
