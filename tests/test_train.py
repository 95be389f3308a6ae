"""The Hydra entry point: config composition, and the command a user types, as a subprocess."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from hydra import compose, initialize_config_module


def test_scenario_is_appended_not_required():
    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        base = compose(config_name="config")
        braking = compose(config_name="config", overrides=["+scenario=braking"])
        congested = compose(config_name="config", overrides=["+scenario=congested", "env.flow_vph=2658"])
    assert base.env.scenario == "baseline" and not base.env.braking.enabled and base.env.flow_scale == 1.0
    assert braking.env.scenario == "braking" and braking.env.braking.enabled
    assert congested.env.flow_scale == 1.5 and congested.env.flow_vph == 2658


def test_train_runs_as_typed_from_any_directory(tmp_path):
    cmd = [sys.executable, "-m", "kddrl_trl.train", "+scenario=braking", "episodes=4", "env.num_roads=2",
           "progress=false"]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    runs = list((tmp_path / "runs").glob("braking__idm_mobil__0__*"))
    assert len(runs) == 1
    summary = json.loads((runs[0] / "summary.json").read_text())
    assert summary["episodes"] == 4 and summary["scenario"] == "braking"
    assert (runs[0] / "episodes.csv").read_text().count("\n") == 5
    assert "mean speed (km/h)" in done.stdout


@pytest.mark.parametrize("override", ["env.flow_vph=-5", "env.flow_vph=lots", "env.flow_vhp=5"])
def test_train_rejects_a_bad_override(tmp_path, override):
    cmd = [sys.executable, "-m", "kddrl_trl.train", override, "episodes=1", "progress=false"]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and ("flow_vph" in done.stderr or "flow_vhp" in done.stderr), done.stderr


def test_summary_statistics_by_hand():
    from kddrl_trl.eval.metrics import summarize

    eps = [
        {"mean_speed_kmh": 36.0, "mean_speed": 10.0, "mean_sq_speed": 100.0, "mean_accel": 0.0, "mean_sq_accel": 1.0,
         "mean_abs_accel": 1.0, "lane_changes": 1, "frames": 10, "return_lc": 1.0, "return_cf": 2.0,
         "collision": False, "outcome": "left_section"},
        {"mean_speed_kmh": 72.0, "mean_speed": 20.0, "mean_sq_speed": 400.0, "mean_accel": 0.0, "mean_sq_accel": 1.0,
         "mean_abs_accel": 1.0, "lane_changes": 0, "frames": 30, "return_lc": 1.0, "return_cf": 2.0,
         "collision": True, "outcome": "collision"},
    ]
    s = summarize(eps)
    assert s["mean_speed_kmh"] == 54.0 and s["mean_speed_kmh_sd"] == 18.0
    # frames: 10 at 10 m/s and 30 at 20 m/s -> mean 17.5, sd sqrt(325 - 306.25) = 4.33 m/s
    assert abs(s["frame_speed_kmh_sd"] - 3.6 * 18.75 ** 0.5) < 1e-9
    assert s["frame_accel_sd"] == 1.0 and s["collision_rate"] == 0.5 and s["lane_changes_total"] == 1
    assert s["outcomes"] == {"left_section": 1, "collision": 1}
