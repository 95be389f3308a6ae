"""Tests of the 10 Hz track table (:mod:`kddrl_trl.data.tracks`) and sample extraction
(:mod:`kddrl_trl.data.extract`) on small recordings synthesised here (both directions, platoons, lane changes)."""

from __future__ import annotations

import dataclasses
import json
import time

import numpy as np
import pandas as pd
import pytest
import torch

from kddrl_trl.data import TRACKS_COLUMNS, HighDRecording, longitudinal_position
from kddrl_trl.data.extract import (
    DRIVER_TYPES,
    KEY_STEPS,
    extract_dataset,
    lane_change_samples,
    leader_samples,
    load_dataset,
    split_by_vehicle,
    window_labels,
)
from kddrl_trl.data.highd import NEIGHBOUR_ID_COLUMNS
from kddrl_trl.data.tracks import TRACKS10_COLUMNS, TRACKS10_DTYPES, longitudinal_tracks, vehicle_num_lanes
from kddrl_trl.physics.idm import IDMParams, idm_rollout

W = 3.75  # lane width (m)
UPPER = "8.0;11.75;15.5;19.25"  # direction 1 (toward -x), rightmost lane at the top
LOWER = "21.0;24.75;28.5;32.25"  # direction 2 (toward +x), rightmost lane at the bottom
ROAD = 420.0
LANE_SPEED = (24.0, 29.0, 34.0)  # m/s, lane 0 (rightmost) .. 2
DRIVERS = ("timid", "normal", "aggressive")
LC_TIME = 3.0  # s, duration of a synthetic lane change


def _neighbors(df: pd.DataFrame) -> pd.DataFrame:
    """HighD-style neighbour ids from direction-free positions (s = front bumper, lane from the right)."""
    df = df.copy()
    df["rear"] = df["s"] - df["L"]
    grp = ["frame", "dir", "lane"]
    srt = df.sort_values([*grp, "s"])
    same = srt[grp].eq(srt[grp].shift(-1)).all(axis=1)
    df.loc[srt.index, "precedingId"] = np.where(same, srt["id"].shift(-1).fillna(0), 0)
    same = srt[grp].eq(srt[grp].shift(1)).all(axis=1)
    df.loc[srt.index, "followingId"] = np.where(same, srt["id"].shift(1).fillna(0), 0)
    for side, off in (("left", 1), ("right", -1)):
        q = df[["frame", "dir", "lane", "s", "rear"]].copy()
        q["lane"] = q["lane"] + off
        q["row"] = np.arange(len(q))
        cand = df[["frame", "dir", "lane", "s", "rear", "id"]]
        # preceding: nearest with its rear at or ahead of the ego's front
        a = pd.merge_asof(
            q.sort_values("s"),
            cand.rename(columns={"s": "s_o", "rear": "key"}).sort_values("key"),
            left_on="s",
            right_on="key",
            by=grp,
            direction="forward",
        )
        df.loc[df.index[a["row"]], f"{side}PrecedingId"] = a["id"].fillna(0).to_numpy()
        # following: nearest with its front at or behind the ego's rear
        f = pd.merge_asof(
            q.sort_values("rear"),
            cand.rename(columns={"s": "key", "rear": "r_o"}).sort_values("key"),
            left_on="rear",
            right_on="key",
            by=grp,
            direction="backward",
        )
        df.loc[df.index[f["row"]], f"{side}FollowingId"] = f["id"].fillna(0).to_numpy()
        # alongside: the first front beyond the ego's rear, if that vehicle's rear is before the ego's front
        g = pd.merge_asof(
            q.sort_values("rear"),
            cand.rename(columns={"s": "key", "rear": "r_o"}).sort_values("key"),
            left_on="rear",
            right_on="key",
            by=grp,
            direction="forward",
            allow_exact_matches=False,
        )
        along = np.where(g["r_o"].to_numpy() < g["s"].to_numpy(), g["id"].fillna(0).to_numpy(), 0)
        df.loc[df.index[g["row"]], f"{side}AlongsideId"] = along
    return df


