"""The studies' run records kept in main's history (``kddrl_trl.devtools.records``): archived records leave the
tree and come back byte for byte, a tracked file that disagrees with its record is refused, and the verdict study's
report regenerates byte-identical from the records of main's history."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from testkit import run_module, study_records

from kddrl_trl.devtools import records

ROOT = Path(__file__).resolve().parents[1]


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, text=True).stdout


@pytest.fixture
def repo(tmp_path):
    """A repository with one study run committed whole: its summary, config and an episode record."""
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "config", "user.email", "t@t")
    _git(tmp_path, "config", "user.name", "t")
    run = tmp_path / "studies" / "x" / "runs" / "baseline__kddrl__0"
    run.mkdir(parents=True)
    (run / "summary.json").write_text('{"seed": 0}\n')
    (run / "config.yaml").write_text("seed: 0\n")
    (run / "eval_episodes.csv.xz").write_bytes(b"\xfd7zXZ records")
    (tmp_path / ".gitignore").write_text("/studies/*/runs/**/*.xz\n")
    _git(tmp_path, "add", "-A")
    _git(tmp_path, "add", "-f", "studies")
    _git(tmp_path, "commit", "-qm", "records")
    return tmp_path


def test_archived_records_leave_the_tree_and_come_back(repo):
    head = _git(repo, "rev-parse", "HEAD").strip()
    assert records.archive(repo, ["studies/x/runs"]) == 1
    _git(repo, "commit", "-qm", "out of the tree")
    tracked = _git(repo, "ls-files").split()
    assert "studies/x/runs/baseline__kddrl__0/summary.json" in tracked
    assert not any(f.endswith(".xz") for f in tracked)
    assert json.loads((repo / "studies" / "records.json").read_text()) == {
        "archives": [{"commit": head, "paths": ["studies/x/runs"]}]
    }
    record = repo / "studies" / "x" / "runs" / "baseline__kddrl__0" / "eval_episodes.csv.xz"
    record.unlink()
    assert records.restore(repo, []) == 1
    assert record.read_bytes() == b"\xfd7zXZ records"
    assert records.restore(repo, ["other"]) == 0


def test_a_tracked_file_that_disagrees_with_its_record_is_refused(repo):
    records.archive(repo, ["studies/x/runs"])
    _git(repo, "commit", "-qm", "out of the tree")
    summary = repo / "studies" / "x" / "runs" / "baseline__kddrl__0" / "summary.json"
    summary.write_text('{"seed": 1}\n')
    with pytest.raises(SystemExit, match="summary.json differs from its record"):
        records.restore(repo, [])


def test_archive_wants_the_records_committed_and_the_manifest_well_formed(repo):
    (repo / "studies" / "x" / "runs" / "baseline__kddrl__0" / "eval_episodes.csv.xz").write_bytes(b"changed")
    with pytest.raises(SystemExit, match="commit studies/x/runs whole first"):
        records.archive(repo, ["studies/x/runs"])
    (repo / "studies" / "records.json").write_text('{"runs": []}')
    with pytest.raises(SystemExit, match="records.json is malformed"):
        records.restore(repo, [])


def test_the_verdict_report_regenerates_byte_identical_from_history(tmp_path):
    studies = study_records(tmp_path, "studies/paper/runs", "studies/paper/runs_5-14")
    out, runs = tmp_path / "report", [str(studies / "paper" / f) for f in ("runs", "runs_5-14")]
    run_module(["kddrl_trl.report", *runs, f"out={out}", "verdict=true"], cwd=tmp_path)
    assert (out / "report.json").read_bytes() == (ROOT / "studies" / "paper" / "report.json").read_bytes()
