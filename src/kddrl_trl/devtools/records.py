"""The studies' run records live in main's history, not in its tree.

main's tree keeps what a reader of a study needs at a glance: each run's ``summary.json`` and its configs
(``*.yaml``). The rest of a run's records, its episode CSVs, logs and traces (what a report is regenerated from),
is kept in commits of main that ``studies/records.json`` lists, each with the paths it holds whole. History is the
archive: it is never rewritten (the reports cite commits), and a clone of main carries it. Git ignores the restored
files (``.gitignore``). From the repository's root:

    python -m kddrl_trl.devtools.records collect SWEEP DEST      # a sweep's finished runs, as a study keeps them
    python -m kddrl_trl.devtools.records restore [STUDY ...]    # the records back into studies/<name>/
    python -m kddrl_trl.devtools.records archive PATH [PATH ...] # PATHs, committed whole at HEAD, leave the tree;
                                                                  # commit the result
    python -m kddrl_trl.devtools.records move OLD NEW            # a run's records move (a superseded run, say):
                                                                  # the archives before it restore OLD's files as NEW's

``collect`` copies each finished run (it has its summary) that DEST lacks, without its checkpoints, TorchRL logs or
curve images (the report redraws them), its CSVs and logs xz-compressed (the reports read them so), and its training
record cut to the columns the reports and a reader of the learning curves use (:func:`compact`).

After ``restore``, ``python -m kddrl_trl.report`` regenerates every study's report byte-identical. A restored file
that main also tracks must come out as main has it (a run's ``config.yaml`` as its record migrated to the current
schema, :mod:`kddrl_trl.devtools.migrate_configs`); one that differs is an error naming it.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import lzma
import shutil
import subprocess
import tarfile
from pathlib import Path, PurePosixPath

from omegaconf import OmegaConf

from ..atomic_files import write_atomic
from ..run_folder import RunFolder
from .migrate_configs import migrate

MANIFEST = PurePosixPath("studies/records.json")


#: the columns of a training record a study keeps: the report draws Fig. 8 from the returns; speed and collisions stay
#: for a reader who asks how driving changed while learning (evaluation records are kept whole: the reports read
#: every column)
KEPT_TRAINING = ("index", "return_lc", "return_cf", "mean_speed_kmh", "collision")
#: kept too where the record has them (after the columns above, in this order): the frames and the shield's
#: interventions (a shield's rate while learning), and the collision's fault class
KEPT_WHERE_PRESENT = ("frames", "shield_interventions", "collision_fault")


def kept_columns(header: list[str]) -> list[str]:
    """The columns a compact training record of ``header`` holds: :data:`KEPT_TRAINING`, then those of
    :data:`KEPT_WHERE_PRESENT` it has."""
    return [*KEPT_TRAINING, *(c for c in KEPT_WHERE_PRESENT if c in header)]


#: what a study does not keep of a run folder: its checkpoints and TorchRL logs (top level), its curve images
NOT_COLLECTED = ("checkpoints", "logs")


def compact_record(raw: bytes, source: Path) -> tuple[bytes, bool]:
    """A training record's content cut to the :func:`kept_columns`, every kept value's text as it was, and whether
    it was compact already; ``source`` names the record in an error."""
    rows = list(csv.reader(io.StringIO(raw.decode())))
    header = rows[0]
    missing = [k for k in KEPT_TRAINING if k not in header]
    if missing:
        raise ValueError(f"{source}: no column(s) {', '.join(missing)}")
    kept = kept_columns(header)
    if header == kept:
        return raw, True
    at = [header.index(k) for k in kept]
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows([[row[i] for i in at] for row in rows])
    return out.getvalue().encode(), False


def compact(path: Path) -> int:
    """Rewrites one training record as ``train_episodes.csv.xz`` (:func:`compact_record`); returns the bytes saved
    (0 for a record compact already)."""
    raw = lzma.decompress(path.read_bytes()) if path.suffix == ".xz" else path.read_bytes()
    kept, already = compact_record(raw, path)
    if already and path.suffix == ".xz":
        return 0
    target = path.with_name(RunFolder.TRAIN_EPISODES + ".xz")
    before = path.stat().st_size
    data = lzma.compress(kept, preset=9)
    write_atomic(target, lambda fh: fh.write(data), binary=True)  # a killed rewrite leaves the record as it was
    if target != path:
        path.unlink()
    return before - target.stat().st_size


def collect(sweep: Path, dest: Path) -> list[str]:
    """The finished runs of ``sweep`` that ``dest`` lacks, copied as a study keeps them (module docstring); a run
    ``dest`` holds already is left as it is (a finished run's records never change). Returns their names."""
    if not sweep.is_dir():
        raise SystemExit(f"records collect: {sweep}: no such sweep folder")
    dest.mkdir(parents=True, exist_ok=True)
    if (sweep / "multirun.yaml").is_file() and not (dest / "multirun.yaml").exists():
        shutil.copyfile(sweep / "multirun.yaml", dest / "multirun.yaml")
    collected = []
    for run in sorted(p for p in sweep.iterdir() if p.is_dir()):
        if not RunFolder(run).is_finished() or RunFolder(dest / run.name).is_finished():
            continue
        for f in sorted(p for p in run.rglob("*") if p.is_file()):
            rel = f.relative_to(run)
            if rel.parts[0] in NOT_COLLECTED or f.name == RunFolder.CURVES:
                continue
            target = dest / run.name / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            if f.suffix in (".csv", ".log"):
                packed = target.with_name(target.name + ".xz")
                data = lzma.compress(f.read_bytes(), preset=9)
                write_atomic(packed, lambda fh, data=data: fh.write(data), binary=True)
            else:
                shutil.copyfile(f, target)
        for record in sorted((dest / run.name).rglob(RunFolder.TRAIN_EPISODES + "*")):
            compact(record)
        collected.append(run.name)
    return collected


def kept_in_tree(path: str) -> bool:
    """Whether a record file stays in main's tree: a run's summary and configs, a seed batch's record of its seeds
    (``seed_batch.json``), and the small per-seed results of a plain script (``studies/reuse/runs/example/*.json``).
    The repository's ``.gitignore`` ignores the rest, so that no ``git add`` takes an archived record back in."""
    p = PurePosixPath(path)
    return (
        p.name in (RunFolder.SUMMARY, RunFolder.SEED_BATCH)
        or p.suffix == ".yaml"
        or (p.suffix == ".json" and "example" in p.parts)
    )


def repo_root(start: Path | None = None) -> Path:
    """The git work tree holding ``start`` (default: the current directory)."""
    out = subprocess.run(
        ["git", "-C", str(start or Path.cwd()), "rev-parse", "--show-toplevel"], capture_output=True, text=True
    )
    if out.returncode != 0:
        raise SystemExit(f"records: {start or Path.cwd()} is not inside a git clone of kddrl_trl")
    return Path(out.stdout.strip())


def _git(root: Path, *args: str, binary: bool = False):
    out = subprocess.run(["git", "-C", str(root), *args], capture_output=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"records: git {' '.join(args)} failed: {out.stderr.decode().strip()}")
    return out.stdout if binary else out.stdout.decode()


def manifest(root: Path) -> list[dict]:
    """The archive entries of ``studies/records.json`` (``[]`` where there is none), each checked for its keys."""
    path = root / MANIFEST
    if not path.exists():
        return []
    try:
        entries = json.loads(path.read_text())["archives"]
    except (json.JSONDecodeError, KeyError, TypeError) as err:
        raise SystemExit(f"records: {MANIFEST} is malformed ({err}); it must be {{'archives': [...]}}") from None
    for i, e in enumerate(entries):
        if isinstance(e, dict) and isinstance(e.get("moved"), dict):
            continue
        if not isinstance(e, dict) or not isinstance(e.get("commit"), str) or not isinstance(e.get("paths"), list):
            raise SystemExit(
                f"records: {MANIFEST} archives[{i}] needs a 'commit' and a list of 'paths' (or a 'moved' mapping)"
            )
    return entries


def _moves(later: list[dict]) -> list[tuple[str, str]]:
    """The ``(OLD, NEW)`` of the ``moved`` entries after an archive, in order."""
    return [(old.rstrip("/"), new.rstrip("/")) for e in later for old, new in e.get("moved", {}).items()]


def _renamed(name: str, moves: list[tuple[str, str]]) -> str:
    """The path an archived file has now (``OLD/x`` is ``NEW/x`` after ``{"moved": {OLD: NEW}}``)."""
    for old, new in moves:
        if _under(name, old):
            name = new + name[len(old) :]
    return name


def _moved_from(wanted: list[str], moves: list[tuple[str, str]]) -> list[str]:
    """The archive paths (OLD of each move) whose files are now under, or hold, one of ``wanted``."""
    return [old for old, new in moves if any(_under(x, new) or _under(new, x) for x in wanted)]


def _under(path: str, folder: str) -> bool:
    """``path`` is ``folder`` or lies inside it (whole path components: ``runs_5-14`` is not under ``runs``)."""
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def _in_commit(root: Path, commit: str, path: str) -> bool:
    probe = ["git", "-C", str(root), "cat-file", "-e", f"{commit}:{path.rstrip('/')}"]
    return subprocess.run(probe, capture_output=True).returncode == 0


def extract(root: Path, dest: Path, prefixes: tuple[str, ...] = ()) -> int:
    """Write every file of every archive (in the manifest's order; a later one wins) that lies under one of
    ``prefixes`` (all where empty) to the same relative path under ``dest``. A file that ``dest`` holds already
    and main keeps in its tree must be byte-identical to its record in the form main keeps (:func:`current`: a run's
    config migrated; archives taken after the migration hold it migrated, earlier ones as the run wrote it), and ends
    in that form. Returns the number of files written."""
    written, entries = 0, manifest(root)
    wanted = [x.rstrip("/") for x in prefixes]
    for i, entry in enumerate(entries):
        if "moved" in entry:
            continue
        commit = entry["commit"]
        probe = subprocess.run(["git", "-C", str(root), "cat-file", "-e", f"{commit}^{{commit}}"], capture_output=True)
        if probe.returncode != 0:
            shallow = _git(root, "rev-parse", "--is-shallow-repository").strip() == "true"
            raise SystemExit(
                f"records: commit {commit} ({MANIFEST}) is not in this clone"
                + (
                    ": it is shallow (git clone --depth), and the records live in main's history; run "
                    "git fetch --unshallow, then restore again"
                    if shallow
                    else "; fetch main's full history (git fetch origin main), then restore again"
                )
            )
        moves = _moves(entries[i + 1 :])
        paths = entry["paths"]
        if prefixes:  # the narrower of each overlapping pair: one run of a study is archived alone; and an archive
            # path holding a moved folder's old place whole (its files are filtered by their new names below)
            olds = _moved_from(wanted, moves)
            paths = sorted(
                {x for x in wanted for p in paths if _under(x, p)}
                | {p for p in paths for x in wanted if _under(p, x)}
                | {p for p in paths for x in olds if _under(x, p) or _under(p, x)}
            )
            # a wanted folder inside an archived one may postdate that archive (a run landed later): not in it
            paths = [p for p in paths if _in_commit(root, commit, p)]
        if not paths:
            continue
        with tarfile.open(fileobj=io.BytesIO(_git(root, "archive", commit, "--", *paths, binary=True))) as tar:
            for member in tar.getmembers():
                name = _renamed(member.name, moves)
                if not member.isfile() or (prefixes and not any(_under(name, x) for x in wanted)):
                    continue
                target, data = dest / name, tar.extractfile(member).read()
                if kept_in_tree(name) and target.exists():
                    have = target.read_bytes()
                    if have != data and current(name, have) != current(name, data):
                        raise SystemExit(f"records: {target} differs from its record in {commit}")
                    if current(name, have) == have:  # the current form (main's, or migrated already)
                        continue
                    data = current(name, data)  # an older form written by an earlier archive: migrated
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(data)
                written += 1
    return written


def migrated(name: str, data: bytes) -> bytes | None:
    """A run's ``config.yaml`` as main keeps it: its record migrated to the current schema
    (:mod:`kddrl_trl.devtools.migrate_configs`, done once in main's tree); None for any other file."""
    if PurePosixPath(name).name != RunFolder.CONFIG or ".hydra" in PurePosixPath(name).parts:
        return None
    config = OmegaConf.to_container(OmegaConf.create(data.decode()))
    return OmegaConf.to_yaml(config).encode() if migrate(config) else None


def current(name: str, data: bytes) -> bytes:
    """A record file in the form main keeps: a run's config migrated (:func:`migrated`), any other file as it is."""
    return migrated(name, data) or data


def restore(root: Path, studies: list[str]) -> int:
    """The named studies' records (every study's where none is named) back into the work tree."""
    return extract(root, root, tuple(f"studies/{s}/" for s in studies))


def archive(root: Path, paths: list[str]) -> int:
    """HEAD holds ``paths`` whole: list HEAD for them in the manifest and take their record files out of the index
    (they stay on disk, ignored). Returns the number of files taken out."""
    head = _git(root, "rev-parse", "HEAD").strip()
    if _git(root, "status", "--porcelain", "--", *paths).strip():
        raise SystemExit(f"records: commit {' '.join(paths)} whole first (git add -f, git commit)")
    tracked = [f for f in _git(root, "ls-files", "--", *paths).splitlines() if f]
    if not tracked:
        raise SystemExit(f"records: nothing of {' '.join(paths)} is committed at HEAD")
    entries = manifest(root) + [{"commit": head, "paths": sorted(paths)}]
    (root / MANIFEST).write_text(json.dumps({"archives": entries}, indent=1) + "\n")
    leaving = [f for f in tracked if not kept_in_tree(f)]
    for i in range(0, len(leaving), 500):
        _git(root, "rm", "--cached", "--quiet", "--", *leaving[i : i + 500])
    _git(root, "add", str(MANIFEST))
    return len(leaving)


def move(root: Path, old: str, new: str) -> int:
    """A run's (or a folder's) records move from ``old`` to ``new``: its files in main's tree by ``git mv``, its
    restored records on disk with them, and a ``moved`` entry in the manifest, so that the archives taken before it
    restore ``old``'s files under ``new`` (a run rerun in ``old``'s place gets ``old`` for its own records). Returns
    the number of files moved on disk. Commit the result."""
    src, dst = root / old, root / new
    if not src.is_dir():
        raise SystemExit(f"records move: {old}: no such folder")
    if dst.exists():
        raise SystemExit(f"records move: {new} exists already")
    tracked = [f for f in _git(root, "ls-files", "--", old).splitlines() if f]
    files = [p for p in src.rglob("*") if p.is_file()]
    for f in files:
        target = dst / f.relative_to(src)
        target.parent.mkdir(parents=True, exist_ok=True)
        if str(f.relative_to(root)) in tracked:
            _git(root, "mv", str(f.relative_to(root)), str(target.relative_to(root)))
        else:
            f.replace(target)
    shutil.rmtree(src)
    entries = manifest(root) + [{"moved": {old.rstrip("/"): new.rstrip("/")}}]
    (root / MANIFEST).write_text(json.dumps({"archives": entries}, indent=1) + "\n")
    _git(root, "add", str(MANIFEST))
    return len(files)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m kddrl_trl.devtools.records", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    collecting = sub.add_parser("collect", help="a sweep's finished runs, as a study keeps them")
    collecting.add_argument("sweep", type=Path)
    collecting.add_argument("dest", type=Path)
    sub.add_parser("restore", help="the records back into the studies' folders").add_argument("studies", nargs="*")
    sub.add_parser("archive", help="records committed whole leave the tree").add_argument("paths", nargs="+")
    moving = sub.add_parser("move", help="a run's records move (a superseded run), with its archived history")
    moving.add_argument("old")
    moving.add_argument("new")
    args = ap.parse_args(argv)
    if args.command == "collect":
        names = collect(args.sweep, args.dest)
        print(f"records: {len(names)} run(s) collected into {args.dest}" + (f": {' '.join(names)}" if names else ""))
        return
    root = repo_root()
    if args.command == "restore":
        print(f"records: {restore(root, args.studies)} files restored")
    elif args.command == "move":
        print(f"records: {move(root, args.old, args.new)} files moved to {args.new}; commit the change")
    else:
        print(f"records: {archive(root, args.paths)} files leave the tree; commit the change")


if __name__ == "__main__":
    main()