def synth_recording(
    recording_id: int = 1,
    duration: float = 20.0,
    headway: float = 2.5,
    seed: int = 0,
    lane_change_every: int = 4,
    driver_type: bool = True,
) -> HighDRecording:
    """Platoons on 3 lanes per direction over a 420 m road; every ``lane_change_every``-th vehicle of the
    right lane changes left and of the left lane changes right, half-way along the road.

    Returns the recording; ``rec.truth`` (an attribute added here) holds the direction-free ground truth
    per 25 Hz row (dir, lane, s, lat)."""
    rng = np.random.default_rng(seed)
    fr = 25
    n_frames = int(round(duration * fr))
    veh = []
    vid = 0
    for direction in (1, 2):
        for lane in range(3):
            v = LANE_SPEED[lane] + rng.normal(0.0, 0.5)
            t_enter = np.arange(-ROAD / v, duration, headway * (1.0 + 0.1 * lane))
            for k, te in enumerate(t_enter + rng.uniform(0.0, 0.3 * headway, len(t_enter))):
                vid += 1
                change = 0
                if lane_change_every and k % lane_change_every == 1 and lane in (0, 2):
                    change = 1 if lane == 0 else -1
                veh.append(
                    dict(
                        id=vid,
                        dir=direction,
                        lane0=lane,
                        v=v,
                        te=te,
                        change=change,
                        L=4.5 if vid % 5 else 12.0,
                        H=1.9 if vid % 5 else 2.5,
                        amp=rng.uniform(0.2, 1.0),
                        om=rng.uniform(0.3, 0.8),
                        ph=rng.uniform(0, 6.28),
                        driver=DRIVERS[vid % 3],
                    )
                )
    vt = pd.DataFrame(veh)
    # rows: every frame during which the vehicle's front is on the road
    t_all = np.arange(n_frames) / fr
    start = np.clip(np.ceil(vt["te"].to_numpy() * fr), 0, n_frames).astype(int)
    stop = np.clip(np.floor((vt["te"] + ROAD / vt["v"]).to_numpy() * fr), -1, n_frames - 1).astype(int)
    n = np.maximum(stop - start + 1, 0)
    keep = n >= 2
    vt, start, n = vt[keep].reset_index(drop=True), start[keep], n[keep]
    i = np.repeat(np.arange(len(vt)), n)
    frame = start[i] + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    t = t_all[frame]
    g = vt.iloc[i].reset_index(drop=True)
    tau = t - g["te"].to_numpy()
    amp, om, ph, v = g["amp"].to_numpy(), g["om"].to_numpy(), g["ph"].to_numpy(), g["v"].to_numpy()
    s = v * tau + amp * np.sin(om * tau + ph) - amp * np.sin(ph)
    speed = v + amp * om * np.cos(om * tau + ph)
    acc = -amp * om**2 * np.sin(om * tau + ph)
    # lateral: smoothstep lane change starting when the front passes mid-road
    t_lc = ROAD / 2 / v
    u = np.clip((tau - t_lc) / LC_TIME, 0.0, 1.0)
    du = np.where((u > 0) & (u < 1), 1.0 / LC_TIME, 0.0)
    ch = g["change"].to_numpy()
    lat = (g["lane0"].to_numpy() + 0.5) * W + ch * W * (3 * u**2 - 2 * u**3)
    vlat = ch * W * (6 * u - 6 * u**2) * du
    lane = np.clip(np.floor(lat / W), 0, 2).astype(int)
    d2 = g["dir"].to_numpy() == 2
    L, H = g["L"].to_numpy(), g["H"].to_numpy()
    upper, lower = np.array(UPPER.split(";"), float), np.array(LOWER.split(";"), float)
    centre = np.where(d2, lower[-1] - lat, upper[0] + lat)
    df = pd.DataFrame(
        {
            "frame": frame,
            "id": g["id"].to_numpy(),
            "x": np.where(d2, s - L, ROAD - s),
            "y": centre - H / 2,
            "width": L,
            "height": H,
            "xVelocity": np.where(d2, speed, -speed),
            "yVelocity": np.where(d2, -vlat, vlat),
            "xAcceleration": np.where(d2, acc, -acc),
            "yAcceleration": 0.0,
            "frontSightDistance": 100.0,
            "backSightDistance": 100.0,
            "dhw": -1.0,
            "thw": -1.0,
            "ttc": -1.0,
            "precedingXVelocity": 0.0,
            "laneId": lane + 2,
            "dir": g["dir"].to_numpy(),
            "lane": lane,
            "s": s,
            "L": L,
        }
    )
    for c in NEIGHBOUR_ID_COLUMNS:
        df[c] = 0
    df = _neighbors(df)
    truth = df[["id", "frame", "dir", "lane", "s"]].reset_index(drop=True)
    tracks = (
        df[list(TRACKS_COLUMNS)]
        .astype({c: "int64" for c in TRACKS_COLUMNS if c.endswith("Id") or c in ("frame", "id")})
        .reset_index(drop=True)
    )
    per = tracks.groupby("id")
    meta = pd.DataFrame(
        {
            "id": vt["id"].to_numpy(),
            "width": vt["L"].to_numpy(),
            "height": vt["H"].to_numpy(),
            "initialFrame": per["frame"].min().reindex(vt["id"]).to_numpy(),
            "finalFrame": per["frame"].max().reindex(vt["id"]).to_numpy(),
            "numFrames": per.size().reindex(vt["id"]).to_numpy(),
            "class": np.where(vt["L"] > 10, "Truck", "Car"),
            "drivingDirection": vt["dir"].to_numpy(),
            "traveledDistance": 100.0,
            "minXVelocity": 20.0,
            "maxXVelocity": 30.0,
            "meanXVelocity": 25.0,
            "minDHW": -1.0,
            "minTHW": -1.0,
            "minTTC": -1.0,
            "numLaneChanges": (vt["change"] != 0).astype(int).to_numpy(),
        }
    )
    if driver_type:
        meta["driverType"] = vt["driver"].to_numpy()
    rmeta = pd.DataFrame(
        [
            {
                "id": recording_id,
                "frameRate": fr,
                "locationId": 1,
                "speedLimit": -1.0,
                "month": "01.2020",
                "weekDay": "Mon",
                "startTime": "10:00",
                "duration": duration,
                "totalDrivenDistance": 1.0,
                "totalDrivenTime": 1.0,
                "numVehicles": len(meta),
                "numCars": len(meta),
                "numTrucks": 0,
                "upperLaneMarkings": UPPER,
                "lowerLaneMarkings": LOWER,
            }
        ]
    )
    rec = HighDRecording(recording_id, tracks, meta, rmeta)
    rec.truth = truth
    return rec


