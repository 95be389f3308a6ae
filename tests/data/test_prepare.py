"""``python -m kddrl_trl.prepare`` end to end, as a user types it (small recordings)."""

from __future__ import annotations

import json
import subprocess
import sys

from omegaconf import OmegaConf

from kddrl_trl.envs import make_config


def run(args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "kddrl_trl.prepare", "progress=false", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_prepare_synthetic_then_highd_source(tmp_path):
    done = run(["record.duration_s=60", "record.num_roads=2"], tmp_path)
    assert done.returncode == 0, done.stderr
    out = tmp_path / "data" / "datasets" / "synthetic_baseline_seed0"
    meta = json.loads((out / "meta.json").read_text())
    assert meta["counts"]["vehicles"] > 50 and meta["counts"]["leaders"]["train"]["samples"] > 0
    for kind in ("leaders", "lane_changes"):
        for split in ("train", "val", "test"):
            assert (out / kind / split).is_dir()
    cal = OmegaConf.load(out / "calibration.yaml")
    cfg = make_config("baseline", OmegaConf.to_container(cal["env"]))
    assert {d.name for d in cfg.drivers} <= {"timid", "normal", "aggressive"}
    assert "fitted" in done.stdout and "true" in done.stdout  # our own data: fitted beside generating values

    again = run(["record.duration_s=60", "record.num_roads=2", "calibrate=false"], tmp_path)
    assert again.returncode == 0 and "dataset (cached)" in again.stdout

    # the same files read as a HighD folder: one option switches the source
    rec_dir = tmp_path / "data" / "recordings" / "baseline_seed0"
    highd = run(["source=highd", f"path={rec_dir}", "calibrate=false"], tmp_path)
    assert highd.returncode == 0, highd.stderr
    meta_h = json.loads((tmp_path / "data" / "datasets" / "highd_baseline_seed0" / "meta.json").read_text())
    assert meta_h["counts"] == meta["counts"]


def test_prepare_bad_source_and_path(tmp_path):
    assert "needs path=DIR" in run(["source=highd"], tmp_path).stderr
    assert "no HighD-format recording" in run(["source=highd", f"path={tmp_path}"], tmp_path).stderr
    assert "source must be" in run(["source=ngsim"], tmp_path).stderr
    assert not list(tmp_path.glob("runs/*"))  # the refused options left no run folder


def test_data_too_short_to_calibrate_gives_datasets_and_a_warning_unless_strict(tmp_path):
    done = run(["record.duration_s=4", "record.num_roads=1"], tmp_path)  # no 5 s car-following segment
    assert done.returncode == 0, done.stderr[-3000:]
    out = tmp_path / "data" / "datasets" / "synthetic_baseline_seed0"
    said = done.stdout + done.stderr
    assert "no car-following segment of at least 5.0 s" in said and "still good for pretraining" in said
    assert "calibrate=strict" in said and "not calibrated" in said
    assert (out / "meta.json").is_file() and (out / "leaders" / "train").is_dir()
    assert not (out / "calibration.yaml").exists()

    strict = run(["record.duration_s=4", "record.num_roads=1", "calibrate=strict"], tmp_path)
    assert strict.returncode != 0 and "no car-following segment of at least 5.0 s" in strict.stderr
    assert "dataset (cached)" in strict.stdout  # the datasets came first, as before
    assert "calibrate must be" in run(["calibrate=maybe"], tmp_path).stderr  # checked before recording
