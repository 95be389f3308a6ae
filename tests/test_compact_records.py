"""The committed runs' training records stay compact, and compacting keeps what the report reads."""

import importlib.util
import lzma
from pathlib import Path

import pandas as pd
import pytest
from testkit import study_records

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("compact_records", ROOT / "studies" / "compact_records.py")
compact_records = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(compact_records)


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
    compact_records.compact(path)
    assert not path.exists()
    kept = lzma.decompress((tmp_path / "train_episodes.csv.xz").read_bytes()).decode().splitlines()
    assert kept[0] == ",".join(compact_records.KEPT)
    assert kept[1] == "0,62.690679132938385,60.40006339550018,121.48628289751012,False"
    assert len(kept) == len(text)
    assert compact_records.compact(tmp_path / "train_episodes.csv.xz") == 0  # already compact


def test_a_record_without_a_kept_column_is_refused_by_name(tmp_path):
    path = tmp_path / "train_episodes.csv"
    pd.DataFrame({"index": [0], "return_lc": [1.0]}).to_csv(path, index=False)
    try:
        compact_records.compact(path)
    except ValueError as err:
        assert "return_cf" in str(err) and str(path) in str(err)
    else:
        raise AssertionError("a record without return_cf was compacted")


def test_every_committed_training_record_is_compact(tmp_path):
    studies = study_records(tmp_path, "studies/")
    records = sorted(studies.rglob("train_episodes.csv*"))
    assert len(records) > 200
    loose = [
        str(p.relative_to(tmp_path))
        for p in records
        if p.suffix != ".xz"
        or lzma.decompress(p.read_bytes()).decode().split("\n", 1)[0] != ",".join(compact_records.KEPT)
    ]
    assert not loose, f"run python studies/compact_records.py on: {loose[:5]}"


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
        compact_records.compact(path)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == [path.name]
