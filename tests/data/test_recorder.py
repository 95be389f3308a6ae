"""The traffic recorder: HighD-format recordings of the simulator's background traffic."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from kddrl_trl.data.highd import (
    TRACKS_COLUMNS,
    lane_index_in_direction,
    list_recordings,
    longitudinal_position,
    read_recording,
)
from kddrl_trl.data.sumo_to_highd import (
    DRIVER_PARAMS_COLUMNS,
    FRAME_RATE,
    read_driver_params,
    record_traffic,
)
from kddrl_trl.envs import make_config

DURATION = 60.0


@pytest.fixture(scope="module")
def recorded():
    cfg = make_config("baseline")
    return cfg, record_traffic(cfg, DURATION, num_roads=2, seed=0, progress=False)


def _lookup(tracks: pd.DataFrame) -> pd.DataFrame:
    return tracks.set_index(["id", "frame"])


def test_one_recording_per_road_with_vehicles(recorded, no_sumo_open):
    cfg, recs = recorded
    assert [r.recording_id for r in recs] == [1, 2]
    for rec in recs:
        meta = rec.recording.recording_meta.iloc[0]
        assert meta["frameRate"] == FRAME_RATE and meta["duration"] == DURATION
        assert meta["numVehicles"] == len(rec.recording.tracks_meta) == meta["numCars"] > 10
        assert rec.recording.tracks["frame"].between(0, DURATION * FRAME_RATE - 1).all()
        assert (rec.recording.tracks_meta["drivingDirection"] == 2).all()
        assert (rec.recording.tracks["xVelocity"] >= 0).all()
        assert list(rec.recording.tracks.columns) == list(TRACKS_COLUMNS)
        # every row is in the field of view: the box overlaps [0, section_length]
        tracks = rec.recording.tracks
        assert ((tracks["x"] + tracks["width"] > 0) & (tracks["x"] < cfg.section_length)).all()
        assert len(rec.sim_lane) == len(tracks)


def test_write_read_round_trip(recorded, tmp_path):
    _, recs = recorded
    for rec in recs:
        paths = rec.write(tmp_path)
        assert paths["driverParams"].name == f"{rec.recording_id:02d}_driverParams.csv"
    assert list_recordings(tmp_path) == [1, 2]
    for rec in recs:
        back = read_recording(tmp_path, rec.recording_id)
        for a, b in (
            (rec.recording.tracks, back.tracks),
            (rec.recording.tracks_meta, back.tracks_meta),
            (rec.recording.recording_meta, back.recording_meta),
        ):
            pd.testing.assert_frame_equal(a.reset_index(drop=True), b.reset_index(drop=True), check_dtype=False)
            assert all(
                str(b[c].dtype) != "object"
                or c
                in ("class", "driverType", "month", "weekDay", "startTime", "upperLaneMarkings", "lowerLaneMarkings")
                for c in b.columns
            )
        params = read_driver_params(tmp_path, rec.recording_id)
        assert list(params.columns) == list(DRIVER_PARAMS_COLUMNS)
        pd.testing.assert_frame_equal(params, rec.driver_params.reset_index(drop=True), check_dtype=False)


def test_frames_consecutive_and_meta_consistent(recorded):
    _, recs = recorded
    for rec in recs:
        tracks, meta = rec.recording.tracks, rec.recording.tracks_meta.set_index("id")
        ids = meta.index.to_numpy()
        assert np.array_equal(np.sort(ids), np.arange(1, len(ids) + 1))
        for vid, grp in tracks.groupby("id"):
            frames = grp["frame"].to_numpy()
            assert np.all(np.diff(frames) == 1), vid
            m = meta.loc[vid]
            assert (m["initialFrame"], m["finalFrame"], m["numFrames"]) == (frames[0], frames[-1], len(frames))
            lane_changes = int(np.count_nonzero(np.diff(grp["laneId"].to_numpy())))
            assert m["numLaneChanges"] == lane_changes
        # ids in order of first appearance
        assert np.all(np.diff(meta.sort_index()["initialFrame"].to_numpy()) >= 0)


def test_lane_index_matches_simulator_lane(recorded):
    cfg, recs = recorded
    n = cfg.num_lanes
    total_changes = 0
    for rec in recs:
        tracks = rec.recording.tracks
        lane = lane_index_in_direction(rec.recording).to_numpy()
        assert np.array_equal(lane, rec.sim_lane)  # SUMO's lane behind each row
        assert np.array_equal(tracks["laneId"].to_numpy(), 2 * n + 2 - lane)  # HighD numbering, lower half
        markings = rec.recording.lower_markings
        assert len(markings) == n + 1 and np.allclose(np.diff(markings), cfg.lane_width)
        total_changes += int(rec.recording.tracks_meta["numLaneChanges"].sum())
    assert total_changes > 0, "no lane change in two minutes of traffic: lane changes are not recorded"


def test_driver_type_matches_vehicle_params(recorded):
    cfg, recs = recorded
    classes = {d.name: d for d in cfg.drivers}
    for rec in recs:
        meta = rec.recording.tracks_meta.set_index("id")
        params = rec.driver_params.set_index("id")
        assert params.index.equals(meta.index)
        assert (params["driverType"] == meta["driverType"]).all()
        assert set(meta["driverType"]) <= set(classes)
        # the true parameters lie within ±2 sd of their class's values (the simulator's truncated draw)
        for vid, row in params.iterrows():
            cls = classes[row["driverType"]]
            for p in ("v0", "T", "s0", "a", "b"):
                base = getattr(cls, p)
                assert abs(row[p] - base) <= 2 * cls.spread * base + 1e-9, (vid, p)
        # SUMO ids are unique and belong to this road
        assert len(set(rec.sumo_ids.values())) == len(rec.sumo_ids) == len(meta)
        assert all(s.startswith(f"h{rec.road}.") for s in rec.sumo_ids.values())


def test_preceding_vehicle_and_gap(recorded):
    _, recs = recorded
    checked = 0
    for rec in recs:
        tracks = rec.recording.tracks.copy()
        tracks["pos"] = longitudinal_position(rec.recording)
        tracks["lane"] = lane_index_in_direction(rec.recording)
        by = _lookup(tracks)
        has = tracks[tracks["precedingId"] > 0]
        lead = by.loc[list(zip(has["precedingId"], has["frame"]))]  # KeyError if not in the same frame
        assert np.array_equal(lead["lane"].to_numpy(), has["lane"].to_numpy())
        assert np.all(lead["pos"].to_numpy() > has["pos"].to_numpy())
        gap = lead["x"].to_numpy() - (has["x"] + has["width"]).to_numpy()
        np.testing.assert_allclose(has["dhw"].to_numpy(), gap, atol=1e-9)
        np.testing.assert_allclose(has["precedingXVelocity"].to_numpy(), lead["xVelocity"].to_numpy())
        np.testing.assert_allclose(has["thw"].to_numpy(), gap / has["xVelocity"].to_numpy())
        none = tracks[tracks["precedingId"] == 0]
        assert (none["dhw"] == -1).all() and (none["thw"] == -1).all() and (none["ttc"] == -1).all()
        assert (none["precedingXVelocity"] == 0).all()
        closing = has["xVelocity"].to_numpy() > lead["xVelocity"].to_numpy()
        assert np.all((has["ttc"].to_numpy() > 0) == closing) and np.all(has["ttc"].to_numpy()[~closing] == -1)
        # following ids point back to the same lane, behind
        fol = tracks[tracks["followingId"] > 0]
        back = by.loc[list(zip(fol["followingId"], fol["frame"]))]
        assert np.array_equal(back["lane"].to_numpy(), fol["lane"].to_numpy())
        assert np.all(back["pos"].to_numpy() < fol["pos"].to_numpy())
        checked += len(has)
    assert checked > 100


def test_side_neighbours(recorded):
    _, recs = recorded
    for rec in recs:
        tracks = rec.recording.tracks.copy()
        tracks["pos"] = longitudinal_position(rec.recording)
        tracks["lane"] = lane_index_in_direction(rec.recording)
        by = _lookup(tracks)
        for side, step in (("left", 1), ("right", -1)):
            for kind in ("Preceding", "Alongside", "Following"):
                col = f"{side}{kind}Id"
                rows = tracks[tracks[col] > 0]
                other = by.loc[list(zip(rows[col], rows["frame"]))]
                assert np.array_equal(other["lane"].to_numpy(), rows["lane"].to_numpy() + step), col
                front, rear = rows["pos"].to_numpy(), rows["pos"].to_numpy() - rows["width"].to_numpy()
                o_front, o_rear = other["pos"].to_numpy(), other["pos"].to_numpy() - other["width"].to_numpy()
                # ids come from the latest 0.1 s sample: exact on frames that fall on a sample (every 5th
                # 25 Hz frame), elsewhere off by what the relative speed covers in under 0.1 s
                exact = (rows["frame"].to_numpy() % 5) == 0
                tol = np.where(
                    exact, 1e-9, np.abs(rows["xVelocity"].to_numpy() - other["xVelocity"].to_numpy()) * 0.1 + 0.05
                )
                if kind == "Preceding":
                    assert np.all(o_rear >= front - tol), col
                elif kind == "Following":
                    assert np.all(o_front <= rear + tol), col
                else:
                    assert np.all((o_rear < front + tol) & (o_front > rear - tol)), col
                assert exact.any()
        # lanes that do not exist have no neighbours
        assert (
            (tracks.loc[tracks["lane"] == 0, ["rightPrecedingId", "rightAlongsideId", "rightFollowingId"]] == 0)
            .all()
            .all()
        )


def test_first_frame_is_where_the_vehicle_enters_the_view(recorded):
    cfg, recs = recorded
    for rec in recs:
        tracks = rec.recording.tracks
        first = tracks.groupby("id").head(1)
        last = tracks.groupby("id").tail(1)
        entered = first[first["frame"] > 0]
        assert len(entered) > 10
        front = (entered["x"] + entered["width"]).to_numpy()
        step = entered["xVelocity"].to_numpy() / FRAME_RATE
        # the front bumper crossed 0 within the last 25 Hz frame (speed changes little within 0.04 s)
        assert np.all(front > 0) and np.all(front <= step + 0.05)
        assert np.all(entered["backSightDistance"] < 0)
        # and a vehicle is dropped when its rear leaves the section (or the recording ends)
        left = last[last["frame"] < DURATION * FRAME_RATE - 1]
        rear = left["x"].to_numpy()
        assert np.all(rear < cfg.section_length) and np.all(
            rear >= cfg.section_length - left["xVelocity"] / FRAME_RATE - 0.05
        )


def test_record_entry_point_runs_from_any_directory(tmp_path):
    out = tmp_path / "recs"
    cmd = [
        sys.executable,
        "-m",
        "kddrl_trl.record",
        "duration_s=20",
        "num_roads=1",
        "progress=false",
        f"out_dir={out}",
    ]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    names = sorted(p.name for p in out.iterdir())
    assert names == ["01_driverParams.csv", "01_recordingMeta.csv", "01_tracks.csv", "01_tracksMeta.csv"]
    rec = read_recording(out, 1)
    assert rec.meta["duration"] == 20.0 and rec.meta["numVehicles"] > 0
    assert "lane changers" in done.stdout and "15.8" in done.stdout
    assert len(list((tmp_path / "runs").glob("record__baseline__0__*"))) == 1
