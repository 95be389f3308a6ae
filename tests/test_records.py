"""The studies' run records kept in main's history (``kddrl_trl.devtools.records``): archived records leave the
tree and come back byte for byte, a tracked file that disagrees with its record is refused, and every study's report
regenerates byte-identical from the records of main's history."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from omegaconf import OmegaConf
from testkit import run_module, study_records

from kddrl_trl.conf.schema import algo_from_node
from kddrl_trl.devtools import migrate_configs, records

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


def test_a_seed_batch_s_record_of_its_seeds_stays_in_the_tree(repo):
    batch = repo / "studies" / "x" / "runs" / "baseline__kddrl__seeds0-1"
    batch.mkdir()
    (batch / "seed_batch.json").write_text('{"seeds": [0, 1]}\n')
    _git(repo, "add", "-f", "studies")
    _git(repo, "commit", "-qm", "a batch")
    records.archive(repo, ["studies/x/runs"])
    tracked = _git(repo, "ls-files").split()
    assert "studies/x/runs/baseline__kddrl__seeds0-1/seed_batch.json" in tracked
    assert not any(f.endswith(".xz") for f in tracked)


@pytest.mark.parametrize(
    "folder", ["studies/paper/runs/baseline__kddrl__0", "studies/performance/seed_batch/batched/baseline__kddrl__0"]
)
def test_the_repository_ignores_a_run_s_records_but_what_main_keeps(folder):
    """Main's ``.gitignore`` agrees with :func:`records.kept_in_tree` for every kind of study folder, so that an
    archived record, still on disk, is never added back by ``git add``."""
    names = ["summary.json", "config.yaml", ".hydra/config.yaml", "seed_batch.json", "train_episodes.csv.xz"]
    names += ["eval_episodes.csv.xz", "train.log.xz", "validation.csv.xz", "checkpoints/latest.pt"]
    for name in names:
        path = f"{folder}/{name}"
        ignored = subprocess.run(["git", "-C", str(ROOT), "check-ignore", "--no-index", "-q", path]).returncode == 0
        assert ignored != records.kept_in_tree(path), path


def test_a_run_landed_after_its_studys_archive_is_extracted_from_its_own(repo, tmp_path):
    """Records asked for by a run's folder: the study's archive, taken before that run landed, does not hold it, and
    the run's own later archive does."""
    records.archive(repo, ["studies/x/runs"])
    _git(repo, "commit", "-qm", "out of the tree")
    later = repo / "studies" / "x" / "runs" / "braking__kddrl__0"
    later.mkdir()
    (later / "summary.json").write_text('{"seed": 0}\n')
    (later / "eval_episodes.csv.xz").write_bytes(b"\xfd7zXZ later")
    _git(repo, "add", "-f", "studies")
    _git(repo, "commit", "-qm", "a run lands")
    records.archive(repo, ["studies/x/runs/braking__kddrl__0"])
    _git(repo, "commit", "-qm", "its records out of the tree")
    out = tmp_path / "out"
    assert records.extract(repo, out, ("studies/x/runs/braking__kddrl__0",)) == 2
    assert (out / "studies/x/runs/braking__kddrl__0/eval_episodes.csv.xz").read_bytes() == b"\xfd7zXZ later"
    assert not (out / "studies/x/runs/baseline__kddrl__0").exists()


def test_a_shallow_clone_says_in_one_line_why_it_cannot_restore_and_what_to_run(repo, tmp_path):
    records.archive(repo, ["studies/x/runs"])
    _git(repo, "commit", "-qm", "out of the tree")
    shallow = tmp_path / "shallow"
    subprocess.run(["git", "clone", "-q", "--depth", "1", f"file://{repo}", str(shallow)], check=True)
    with pytest.raises(SystemExit, match=r"it is shallow \(git clone --depth\).*git fetch --unshallow") as err:
        records.restore(shallow, [])
    assert "\n" not in str(err.value)


def test_a_superseded_run_moves_with_its_archived_records_and_a_rerun_takes_its_place(repo):
    records.archive(repo, ["studies/x/runs"])
    _git(repo, "commit", "-qm", "out of the tree")
    old, new = "studies/x/runs/baseline__kddrl__0", "studies/x/superseded/baseline__kddrl__0"
    assert records.move(repo, old, new) == 3  # summary, config and the restored record
    _git(repo, "commit", "-qm", "superseded")
    rerun = repo / old
    rerun.mkdir(parents=True)
    (rerun / "summary.json").write_text('{"seed": 0, "rerun": true}\n')
    (rerun / "config.yaml").write_text("seed: 0\n")
    (rerun / "eval_episodes.csv.xz").write_bytes(b"\xfd7zXZ rerun")
    _git(repo, "add", "-f", "studies")
    _git(repo, "commit", "-qm", "the rerun")
    records.archive(repo, ["studies/x/runs"])
    _git(repo, "commit", "-qm", "the rerun out of the tree")
    for f in (repo / "studies").rglob("*.xz"):
        f.unlink()
    # the first archive's files come back under the superseded folder, the rerun's in the run's own folder: no
    # record of the first run collides with the rerun's tracked summary
    assert records.restore(repo, []) == 2
    assert (repo / new / "eval_episodes.csv.xz").read_bytes() == b"\xfd7zXZ records"
    assert (repo / old / "eval_episodes.csv.xz").read_bytes() == b"\xfd7zXZ rerun"
    assert json.loads((repo / new / "summary.json").read_text()) == {"seed": 0}
    assert records.restore(repo, ["x/superseded"]) == 1
    with pytest.raises(SystemExit, match="exists already"):
        records.move(repo, old, new)