@pytest.fixture(scope="module")
def rec():
    return synth_recording(1)


@pytest.fixture(scope="module")
def tracks(rec):
    return longitudinal_tracks(rec)


@pytest.fixture(scope="module")
def leaders(tracks):
    return leader_samples(tracks)


@pytest.fixture(scope="module")
def changes(tracks, rec):
    return lane_change_samples(tracks)


def _at(tracks: pd.DataFrame, vid, frame, column: str) -> np.ndarray:
    """tracks[column] of (vehicle, frame) pairs (NaN where absent)."""
    s = tracks.set_index(["vehicle_id", "frame"])[column]
    return s.reindex(pd.MultiIndex.from_arrays([np.asarray(vid), np.asarray(frame)])).to_numpy()


# ------------------------------------------------------------------------------------------- tracks10
def test_tracks10_columns_dtypes_and_order(tracks, rec):
    assert tuple(tracks.columns) == TRACKS10_COLUMNS
    for c, d in TRACKS10_DTYPES.items():
        if d == "str":
            assert pd.api.types.is_string_dtype(tracks[c]), c
        else:
            assert tracks[c].dtype == np.dtype(d), c
    key = tracks[["recording_id", "vehicle_id", "frame"]].to_numpy()
    assert (np.lexsort(key[:, ::-1].T) == np.arange(len(key))).all()
    same = tracks["vehicle_id"].diff() == 0
    assert (tracks["frame"].diff()[same] == 1).all()
    np.testing.assert_allclose(tracks["t"], tracks["frame"] / 10.0)
    assert set(tracks["driver_type"]) == set(DRIVERS)
    assert set(tracks["vehicle_id"]) <= set(rec.tracks_meta["id"])
    # times are inside each vehicle's 25 Hz span
    span = rec.tracks.groupby("id")["frame"].agg(["min", "max"]) / 25.0
    lo, hi = span["min"].reindex(tracks["vehicle_id"]).to_numpy(), span["max"].reindex(tracks["vehicle_id"]).to_numpy()
    assert ((tracks["t"] >= lo - 1e-9) & (tracks["t"] <= hi + 1e-9)).all()


def test_tracks10_both_directions_travel_toward_plus_y(tracks, rec):
    direction = tracks["vehicle_id"].map(rec.tracks_meta.set_index("id")["drivingDirection"])
    assert set(direction) == {1, 2}
    for d in (1, 2):
        sub = tracks[direction == d]
        dy = sub.groupby("vehicle_id")["y"].diff().dropna()
        assert (dy > 0).all(), d
        assert (sub["v"] > 0).all()
        # x_lat from the right edge: lane = floor(x_lat / W), within the carriageway
        assert ((sub["x_lat"] > 0) & (sub["x_lat"] < 3 * W)).all()
        even = sub[sub["frame"] % 2 == 0]  # on a 25 Hz row (odd frames: lane from the row before, x_lat interp.)
        np.testing.assert_array_equal(even["lane"], np.clip(np.floor(even["x_lat"] / W), 0, 2).astype(int))


