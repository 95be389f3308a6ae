"""IDM / MOBIL calibration (kddrl_trl.data.calibrate) on synthetic data generated with the physics models.

Synthetic car following: 3 driver classes (``default_drivers()``) x 10 followers, each behind its own leader
for 36 s at 10 Hz; per-vehicle IDM parameters are drawn around the class values with 5 % relative sd (as
the environment does), and the follower is integrated with the same IDM + semi-implicit Euler the fit uses.
Observed positions carry 2 cm of noise. The leader profiles excite every parameter: steady following
(T), hard braking from ~20 to ~3-5 m/s and standing-off at low speed (s0, and sqrt(a b) through the
approach term), then a long acceleration to 45 m/s that the follower cannot match, so it leaves the leader
and accelerates freely toward its own v0 (a, and v0 partially).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import torch
from omegaconf import OmegaConf

from kddrl_trl import keys as K
from kddrl_trl.data.calibrate import (
    balanced_accuracy,
    calibrate,
    car_following_segments,
    class_parameters,
    decision_points,
    fit_idm,
    fit_mobil,
    mobil_decision,
    write_calibration,
)
from kddrl_trl.highway_config import default_drivers, make_config
from kddrl_trl.physics.idm import IDMParams, idm_acceleration
from kddrl_trl.physics.mobil import MOBILParams, mobil_utilities

torch.set_num_threads(1)

HZ, DT = 10.0, 0.1
ID_COLS = (
    "preceding_id",
    "following_id",
    "left_preceding_id",
    "left_alongside_id",
    "left_following_id",
    "right_preceding_id",
    "right_alongside_id",
    "right_following_id",
)


def track_rows(rec, vid, frames, y, v, lane, length=4.5, driver_type="", **ids) -> pd.DataFrame:
    """Rows of a tracks10 table (TRACKS10.md schema) for one vehicle."""
    n = len(frames)
    y, v = np.broadcast_to(np.asarray(y, float), (n,)), np.broadcast_to(np.asarray(v, float), (n,))
    a = np.gradient(v, DT) if n > 1 else np.zeros(n)
    df = pd.DataFrame(
        {
            "recording_id": np.int64(rec),
            "vehicle_id": np.int64(vid),
            "frame": np.asarray(frames, np.int64),
            "t": np.asarray(frames) / HZ,
            "y": y,
            "v": v,
            "a": a,
            "x_lat": 1.6,
            "vx_lat": 0.0,
            "lane": np.broadcast_to(np.asarray(lane, np.int64), (n,)),
            "length": float(length),
            "driver_type": driver_type,
        }
    )
    for col in ID_COLS:
        df[col] = np.broadcast_to(np.asarray(ids.get(col, 0), np.int64), (n,))
    return df


def leader_speed(rng, n: int) -> np.ndarray:
    """Cruise, brake hard to a crawl, hold, accelerate briskly to 26-29 m/s and cruise there."""
    v1, v_low, v_high = rng.uniform(18, 24), rng.uniform(3, 5), rng.uniform(26, 29)
    t_cruise, decel, hold, acc = rng.uniform(4, 6), rng.uniform(3.5, 5.0), rng.uniform(3, 5), rng.uniform(3.0, 4.0)
    v, out = v1, []
    for k in range(n):
        t = k * DT
        t_brake_end = t_cruise + (v1 - v_low) / decel
        if t < t_cruise:
            a = 0.0
        elif t < t_brake_end:
            a = -decel
        elif t < t_brake_end + hold:
            a = 0.0
        else:
            a = acc
        out.append(v)
        v = float(np.clip(v + a * DT, v_low, v_high)) if t >= t_cruise else v
    return np.asarray(out)


def synthetic_following(per_class: int = 10, seconds: float = 36.0, seed: int = 0, noise: float = 0.02):
    """tracks10 table of leader/follower pairs, and the true per-vehicle parameters."""
    rng = np.random.default_rng(seed)
    n = int(seconds * HZ) + 1
    frames = np.arange(n)
    rows, truth = [], []
    vid = 1
    for cls in default_drivers():
        for _ in range(per_class):
            p = {
                k: getattr(cls, k) * float(np.clip(rng.normal(1.0, 0.05), 0.9, 1.1))
                for k in ("v0", "T", "s0", "a", "b")
            }
            lv = leader_speed(rng, n)
            ly = 200.0 + np.concatenate([[0.0], np.cumsum(lv[1:] * DT)])
            L = 4.5
            params = IDMParams(v0=p["v0"], T=p["T"], s0=p["s0"], a_max=p["a"], b=p["b"])
            v = lv[0]
            s_eq = (p["s0"] + v * p["T"]) / math.sqrt(1 - (v / p["v0"]) ** 4)
            y = ly[0] - L - s_eq
            ys, vs = [y], [v]
            for k in range(n - 1):
                acc = float(idm_acceleration(torch.tensor(v), lv[k], ly[k] - L - y, params))
                v = max(v + acc * DT, 0.0)
                y = y + v * DT
                ys.append(y)
                vs.append(v)
            ys = np.asarray(ys) + rng.normal(0, noise, n)
            lead_id, fol_id = vid, vid + 1
            rows.append(track_rows(1, lead_id, frames, ly, lv, 1, L, cls.name, following_id=fol_id))
            rows.append(track_rows(1, fol_id, frames, ys, np.asarray(vs), 1, 4.5, cls.name, preceding_id=lead_id))
            truth.append({"vehicle_id": fol_id, "driver_type": cls.name, **p})
            vid += 2
    return pd.concat(rows, ignore_index=True), pd.DataFrame(truth)


@pytest.fixture(scope="module")
def synthetic():
    return synthetic_following()


@pytest.fixture(scope="module")
def segments(synthetic):
    return car_following_segments(synthetic[0], min_duration_s=5.0)


# ------------------------------------------------------------------------------------------ segments
def test_segments_split_at_lane_and_leader_changes():
    f = np.arange(200)
    # follower 10: lane 1 for frames 0-79, lane 2 from 80; leader 1 until frame 119, then leader 2
    pid = np.where(f < 120, 1, 2)
    lane = np.where(f < 80, 1, 2)
    fol = track_rows(3, 10, f, 100 + 20 * f * DT, 20.0, lane, preceding_id=pid)
    l1 = track_rows(3, 1, f, 130 + 20 * f * DT, 20.0, lane, length=12.0)
    l2 = track_rows(3, 2, f[100:], 140 + 20 * f[100:] * DT, 20.0, 2, length=4.0)
    # follower 11 behind leader 1, but leader 1 is missing for frames 50-54 -> split, and a 3 s piece dropped
    fol2 = track_rows(3, 11, f[:90], 60 + 20 * f[:90] * DT, 20.0, 1, preceding_id=3)
    l3 = track_rows(3, 3, np.r_[f[:50], f[55:90]], 0.0, 20.0, 1)
    l3["y"] = 90 + 20 * l3["frame"] * DT
    tracks = pd.concat([fol, l1, l2, fol2, l3], ignore_index=True)
    seg = car_following_segments(tracks, min_duration_s=3.5)
    got = sorted(
        zip(
            seg["vehicle_id"].tolist(),
            seg["frame0"].tolist(),
            seg["num_frames"].tolist(),
            seg["leader_id"].tolist(),
            seg["lane"].tolist(),
        )
    )
    # 10: [0,80) lane 1 leader 1; [80,120) lane 2 leader 1; [120,200) lane 2 leader 2
    # 11: [0,50) and [55,90) behind 3 (35 frames = 3.4 s < 3.5 s -> dropped)
    assert got == [(10, 0, 80, 1, 1), (10, 80, 40, 1, 2), (10, 120, 80, 2, 2), (11, 0, 50, 3, 1)]
    i = seg["frame0"].tolist().index(0)
    gap = seg["leader_y"][i] - seg["leader_length"][i] - seg["y"][i]
    assert torch.allclose(gap[seg["valid"][i]], torch.full((80,), 30.0 - 12.0, dtype=gap.dtype))
    assert not torch.isnan(seg["leader_y"]).any()


# ----------------------------------------------------------------------------------------- IDM fit
@pytest.mark.slow
def test_class_fit_recovers_identifiable_parameters(synthetic, segments):
    """Class centres: median of per-vehicle fits within 5 % (T, s0, a); pooled class fit within 15 % (T, s0).

    Per vehicle, every parameter is excited (see module docstring) and the fit reaches the 2 cm noise floor,
    so per-vehicle estimates are near exact and the median of 10 of them sits within the sampling error of
    the median of 10 draws with 5 % sd (~1.9 %) of the class value: 5 % is ~2.5 standard errors. The pooled
    class fit (one parameter set for 10 different drivers) is a compromise, not the class centre: with 5 %
    heterogeneity the gaps differ by metres between drivers and the fit damps the dynamics, biasing a and b
    low (measured up to -40 % / -70 %); T and s0, which set the steady gaps, stay within ~10 % (15 % asserted),
    and the pooled fit must still beat Table A.1 by a wide margin for the non-Table-A.1 classes.
    """
    from kddrl_trl.data.calibrate import class_parameters

    classes = {d.name: d for d in default_drivers()}
    vehicles = fit_idm(segments, steps=40)
    med = class_parameters(vehicles)
    pooled = fit_idm(segments, groups="driver_type", steps=40)
    assert len(pooled) == 3 and np.isfinite(pooled[["v0", "T", "s0", "a", "b", "rmse"]].to_numpy(float)).all()
    for _, row in med.iterrows():
        cls = classes[row["group"]]
        err = {k: round(row[k] / getattr(cls, k) - 1, 3) for k in ("v0", "T", "s0", "a", "b")}
        print("median of vehicles", row["group"], err, "spread", round(row["spread"], 3))
        for k in ("T", "s0", "a"):
            assert abs(err[k]) < 0.05, (row["group"], k, row[k], getattr(cls, k))
        assert abs(err["v0"]) < 0.10 and abs(err["b"]) < 0.15
        assert row["n_vehicles"] == 10 and 0.01 < row["spread"] < 0.12
    for _, row in pooled.iterrows():
        cls = classes[row["group"]]
        err = {k: round(row[k] / getattr(cls, k) - 1, 3) for k in ("v0", "T", "s0", "a", "b")}
        print("pooled", row["group"], err, "rmse", round(row["rmse"], 3), "table A.1", round(row["rmse_init"], 3))
        for k in ("T", "s0"):
            assert abs(err[k]) < 0.15, (row["group"], k, row[k], getattr(cls, k))
        assert row["n_segments"] == 10 and row["seconds"] == pytest.approx(360.0)
        assert row["rmse"] <= row["rmse_init"] + 1e-9
        if row["group"] != "normal":
            assert row["rmse"] < 0.5 * row["rmse_init"]


@pytest.mark.slow
def test_vehicle_fit_beats_table_a1(synthetic, segments):
    _, truth = synthetic
    res = fit_idm(segments, steps=40)
    assert len(res) == 30
    assert (res["rmse"] <= res["rmse_init"] + 1e-9).all()
    assert res["rmse"].median() < 0.1 * res["rmse_init"].median()
    assert res["rmse"].max() < 0.05  # 2 cm position noise
    # per-vehicle parameters against each vehicle's own draw
    true = truth.set_index("vehicle_id")
    vid = [g[1] for g in res["group"]]
    for k in ("v0", "T", "s0", "a", "b"):
        rel = res[k].to_numpy() / true.loc[vid, k].to_numpy() - 1
        print(f"per-vehicle {k}: median |err| {np.median(np.abs(rel)):.4f} max {np.abs(rel).max():.4f}")
        assert np.abs(rel).max() < (0.05 if k in ("T", "s0", "a") else 0.15), k
    print(
        "rmse median",
        res["rmse"].median(),
        "fit s",
        res.attrs["fit_seconds"],
        "segments/s",
        res.attrs["segments_per_second"],
        "iterations",
        res.attrs["iterations"],
    )


def test_fit_is_finite_on_degenerate_data():
    """A leader that stops dead in front of a fast follower: clamped gaps, no NaN anywhere."""
    f = np.arange(80)
    lead = track_rows(1, 1, f, 50.0, 0.0, 0)
    fol = track_rows(1, 2, f, 20 + 30 * f * DT, 30.0, 0, preceding_id=1)
    seg = car_following_segments(pd.concat([lead, fol], ignore_index=True))
    res = fit_idm(seg, steps=20)
    assert np.isfinite(res[["v0", "T", "s0", "a", "b", "rmse", "rmse_init"]].to_numpy(float)).all()


# --------------------------------------------------------------------------------------------- MOBIL
def random_decisions(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.rand(*s, generator=g, dtype=torch.float64)  # noqa: E731
    ego_y = torch.zeros(n, dtype=torch.float64)
    ego_v = 20 + 15 * r(n)
    dy = torch.stack(
        [30 + 80 * r(n), 10 + 60 * r(n), 30 + 80 * r(n), -(15 + 60 * r(n)), -(15 + 60 * r(n)), -(15 + 60 * r(n))], -1
    )
    v = ego_v[:, None] + torch.cat([4 * (r(n, 3) - 0.2) * 3, 8 * (r(n, 3) - 0.5)], -1)
    kin = torch.stack([dy, v, torch.zeros_like(v)], -1)
    mask = r(n, 6) < 0.85
    lane = torch.randint(0, 3, (n,), generator=g)
    return ego_y, ego_v.clamp(min=0), kin, mask, lane


def test_fit_mobil_recovers_rule_parameters():
    from tensordict import TensorDict

    true = MOBILParams(politeness=0.4, threshold=0.2, b_safe=3.0)
    ego_y, ego_v, kin, mask, lane = random_decisions(4000)
    U, safe = mobil_utilities(ego_y, ego_v, kin, mask, lane, 3, IDMParams(), true)
    label = mobil_decision(U, safe, true.threshold)
    assert (label == K.LEFT).sum() > 100 and (label == K.RIGHT).sum() > 100
    td = TensorDict(
        {
            "ego_y": ego_y,
            "ego_v": ego_v,
            K.NEIGHBORS_KIN: kin,
            K.NEIGHBORS_MASK: mask,
            "lane": lane,
            "num_lanes": torch.full_like(lane, 3),
            "label": label,
        },
        batch_size=[4000],
    )
    res = fit_mobil(td)
    print(
        "MOBIL",
        {k: res[k] for k in ("politeness", "threshold", "b_safe", "balanced_accuracy", "n_ties")},
        "table A.1",
        res["table_a1"]["balanced_accuracy"],
    )
    assert res["balanced_accuracy"] == pytest.approx(1.0)  # the true point is on the grid
    assert abs(res["politeness"] - true.politeness) <= 0.1
    assert abs(res["threshold"] - true.threshold) <= 0.1
    assert res["table_a1"]["balanced_accuracy"] < res["balanced_accuracy"]
    ba, recalls = balanced_accuracy(label, label)
    assert ba == 1.0 and recalls == [1.0, 1.0, 1.0]


def test_decision_points_labels_and_slots():
    f = np.arange(60)
    # vehicle 5 drives in lane 0, crosses to lane 1 at frame 30; vehicle 6 is its leader, 7 its left leader
    ego = track_rows(
        2,
        5,
        f,
        10 + 25 * f * DT,
        25.0,
        np.where(f < 30, 0, 1),
        preceding_id=6,
        left_preceding_id=np.where(f < 30, 7, 0),
    )
    lead = track_rows(2, 6, f, 60 + 20 * f * DT, 20.0, 0, length=10.0, following_id=5)
    left = track_rows(2, 7, f[:40], 80 + 30 * f[:40] * DT, 30.0, 1)
    other = track_rows(2, 8, f, 0.0 + 25 * f * DT, 25.0, 2)  # lane 2 exists: 3 lanes
    dec = decision_points(pd.concat([ego, lead, left, other], ignore_index=True), horizon_s=1.0, cooldown_s=1.0)
    is5 = dec["vehicle_id"] == 5
    fr, lab = dec["frame"][is5], dec["label"][is5]
    # frames 20..29 see the crossing at 30 within 1 s -> left; 30..39 dropped (cooldown); 50..59 unobserved
    assert fr.tolist() == list(range(0, 30)) + list(range(40, 50))
    assert (lab[(fr >= 20) & (fr < 30)] == K.LEFT).all() and (lab[fr < 20] == K.KEEP).all()
    assert (lab[fr >= 40] == K.KEEP).all()
    row = dec[torch.nonzero(is5 & (dec["frame"] == 10)).item()]
    assert row[K.NEIGHBORS_MASK].tolist() == [True, True, False, False, False, False]
    assert row[K.NEIGHBORS_KIN][K.SLOT["b"]].tolist()[:2] == pytest.approx([80.0, 20.0])
    assert row[K.NEIGHBORS_KIN][K.SLOT["a"]].tolist()[:2] == pytest.approx([110.0, 30.0])
    assert row["neighbors", "length"][K.SLOT["b"]].item() == 10.0
    assert int(row["num_lanes"]) == 3 and int(row["lane"]) == 0


# ------------------------------------------------------------------------------------------ end to end
def test_calibrate_and_write_loads_with_make_config(synthetic, tmp_path):
    tracks, _ = synthetic
    result = calibrate(
        tracks,
        per_vehicle=True,
        progress=False,
        steps=30,
        mobil_grid={"politeness": (0.0, 0.5), "threshold": (0.1, 0.3), "b_safe": (4.0,)},
        source="synthetic IDM test data",
    )
    path = tmp_path / "sub" / "calibration.yaml"
    write_calibration(result, path)
    text = path.read_text()
    assert text.startswith("# IDM / MOBIL calibration") and "synthetic IDM test data" in text
    conf = OmegaConf.load(path)
    cfg = make_config("baseline", conf["env"])
    names = {d.name: d for d in cfg.drivers}
    assert set(names) == {"timid", "normal", "aggressive"}
    assert sum(d.share for d in cfg.drivers) == pytest.approx(1.0, abs=1e-5)
    assert names["timid"].T > names["normal"].T > names["aggressive"].T
    timid_default = next(d for d in default_drivers() if d.name == "timid")
    assert names["timid"].lc_speed_gain == timid_default.lc_speed_gain  # untouched defaults of the class
    assert set(conf["mobil"]) >= {"politeness", "threshold", "b_safe"}
    assert set(conf["idm"]) >= {"v0", "T", "s0", "a", "b"}
    assert not list(path.parent.glob(".calibration-*"))  # no temp file left behind


@pytest.mark.slow
def test_sumo_recordings_recover_desired_speed_and_headway_per_class(tmp_path):
    """On our own SUMO recordings the generating parameters are known. In steady highway following only
    v0 and T are identifiable (s0, a and b barely change the spacing; see the closing note of the data
    issue). Tolerances: v0 5 %, T 8 % of the true class medians. On the default hour the errors are below
    1 % (v0) and 2 % (T); on this 30-minute sample the aggressive drivers' T comes out ~6 % high, because
    their segments are short and often start right after a cut-in, far from the IDM equilibrium."""
    import numpy as np

    from kddrl_trl.data.sumo_to_highd import record_traffic
    from kddrl_trl.data.tracks import longitudinal_tracks
    from kddrl_trl.envs import make_config

    recorded = record_traffic(make_config("baseline"), 900.0, num_roads=2, seed=1, progress=False)
    tracks = pd.concat([longitudinal_tracks(r.recording) for r in recorded], ignore_index=True)
    truth = pd.concat([r.driver_params for r in recorded]).groupby("driverType")[["v0", "T"]].median()
    seg = car_following_segments(tracks)
    fits = class_parameters(fit_idm(seg, groups=None, progress=False)).set_index("group")
    for cls in truth.index:
        for p, rtol in (("v0", 0.05), ("T", 0.08)):
            assert np.isclose(fits.loc[cls, p], truth.loc[cls, p], rtol=rtol), (
                cls,
                p,
                fits.loc[cls, p],
                truth.loc[cls, p],
            )
