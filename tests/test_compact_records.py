"""The committed runs' training records stay compact, compacting keeps what the report reads, and a sweep's runs are
collected as a study keeps them (``python -m kddrl_trl.devtools.records collect``)."""

import lzma
from pathlib import Path

import pandas as pd
import pytest
from testkit import study_records

from kddrl_trl.devtools import records
from kddrl_trl.devtools.records import KEPT_TRAINING, compact, kept_columns

ROOT = Path(__file__).resolve().parents[1]


def test_compacting_keeps_the_kept_columns_text_for_text(tmp_path):
    frame = pd.DataFrame(
        {
            "index": [0, 1],
            "start": [0, 5],
            "return_lc": [62.690679132938385, -1.5],
            "return_cf": [60.40006339550018, 2.0],
            "mean_speed_kmh": [121.48628289751012, 90.0],
            "collision": [False, True],
            "braking_distance": [260.9, None],
        }
    )
    path = tmp_path / "train_episodes.csv"
    frame.to_csv(path, index=False)
    text = path.read_text().splitlines()
    compact(path)
    assert not path.exists()
    kept = lzma.decompress((tmp_path / "train_episodes.csv.xz").read_bytes()).decode().splitlines()
    assert kept[0] == ",".join(KEPT_TRAINING)
    assert kept[1] == "0,62.690679132938385,60.40006339550018,121.48628289751012,False"
    assert len(kept) == len(text)
    assert compact(tmp_path / "train_episodes.csv.xz") == 0  # already compact
    # the shield's interventions, the frames and the fault class stay where the record has them
    path = tmp_path / "train_episodes.csv"
    frame.assign(frames=[10, 20], shield_interventions=[1, 0], collision_fault=["", "ego"]).to_csv(path, index=False)
    compact(path)
    kept = lzma.decompress((tmp_path / "train_episodes.csv.xz").read_bytes()).decode().splitlines()
    assert kept[0] == ",".join([*KEPT_TRAINING, "frames", "shield_interventions", "collision_fault"])
    assert kept[2].endswith(",True,20,0,ego")


def test_a_record_without_a_kept_column_is_refused_by_name(tmp_path):
    path = tmp_path / "train_episodes.csv"
    pd.DataFrame({"index": [0], "return_lc": [1.0]}).to_csv(path, index=False)
    try:
        compact(path)
    except ValueError as err:
        assert "return_cf" in str(err) and str(path) in str(err)
    else:
        raise AssertionError("a record without return_cf was compacted")


@pytest.mark.records
def test_every_committed_training_record_is_compact(tmp_path):
    studies = study_records(tmp_path, "studies/")
    records = sorted(studies.rglob("train_episodes.csv*"))
    assert len(records) > 200
    loose = [
        str(p.relative_to(tmp_path))
        for p in records
        if p.suffix != ".xz"
        or (header := lzma.decompress(p.read_bytes()).decode().split("\n", 1)[0].split(",")) != kept_columns(header)
    ]
    assert not loose, f"run python -m kddrl_trl.devtools.records collect, or compact(), on: {loose[:5]}"


def test_a_rewrite_that_fails_leaves_the_record_as_it_was(tmp_path, monkeypatch):
    """The record is rewritten onto itself (an ``.xz`` with more columns): a write that fails before it is complete
    (here at its flush to disk) leaves the old file whole, and no temporary file behind."""
    path = tmp_path / "train_episodes.csv.xz"
    text = "index,start,return_lc,return_cf,mean_speed_kmh,collision\n0,0,1.5,2.5,100.0,False\n"
    path.write_bytes(lzma.compress(text.encode()))
    before = path.read_bytes()

    def fail(fd):
        raise OSError("disk full")

    monkeypatch.setattr("os.fsync", fail)
    with pytest.raises(OSError, match="disk full"):
        compact(path)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == [path.name]


def test_collect_copies_finished_runs_as_a_study_keeps_them(tmp_path):
    """Only finished runs, once; no checkpoints, logs or curve images; CSVs and logs xz-compressed, the training
    record compacted, everything else as it was."""
    sweep = tmp_path / "sweep"
    run, unfinished = sweep / "baseline__kddrl__0", sweep / "baseline__kddrl__1"
    for folder in (run / "checkpoints", run / "logs", run / ".hydra", unfinished):
        folder.mkdir(parents=True)
    (sweep / "multirun.yaml").write_text("sweep: 1\n")
    (run / "summary.json").write_text('{"seed": 0}\n')
    (run / "config.yaml").write_text("seed: 0\n")
    (run / ".hydra" / "config.yaml").write_text("seed: 0\n")
    (run / "checkpoints" / "ep000001.pt").write_bytes(b"weights")
    (run / "logs" / "scalars.csv").write_text("a\n")
    (run / "training_curves.png").write_bytes(b"png")
    (run / "eval_episodes.csv").write_text("index,speed\n0,1.5\n")
    (run / "train.log").write_text("log\n")
    header = "index,start,return_lc,return_cf,mean_speed_kmh,collision\n0,0,1.5,2.5,100.0,False\n"
    (run / "train_episodes.csv").write_text(header)
    (unfinished / "config.yaml").write_text("seed: 1\n")
    dest = tmp_path / "dest"
    assert records.collect(sweep, dest) == ["baseline__kddrl__0"]
    got = sorted(str(p.relative_to(dest)) for p in dest.rglob("*") if p.is_file())
    assert got == [
        "baseline__kddrl__0/.hydra/config.yaml",
        "baseline__kddrl__0/config.yaml",
        "baseline__kddrl__0/eval_episodes.csv.xz",
        "baseline__kddrl__0/summary.json",
        "baseline__kddrl__0/train.log.xz",
        "baseline__kddrl__0/train_episodes.csv.xz",
        "multirun.yaml",
    ]
    assert lzma.decompress((dest / run.name / "eval_episodes.csv.xz").read_bytes()) == b"index,speed\n0,1.5\n"
    kept = lzma.decompress((dest / run.name / "train_episodes.csv.xz").read_bytes()).decode()
    assert kept.split("\n")[0] == ",".join(KEPT_TRAINING)
    assert records.collect(sweep, dest) == []  # collected once
    with pytest.raises(SystemExit, match="no such sweep folder"):
        records.collect(tmp_path / "nope", dest)