def test_tracks10_interpolation_matches_25hz(tracks, rec):
    # 10 Hz frame 2k is 25 Hz frame 5k exactly; odd 10 Hz frames lie half-way between 25 Hz frames 5k+2, 5k+3
    pos = pd.Series(
        longitudinal_position(rec).to_numpy(), index=pd.MultiIndex.from_arrays([rec.tracks["id"], rec.tracks["frame"]])
    )
    even = tracks[tracks["frame"] % 2 == 0]
    np.testing.assert_allclose(
        even["y"],
        pos.reindex(pd.MultiIndex.from_arrays([even["vehicle_id"], even["frame"] * 5 // 2])).to_numpy(),
        rtol=0,
        atol=1e-9,
    )
    odd = tracks[tracks["frame"] % 2 == 1]
    f = odd["frame"].to_numpy() * 5 // 2
    a = pos.reindex(pd.MultiIndex.from_arrays([odd["vehicle_id"], f])).to_numpy()
    b = pos.reindex(pd.MultiIndex.from_arrays([odd["vehicle_id"], f + 1])).to_numpy()
    np.testing.assert_allclose(odd["y"], 0.5 * (a + b), rtol=0, atol=1e-9)
    # lateral speed is + to the left in both directions for the vehicles changing left
    changers = rec.tracks_meta.loc[rec.tracks_meta["numLaneChanges"] > 0, "id"]
    sub = tracks[tracks["vehicle_id"].isin(changers)]
    went_left = sub.groupby("vehicle_id")["lane"].agg(lambda s: s.iloc[-1] - s.iloc[0])
    for vid, d_lane in went_left.items():
        v = sub.loc[sub["vehicle_id"] == vid, "vx_lat"]
        if d_lane:
            assert np.sign(v[v.abs() > 0.1]).eq(np.sign(d_lane)).all()


def test_tracks10_other_rate_and_num_lanes(rec):
    t5 = longitudinal_tracks(rec, hz=5.0)
    np.testing.assert_allclose(t5["t"], t5["frame"] / 5.0)
    assert (vehicle_num_lanes(rec) == 3).all()


# -------------------------------------------------------------------------------- lane-change samples
def test_lane_change_samples_schema(changes, tracks):
    n = changes.batch_size[0]
    assert n > 0
    shapes = {
        "label": [n],
        "s_av": [n, 4],
        "rel": [n, 6, 4],
        "lane_offset": [n, 6],
        "mask": [n, 6],
        "key_gaps": [n, 3, 2],
        "key_gaps_mask": [n, 3],
        "num_lanes": [n],
        "recording_id": [n],
        "vehicle_id": [n],
        "frame": [n],
        "driver": [n],
    }
    assert set(changes.keys()) == set(shapes)
    for k, s in shapes.items():
        assert list(changes[k].shape) == s, k
    assert changes["label"].dtype == torch.int64 and changes["mask"].dtype == torch.bool
    assert changes["rel"].dtype == torch.float32 and (changes["num_lanes"] == 3).all()
    # every sample's window lies inside the ego's track
    end = _at(tracks, changes["vehicle_id"].numpy(), changes["frame"].numpy() + 20, "y")
    assert np.isfinite(end).all()
    assert (changes["rel"][~changes["mask"]] == 0).all()
    assert (changes["lane_offset"][~changes["mask"]] == 0).all()
    # the ego's lane offset (S_AV[3]) is the tracks' one; the current leader's is its own at the same frame
    np.testing.assert_allclose(
        changes["s_av"][:, 3].numpy(),
        _at(tracks, changes["vehicle_id"].numpy(), changes["frame"].numpy(), "lane_offset"),
        atol=1e-5,
    )
    has_b = changes["mask"][:, 1].numpy()
    pid = _at(tracks, changes["vehicle_id"].numpy()[has_b], changes["frame"].numpy()[has_b], "preceding_id")
    np.testing.assert_allclose(
        changes["lane_offset"][has_b, 1].numpy(),
        _at(tracks, pid, changes["frame"].numpy()[has_b], "lane_offset"),
        atol=1e-5,
    )
    assert (changes["key_gaps"][~changes["key_gaps_mask"]] == 0).all()
    assert not (changes["key_gaps_mask"] & ~changes["mask"][:, :3]).any()
    names = [DRIVER_TYPES[i] for i in changes["driver"].tolist()]
    assert names == list(_at(tracks, changes["vehicle_id"].numpy(), changes["frame"].numpy(), "driver_type"))


def test_lane_change_labels_match_the_lane_the_vehicle_ends_in(changes, tracks, rec):
    vid, frame, label = changes["vehicle_id"].numpy(), changes["frame"].numpy(), changes["label"].numpy()
    lane0 = _at(tracks, vid, frame, "lane")
    lane1 = _at(tracks, vid, frame + 20, "lane")
    expected = np.select([lane1 > lane0, lane1 < lane0], [0, 2], 1)
    np.testing.assert_array_equal(label, expected)
    assert (label == 0).sum() > 0 and (label == 2).sum() > 0 and (label == 1).sum() > 0
    assert changes["s_av"][:, 2].numpy().tolist() == lane0.astype(float).tolist()
    # a synthetic left changer: the window that straddles its change says left, and it ends one lane left
    meta = rec.tracks_meta.set_index("id")
    truth = rec.truth
    for v in meta.index[meta["numLaneChanges"] > 0]:
        lanes = truth.loc[truth["id"] == v, "lane"].to_numpy()
        if lanes[0] == lanes[-1]:
            continue  # left the road before finishing its change
        sel = vid == v
        want = 0 if lanes[-1] > lanes[0] else 2
        assert (label[sel] == want).sum() >= 1, v
        assert set(label[sel]) <= {1, want}
        last = np.argmax(np.where(sel, frame, -1))
        assert lane0[last] + (1 if want == 0 else -1) * (label[last] != 1) == lane1[last]
    # vehicles that never change lanes are all "keep"
    keepers = meta.index[meta["numLaneChanges"] == 0]
    assert (label[np.isin(vid, keepers)] == 1).all()


def test_lane_change_rel_matches_neighbor_ids(changes, tracks):
    vid, frame = changes["vehicle_id"].numpy(), changes["frame"].numpy()
    pid = _at(tracks, vid, frame, "preceding_id")
    y_e = _at(tracks, vid, frame, "y")
    y_p = _at(tracks, pid, frame, "y")
    present = (pid > 0) & np.isfinite(y_p) & (np.abs(y_p - y_e) <= 200)
    np.testing.assert_array_equal(changes["mask"][:, 1].numpy(), present)
    np.testing.assert_allclose(changes["rel"][present, 1, 1].numpy(), (y_p - y_e)[present], atol=1e-3)
    x_e, x_p = _at(tracks, vid, frame, "x_lat"), _at(tracks, pid, frame, "x_lat")
    np.testing.assert_allclose(changes["rel"][present, 1, 0].numpy(), (x_p - x_e)[present], atol=1e-4)
    # left leaders are ahead and to the left, right followers behind and to the right
    m = changes["mask"]
    assert (changes["rel"][m[:, 0], 0, 1] > 0).all() and (changes["rel"][m[:, 0], 0, 0] > 0).all()
    assert (changes["rel"][m[:, 5], 5, 1] <= 0).all() and (changes["rel"][m[:, 5], 5, 0] < 0).all()
    # key gaps: the current leader's true y at t+10, t+20 minus ego y at t
    km = changes["key_gaps_mask"][:, 1].numpy()
    for j, step in enumerate(KEY_STEPS):
        y_f = _at(tracks, pid, frame + step, "y")
        np.testing.assert_allclose(changes["key_gaps"][km, 1, j].numpy(), (y_f - y_e)[km], atol=1e-3)
    assert km.sum() > 0


def test_sensing_range_hides_far_neighbors(tracks):
    near = lane_change_samples(tracks, sensing_range=30.0)
    assert (near["rel"][..., 1].abs() <= 30.0 + 1e-4).all()
    far = lane_change_samples(tracks)
    assert near["mask"].sum() < far["mask"].sum()
    assert leader_samples(tracks, sensing_range=30.0).batch_size[0] < leader_samples(tracks).batch_size[0]


def test_stride(tracks, changes):
    s5 = lane_change_samples(tracks, stride=5)
    assert (s5["frame"] % 5 == 0).all()
    sel = (changes["frame"] % 5 == 0).numpy()
    torch.testing.assert_close(s5["rel"], changes["rel"][torch.as_tensor(sel)])


# ------------------------------------------------------------------------------------- leader samples
def test_leader_samples_schema_and_future(leaders, tracks):
    n = leaders.batch_size[0]
    assert n > 0
    assert leaders["history"].shape == (n, 10, 2) and leaders["prior"].shape == (n, 20)
    assert leaders["future"].shape == (n, 20) and leaders["ahead"].shape == (n, 3)
    assert set(leaders["slot"].tolist()) == {0, 1, 2}
    vid, lid, frame = (leaders[k].numpy() for k in ("vehicle_id", "leader_id", "frame"))
    slot = leaders["slot"].numpy()
    col = np.select(
        [slot == 0, slot == 1],
        [_at(tracks, vid, frame, "left_preceding_id"), _at(tracks, vid, frame, "preceding_id")],
        _at(tracks, vid, frame, "right_preceding_id"),
    )
    along = np.select(
        [slot == 0, slot == 2],
        [_at(tracks, vid, frame, "left_alongside_id"), _at(tracks, vid, frame, "right_alongside_id")],
        0,
    )
    assert ((col == lid) | ((col == 0) & (along == lid))).all()
    # the alongside fallback was exercised and only for leaders whose front is ahead
    fallback = col != lid
    assert fallback.any()
    assert (_at(tracks, lid, frame, "y")[fallback] > _at(tracks, vid, frame, "y")[fallback]).all()
    for k in range(20):
        np.testing.assert_allclose(
            leaders["future"][:, k].numpy(), _at(tracks, lid, frame + k + 1, "y"), rtol=0, atol=1e-4
        )
    for k in range(10):
        np.testing.assert_allclose(
            leaders["history"][:, k, 0].numpy(), _at(tracks, lid, frame - 9 + k, "y"), rtol=0, atol=1e-4
        )
        np.testing.assert_allclose(
            leaders["history"][:, k, 1].numpy(), _at(tracks, lid, frame - 9 + k, "v"), rtol=0, atol=1e-5
        )
    np.testing.assert_allclose(leaders["ego"][:, 0].numpy(), _at(tracks, vid, frame, "y"), atol=1e-4)
    np.testing.assert_allclose(leaders["leader_length"].numpy(), _at(tracks, lid, frame, "length"), atol=1e-6)
    # the leader's own preceding vehicle
    aid = _at(tracks, lid, frame, "preceding_id")
    has = leaders["ahead"][:, 2].numpy() > 0
    assert has.any() and (~has).any()
    assert (aid[has] > 0).all()
    np.testing.assert_allclose(leaders["ahead"][has, 0].numpy(), _at(tracks, aid[has], frame[has], "y"), atol=1e-4)
    np.testing.assert_allclose(
        leaders["ahead_length"][has].numpy(), _at(tracks, aid[has], frame[has], "length"), atol=1e-6
    )
    assert (leaders["ahead"][~has] == 0).all()
    drivers = [DRIVER_TYPES[i] for i in leaders["leader_driver"].tolist()]
    assert drivers == list(_at(tracks, lid, frame, "driver_type"))


def test_prior_equals_direct_idm_rollout(leaders):
    idm = IDMParams()
    a = leaders["ahead"]
    direct = idm_rollout(
        leaders["history"][:, -1, 0],
        leaders["history"][:, -1, 1],
        a[:, 0],
        a[:, 1],
        a[:, 2] > 0,
        steps=20,
        dt=0.1,
        params=dataclasses.replace(idm, length=leaders["ahead_length"]),
    )
    torch.testing.assert_close(leaders["prior"], direct, rtol=1e-6, atol=1e-4)
    # one sample on its own gives the same prior
    i = int(torch.nonzero(a[:, 2] > 0)[0])
    one = idm_rollout(
        float(leaders["history"][i, -1, 0]),
        float(leaders["history"][i, -1, 1]),
        float(a[i, 0]),
        float(a[i, 1]),
        True,
        steps=20,
        dt=0.1,
        params=dataclasses.replace(idm, length=float(leaders["ahead_length"][i])),
    )
    torch.testing.assert_close(leaders["prior"][i], one, rtol=1e-6, atol=1e-4)
    # the prior is a forward motion that starts from the leader's position at t
    assert (leaders["prior"][:, 0] >= leaders["history"][:, -1, 0]).all()
    assert (leaders["prior"].diff(dim=1) >= 0).all()


def test_leader_coverage_and_history_parameters(tracks):
    td = leader_samples(tracks, history=5, horizon=8)
    assert td["history"].shape[1:] == (5, 2) and td["prior"].shape[1:] == (8,)
    lid, frame = td["leader_id"].numpy(), td["frame"].numpy()
    assert np.isfinite(_at(tracks, lid, frame - 4, "y")).all() and np.isfinite(_at(tracks, lid, frame + 8, "y")).all()
    # longer windows give fewer samples
    assert td.batch_size[0] > leader_samples(tracks, history=20, horizon=30).batch_size[0]


# ----------------------------------------------------------------------------------------- splitting
def test_split_by_vehicle_disjoint_and_deterministic(changes, leaders):
    for td, key in ((changes, "vehicle_id"), (leaders, "leader_id")):
        a = split_by_vehicle(td, seed=3)
        b = split_by_vehicle(td, seed=3)
        assert sum(p.batch_size[0] for p in a.values()) == td.batch_size[0]
        sets = {k: set(zip(p["recording_id"].tolist(), p[key].tolist())) for k, p in a.items()}
        assert not (sets["train"] & sets["val"]) and not (sets["train"] & sets["test"])
        assert not (sets["val"] & sets["test"])
        assert all(len(s) for s in sets.values())
        for k in a:
            assert torch.equal(a[k]["frame"], b[k]["frame"]) and torch.equal(a[k][key], b[k][key])
        c = split_by_vehicle(td, seed=4)
        assert any(c[k].batch_size != a[k].batch_size or not torch.equal(c[k][key], a[k][key]) for k in a)
    total = len(set(changes["vehicle_id"].tolist()))
    n_train = len(set(split_by_vehicle(changes, seed=0)["train"]["vehicle_id"].tolist()))
    assert n_train == round(0.8 * total)


# ------------------------------------------------------------------------------------- whole data set
def test_extract_dataset_cache_force_and_load(tmp_path):
    recs = [synth_recording(1, duration=12.0), synth_recording(2, duration=12.0, seed=1, driver_type=False)]
    meta = extract_dataset(recs, tmp_path, seed=0, progress=False)
    assert meta["cached"] is False
    on_disk = json.loads((tmp_path / "meta.json").read_text())
    assert on_disk["input_hash"] == meta["input_hash"] and on_disk["driver_types"] == list(DRIVER_TYPES)
    counts = on_disk["counts"]
    assert counts["vehicles"] == sum(r.tracks_meta["id"].nunique() for r in recs)
    assert counts["lane_changers"] > 0
    keys = {}
    for kind in ("leaders", "lane_changes"):
        for split in ("train", "val", "test"):
            td = load_dataset(tmp_path, kind, split)
            assert td.batch_size[0] == counts[kind][split]["samples"]
            if kind == "lane_changes":
                per = torch.bincount(td["label"], minlength=3).tolist()
                assert per == [counts[kind][split]["per_class"][k] for k in ("left", "keep", "right")]
            key = "leader_id" if kind == "leaders" else "vehicle_id"
            keys[kind, split] = set(zip(td["recording_id"].tolist(), td[key].tolist()))
    assert (load_dataset(tmp_path, "leaders", "train")["leader_driver"] == 0).any()  # recording 2: "unknown"
    # the same vehicle -> split assignment for both kinds
    for s in ("train", "val", "test"):
        for o in ("train", "val", "test"):
            if s != o:
                assert not (keys["leaders", s] & keys["lane_changes", o])
                assert not (keys["leaders", s] & keys["leaders", o])
    # cache: same inputs and parameters -> nothing rewritten
    stamp = (tmp_path / "meta.json").stat().st_mtime_ns
    data_stamp = next((tmp_path / "leaders" / "train").iterdir()).stat().st_mtime_ns
    time.sleep(0.01)
    again = extract_dataset(recs, tmp_path, seed=0, progress=False)
    assert again["cached"] is True and again["counts"] == counts
    assert (tmp_path / "meta.json").stat().st_mtime_ns == stamp
    assert next((tmp_path / "leaders" / "train").iterdir()).stat().st_mtime_ns == data_stamp
    # force recomputes, with identical counts (deterministic)
    forced = extract_dataset(recs, tmp_path, seed=0, progress=False, force=True)
    assert forced["cached"] is False and forced["counts"] == counts
    assert (tmp_path / "meta.json").stat().st_mtime_ns != stamp
    # different parameters or inputs -> recompute
    assert extract_dataset(recs, tmp_path, seed=1, progress=False)["cached"] is False
    recs[0].tracks.loc[0, "x"] += 0.01
    assert extract_dataset(recs, tmp_path, seed=1, progress=False)["cached"] is False
    with pytest.raises(ValueError):
        load_dataset(tmp_path, "nope", "train")
    with pytest.raises(FileNotFoundError):
        load_dataset(tmp_path / "missing", "leaders", "train")


# ------------------------------------------------------------------------------------------ bad input
def test_no_vehicles():
    r = synth_recording(1, duration=4.0)
    r.tracks = r.tracks.iloc[:0]
    with pytest.raises(ValueError, match="no vehicles"):
        longitudinal_tracks(r)
    with pytest.raises(ValueError, match="no rows"):
        leader_samples(longitudinal_tracks(synth_recording(1, duration=4.0)).iloc[:0])


def test_nan_column_is_named(rec):
    r = HighDRecording(1, rec.tracks.copy(), rec.tracks_meta, rec.recording_meta)
    vid = int(r.tracks.loc[100, "id"])
    r.tracks.loc[100, "xVelocity"] = np.nan
    with pytest.raises(ValueError, match=rf"column 'v' of vehicle {vid}\b"):
        longitudinal_tracks(r)
    t = longitudinal_tracks(rec).copy()
    t.loc[7, "x_lat"] = np.inf
    with pytest.raises(ValueError, match=rf"column 'x_lat' of vehicle {int(t.loc[7, 'vehicle_id'])}\b"):
        lane_change_samples(t)
    t = longitudinal_tracks(rec).copy()
    t.loc[7, "y"] = np.nan
    with pytest.raises(ValueError, match="column 'y'"):
        leader_samples(t)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda t: leader_samples(t, history=0), "history"),
        (lambda t: leader_samples(t, horizon=-1), "horizon"),
        (lambda t: leader_samples(t, stride=0), "stride"),
        (lambda t: leader_samples(t, sensing_range=0.0), "sensing_range"),
        (lambda t: leader_samples(t, idm=IDMParams(T=-1.0)), "idm.T"),
        (lambda t: lane_change_samples(t, window=0), "window"),
        (lambda t: lane_change_samples(t, sensing_range=float("nan")), "sensing_range"),
        (lambda t: lane_change_samples(t.drop(columns=["lane"])), "lane"),
        (lambda t: lane_change_samples(t.drop(index=[5])), "not consecutive"),
        (lambda t: lane_change_samples(t.assign(driver_type="reckless")), "reckless"),
        (lambda t: split_by_vehicle(lane_change_samples(t), fractions=(0.5, 0.2, 0.2)), "fractions"),
        (lambda t: split_by_vehicle(lane_change_samples(t), fractions=(1.2, -0.1, -0.1)), "fractions"),
    ],
)
def test_bad_parameters(call, match):
    t = longitudinal_tracks(synth_recording(1, duration=4.0))
    with pytest.raises(ValueError, match=match):
        call(t)


