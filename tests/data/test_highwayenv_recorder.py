"""HighwayEnv's traffic recorded in the HighD format (``kddrl_trl.data.highwayenv_to_highd``): tracks that agree
with HighwayEnv's own vehicles, episodes as separate tracks, repeatable, and a dataset the GANs can learn from.
Skipped without ``highway_env`` (the optional extra ``.[highway]``)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("highway_env")

from testkit import run_module  # noqa: E402

from kddrl_trl.data.extract import extract_dataset  # noqa: E402
from kddrl_trl.data.highd import lane_index_in_direction, list_recordings, read_recording  # noqa: E402
from kddrl_trl.data.highwayenv_to_highd import record_highwayenv_traffic  # noqa: E402
from kddrl_trl.data.sumo_to_highd import FRAME_RATE, read_driver_params  # noqa: E402
from kddrl_trl.envs import make_config  # noqa: E402
from kddrl_trl.highwayenv_options import HighwayEnvOptions  # noqa: E402

OPTIONS = HighwayEnvOptions(vehicles_count=12, record_episode_s=8.0)
DURATION = 16.0  # two episodes per recording


def _config():
    return make_config("baseline", {"lane_width": 4.0})


@pytest.fixture(scope="module")
def recorded():
    return record_highwayenv_traffic(_config(), DURATION, num_roads=2, seed=3, progress=False, options=OPTIONS)


def test_every_vehicle_of_every_episode_is_one_track_inside_its_episode(recorded):
    assert [r.recording_id for r in recorded] == [1, 2]
    for rec in recorded:
        tracks, meta = rec.recording.tracks, rec.recording.tracks_meta
        # 12 background vehicles + the ego driven by HighwayEnv's IDM, in each of the two episodes
        assert len(meta) == 2 * (OPTIONS.vehicles_count + 1)
        episode_frames = OPTIONS.record_episode_s * FRAME_RATE
        first = (meta["initialFrame"] // episode_frames).to_numpy()
        last = (meta["finalFrame"] // episode_frames).to_numpy()
        np.testing.assert_array_equal(first, last)  # no track crosses an episode's end
        assert sorted(np.bincount(first.astype(int)).tolist()) == [13, 13]
        assert tracks["frame"].max() < DURATION * FRAME_RATE


def test_tracks_are_consistent_highd(recorded):
    for rec in recorded:
        tracks = rec.recording.tracks
        lanes = lane_index_in_direction(rec.recording).to_numpy()
        assert set(np.unique(lanes)) <= {0, 1, 2}
        # the lane written is the lane the box centre is in (as the HighwayEnv adapter reads lanes)
        np.testing.assert_array_equal(lanes, rec.sim_lane)
        # speeds are those the positions move by (25 Hz frames interpolated from the 0.1 s samples)
        by_id = tracks.sort_values(["id", "frame"])
        same = by_id["id"].to_numpy()[1:] == by_id["id"].to_numpy()[:-1]
        dx = np.diff(by_id["x"].to_numpy())[same] * FRAME_RATE
        v = 0.5 * (by_id["xVelocity"].to_numpy()[1:] + by_id["xVelocity"].to_numpy()[:-1])[same]
        assert np.median(np.abs(dx - v)) < 0.3
        assert (by_id["xVelocity"] > 0).mean() > 0.99


def test_driver_parameters_are_highwayenvs_idm(recorded):
    params = recorded[0].driver_params
    assert (params["driverType"] == "unknown").all()
    np.testing.assert_allclose(params["s0"], 5.0)  # DISTANCE_WANTED (10 m between centres) minus the 5 m length
    np.testing.assert_allclose(params["T"], 1.5)
    assert params["v0"].between(15.0, 40.0).all()


def test_the_same_seed_records_the_same_traffic(recorded):
    again = record_highwayenv_traffic(_config(), DURATION, num_roads=1, seed=3, progress=False, options=OPTIONS)
    assert again[0].recording.tracks.equals(recorded[0].recording.tracks)
    other = record_highwayenv_traffic(_config(), DURATION, num_roads=1, seed=4, progress=False, options=OPTIONS)
    assert not other[0].recording.tracks.equals(recorded[0].recording.tracks)


def test_recorded_traffic_gives_both_gan_datasets(recorded, tmp_path):
    meta = extract_dataset([r.recording for r in recorded], tmp_path / "ds", seed=0, progress=False)
    counts = meta["counts"]
    assert sum(counts["leaders"][s]["samples"] for s in meta["splits"]) > 100
    assert sum(counts["lane_changes"][s]["samples"] for s in meta["splits"]) > 100


def test_record_entry_point_records_highwayenv_traffic(tmp_path):
    out = tmp_path / "rec"
    run_module(
        [
            "kddrl_trl.record",
            "env=highwayenv",
            "duration_s=6",
            "num_roads=1",
            "env.highwayenv.vehicles_count=6",
            "env.highwayenv.record_episode_s=3",
            f"out_dir={out}",
            f"hydra.run.dir={tmp_path / 'run'}",
            "progress=false",
        ],
        tmp_path,
    )
    assert list_recordings(out) == [1]
    assert len(read_recording(out, 1).tracks_meta) == 2 * 7
    assert len(read_driver_params(out, 1)) == 2 * 7


def test_record_episode_length_is_checked():
    with pytest.raises(ValueError, match="record_episode_s"):
        record_highwayenv_traffic(
            _config(), 10.0, num_roads=1, progress=False, options=HighwayEnvOptions(record_episode_s=1000.0)
        )


def test_a_vehicle_length_other_than_highwayenvs_is_refused():
    cfg = make_config("baseline", {"lane_width": 4.0, "vehicle_length": 4.5})
    with pytest.raises(ValueError, match="vehicle_length"):
        record_highwayenv_traffic(cfg, 10.0, num_roads=1, progress=False, options=OPTIONS)