def test_a_tracked_file_that_disagrees_with_its_record_is_refused(repo):
    records.archive(repo, ["studies/x/runs"])
    _git(repo, "commit", "-qm", "out of the tree")
    summary = repo / "studies" / "x" / "runs" / "baseline__kddrl__0" / "summary.json"
    summary.write_text('{"seed": 1}\n')
    with pytest.raises(SystemExit, match="summary.json differs from its record"):
        records.restore(repo, [])


OLD_CONFIG = """\
train:
  n_steps: 1
algo:
  name: kddrl
  kind: hierarchical
  transforms:
    enabled: true
    compile: true
"""


def test_a_migrated_config_is_accepted_and_any_other_difference_refused(repo):
    config = repo / "studies" / "x" / "runs" / "baseline__kddrl__0" / "config.yaml"
    config.write_text(OLD_CONFIG)
    _git(repo, "commit", "-qam", "an older run's config")
    records.archive(repo, ["studies/x/runs"])
    _git(repo, "commit", "-qm", "out of the tree")
    assert migrate_configs.main([str(repo / "studies")]) == 0
    migrated = config.read_text()
    assert "compile" not in migrated and "event_oracle: false" in migrated and "prioritized: false" in migrated
    assert migrate_configs.main(["--check", str(repo / "studies")]) == 0  # once: nothing is left to migrate
    records.restore(repo, [])  # the tracked config is its record migrated: accepted
    assert config.read_text() == migrated
    config.write_text(migrated.replace("enabled: true", "enabled: false"))
    with pytest.raises(SystemExit, match="config.yaml differs from its record"):
        records.restore(repo, [])


def test_every_committed_run_config_loads_through_the_schema():
    """The studies' configs are migrated (``python -m kddrl_trl.devtools.migrate_configs --check studies``: none
    left) and each algo node loads, but those of the PASAC before its rewrite (a different algorithm; its runs are
    kept as records, not as configs to rerun)."""
    assert migrate_configs.main(["--check", str(ROOT / "studies")]) == 0
    tracked = _git(ROOT, "ls-files", "studies/*config.yaml").split()
    configs = [ROOT / f for f in tracked if "/.hydra/" not in f]
    failed = []
    for path in configs:
        try:
            algo_from_node(OmegaConf.load(path).algo)
        except Exception as err:  # noqa: BLE001 - collected and named below
            failed.append(f"{path.relative_to(ROOT)}: {type(err).__name__}")
    assert len(configs) > 300
    assert all("pasac_unified" in f and "comparison" in f for f in failed), failed


def test_archive_wants_the_records_committed_and_the_manifest_well_formed(repo):
    (repo / "studies" / "x" / "runs" / "baseline__kddrl__0" / "eval_episodes.csv.xz").write_bytes(b"changed")
    with pytest.raises(SystemExit, match="commit studies/x/runs whole first"):
        records.archive(repo, ["studies/x/runs"])
    (repo / "studies" / "records.json").write_text('{"runs": []}')
    with pytest.raises(SystemExit, match="records.json is malformed"):
        records.restore(repo, [])


#: the footer line of a report made by ``python -m kddrl_trl.report``: the command that made it
COMMAND = "* **Command:** `python -m kddrl_trl.report "
#: every committed report of that command (the verdict's, with its claims file, among them)
REPORTS = sorted(
    p.parent.relative_to(ROOT).as_posix() for p in ROOT.glob("studies/**/report.md") if COMMAND in p.read_text()
)


def _without_provenance(md: str) -> list[str]:
    """A report.md's lines but its command (another ``out=``) and where and when it was made."""
    return [line for line in md.splitlines() if not line.startswith((COMMAND, "* **Report made at commit"))]


@pytest.mark.records
@pytest.mark.parametrize("folder", REPORTS)
def test_a_study_report_regenerates_byte_identical_from_its_own_command(folder, tmp_path):
    """The command in a report's footer, run again on the records of main's history (their summaries and configs
    from the tree, the rest extracted), writes the same report.json byte for byte and the same report.md but its
    provenance."""
    import shlex
    import shutil

    md = (ROOT / folder / "report.md").read_text()
    args = shlex.split(next(line for line in md.splitlines() if line.startswith(COMMAND)).split("`")[1])[3:]
    runs = [a for a in args if "=" not in a]
    claims = [a.split("=", 1)[1] for a in args if a.startswith("claims=")]
    tracked = _git(ROOT, "ls-files", "--", *runs, *claims).split()
    for name in tracked:  # what main keeps in its tree, then the records from its history beside it
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ROOT / name, tmp_path / name)
    study_records(tmp_path, *runs)
    out = tmp_path / "regenerated"
    run_module(["kddrl_trl.report", *[a for a in args if not a.startswith("out=")], f"out={out}"], cwd=tmp_path)
    assert (out / "report.json").read_bytes() == (ROOT / folder / "report.json").read_bytes(), folder
    assert _without_provenance((out / "report.md").read_text()) == _without_provenance(md), folder