def test_bad_extract_arguments(tmp_path):
    r = synth_recording(1, duration=4.0)
    with pytest.raises(ValueError, match="no recordings"):
        extract_dataset([], tmp_path)
    with pytest.raises(ValueError, match="duplicate"):
        extract_dataset([r, r], tmp_path, progress=False)
    with pytest.raises(ValueError, match="stride"):
        extract_dataset([r], tmp_path, stride=0, progress=False)
    with pytest.raises(ValueError, match="hz"):
        longitudinal_tracks(r, hz=0.0)
    assert not (tmp_path / "meta.json").exists()


# ------------------------------------------------------------------------------------------------ speed
def test_extraction_speed(tmp_path):
    """~10 minutes of synthetic traffic (both directions, 6 lanes): extraction throughput is printed."""
    r = synth_recording(1, duration=600.0, headway=8.0, seed=2)
    t0 = time.perf_counter()
    meta = extract_dataset([r], tmp_path, progress=False)
    dt = time.perf_counter() - t0
    n = sum(c["samples"] for kind in ("leaders", "lane_changes") for c in meta["counts"][kind].values())
    print(
        f"\n{meta['counts']['vehicles']} vehicles, {len(r.tracks)} 25 Hz rows -> {n} samples in {dt:.2f} s "
        f"({n / dt:,.0f} samples/s)"
    )
    assert dt < 60.0


def test_tracks10_lane_offset_is_from_the_lane_centre(tracks):
    """lane_offset = x_lat minus the centre of the row's lane (uniform lanes of width W here), within +-W/2
    up to the 25 Hz lane lag at a crossing."""
    centre = (tracks["lane"].to_numpy() + 0.5) * W
    np.testing.assert_allclose(tracks["lane_offset"], tracks["x_lat"] - centre, atol=1e-9)
    assert (tracks["lane_offset"].abs() <= W / 2 + 0.2).all()


def test_window_labels_within_and_end():
    """'within' takes the first lane change in the window, 'end' the net change: they differ on a window with
    a change and a change back (left then right: within says left, end says keep)."""
    now = np.array([1, 1, 1, 1])
    after = np.array(
        [
            [1, 2, 2, 1],  # left and back
            [1, 1, 0, 0],  # right
            [1, 1, 1, 1],  # keep
            [2, 2, 2, 2],
        ]
    )  # left at the first step
    np.testing.assert_array_equal(window_labels(now, after, "within"), [0, 2, 1, 0])
    np.testing.assert_array_equal(window_labels(now, after, "end"), [1, 2, 1, 0])
    with pytest.raises(ValueError, match="label must be one of"):
        window_labels(now, after, "middle")
