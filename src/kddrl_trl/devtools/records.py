"""The studies' run records live in main's history, not in its tree.

main's tree keeps what a reader of a study needs at a glance: each run's ``summary.json`` and its configs
(``*.yaml``). The rest of a run's records, its episode CSVs, logs and traces (what a report is regenerated from),
is kept in commits of main that ``studies/records.json`` lists, each with the paths it holds whole. History is the
archive: it is never rewritten (the reports cite commits), and a clone of main carries it. Git ignores the restored
files (``.gitignore``). From the repository's root:

    python -m kddrl_trl.devtools.records restore [STUDY ...]    # the records back into studies/<name>/
    python -m kddrl_trl.devtools.records archive PATH [PATH ...] # PATHs, committed whole at HEAD, leave the tree;
                                                                  # commit the result

After ``restore``, ``python -m kddrl_trl.report`` regenerates every study's report byte-identical. A restored file
that main also tracks must come out as main has it (a run's ``config.yaml`` as its record migrated to the current
schema, :mod:`kddrl_trl.devtools.migrate_configs`); one that differs is an error naming it.
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import tarfile
from pathlib import Path, PurePosixPath

from omegaconf import OmegaConf

from ..run_folder import RunFolder
from .migrate_configs import migrate

MANIFEST = PurePosixPath("studies/records.json")


def kept_in_tree(path: str) -> bool:
    """Whether a record file stays in main's tree: a run's summary and configs, and the small per-seed results of a
    plain script (``studies/reuse/runs/example/*.json``)."""
    p = PurePosixPath(path)
    return p.name == RunFolder.SUMMARY or p.suffix == ".yaml" or (p.suffix == ".json" and "example" in p.parts)


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
        if not isinstance(e, dict) or not isinstance(e.get("commit"), str) or not isinstance(e.get("paths"), list):
            raise SystemExit(f"records: {MANIFEST} archives[{i}] needs a 'commit' and a list of 'paths'")
    return entries


def _under(path: str, folder: str) -> bool:
    """``path`` is ``folder`` or lies inside it (whole path components: ``runs_5-14`` is not under ``runs``)."""
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def extract(root: Path, dest: Path, prefixes: tuple[str, ...] = ()) -> int:
    """Write every file of every archive (in the manifest's order; a later one wins) that lies under one of
    ``prefixes`` (all where empty) to the same relative path under ``dest``. A file that ``dest`` holds already
    and main keeps in its tree must be byte-identical. Returns the number of files written."""
    written = 0
    for entry in manifest(root):
        commit = entry["commit"]
        probe = subprocess.run(["git", "-C", str(root), "cat-file", "-e", f"{commit}^{{commit}}"], capture_output=True)
        if probe.returncode != 0:
            raise SystemExit(
                f"records: commit {commit} ({MANIFEST}) is not in this clone; a shallow clone lacks it: "
                "git fetch --unshallow"
            )
        paths = entry["paths"]
        if prefixes:  # the narrower of each overlapping pair: one run of a study is archived alone
            wanted = [x.rstrip("/") for x in prefixes]
            paths = sorted(
                {x for x in wanted for p in paths if _under(x, p)} | {p for p in paths for x in wanted if _under(p, x)}
            )
        if not paths:
            continue
        with tarfile.open(fileobj=io.BytesIO(_git(root, "archive", commit, "--", *paths, binary=True))) as tar:
            for member in tar.getmembers():
                if not member.isfile() or (prefixes and not any(_under(member.name, x) for x in wanted)):
                    continue
                target, data = dest / member.name, tar.extractfile(member).read()
                if kept_in_tree(member.name) and target.exists():
                    if target.read_bytes() != data and target.read_bytes() != migrated(member.name, data):
                        raise SystemExit(f"records: {target} differs from its record in {commit}")
                    continue
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


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m kddrl_trl.devtools.records", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("restore", help="the records back into the studies' folders").add_argument("studies", nargs="*")
    sub.add_parser("archive", help="records committed whole leave the tree").add_argument("paths", nargs="+")
    args = ap.parse_args(argv)
    root = repo_root()
    if args.command == "restore":
        print(f"records: {restore(root, args.studies)} files restored")
    else:
        print(f"records: {archive(root, args.paths)} files leave the tree; commit the change")


if __name__ == "__main__":
    main()
