"""Run folders: the names of a run's files (:class:`RunFolder`), where its checkpoints are, which one is the latest,
and which folder a run writes into.

A run folder holds ``config.yaml`` (the resolved config), ``train_episodes.csv``, ``validation.csv``,
``training_curves.png`` and ``checkpoints/`` (a training run), ``eval_episodes.csv`` and ``summary.json``, which is
written last: a folder with a summary is a finished run (or evaluation). Checkpoints:
``<run_dir>/checkpoints/ep<NNNNNN>.pt`` (the last two) and ``<run_dir>/checkpoints/latest`` (the file name of the
newest complete checkpoint, :mod:`kddrl_trl.training.checkpoint`, which falls back to the previous one when the
newest does not load). The output folder of an entry point is chosen once, while Hydra composes the config
(:mod:`kddrl_trl.conf.resolvers`); the entry point reads it from ``HydraConfig`` and learns that it resumes from the
checkpoint the folder holds.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from contextlib import contextmanager
from pathlib import Path

from .atomic_files import write_json_atomic, write_text_atomic


class RunFolder:
    """The files of one run (or evaluation) folder, by name: the one place that knows them. The writers
    (``train``, ``evaluate``, the final evaluation) and the readers (resume, :mod:`kddrl_trl.reporting.records`, the
    studies' tools) both go through it. :meth:`finish` writes the summary, and the summary is always the last file a
    run writes: a folder that has one is finished."""

    CONFIG = "config.yaml"
    SUMMARY = "summary.json"
    EVAL_EPISODES = "eval_episodes.csv"
    TRAIN_EPISODES = "train_episodes.csv"
    VALIDATION = "validation.csv"
    CURVES = "training_curves.png"
    CHECKPOINTS = "checkpoints"
    #: a seed batch's folder: its seeds and their run folders (:mod:`kddrl_trl.training.seed_batch_trainer`)
    SEED_BATCH = "seed_batch.json"

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    @property
    def config(self) -> Path:
        return self.path / self.CONFIG

    @property
    def summary(self) -> Path:
        return self.path / self.SUMMARY

    @property
    def eval_episodes(self) -> Path:
        return self.path / self.EVAL_EPISODES

    @property
    def train_episodes(self) -> Path:
        return self.path / self.TRAIN_EPISODES

    @property
    def validation(self) -> Path:
        return self.path / self.VALIDATION

    @property
    def curves(self) -> Path:
        return self.path / self.CURVES

    @property
    def checkpoints(self) -> Path:
        return self.path / self.CHECKPOINTS

    def is_finished(self) -> bool:
        """Whether the run wrote its summary (its last file)."""
        return self.summary.is_file()

    def read_summary(self) -> dict:
        return json.loads(self.summary.read_text())

    def write_config(self, text: str) -> None:
        write_text_atomic(self.config, text)

    def write_table(self, path: Path, rows: list[dict]) -> None:
        """``rows`` as a CSV at ``path`` (one of this folder's tables: :attr:`train_episodes`, :attr:`validation`)."""
        import pandas as pd  # here, not at the top: resolving a config's run folder (conf/resolvers.py) needs no pandas

        write_text_atomic(path, pd.DataFrame(rows).to_csv(index=False))

    def finish(self, summary: dict, episodes: list[dict] | None = None) -> dict:
        """The run's last writes: its evaluated ``episodes`` (``eval_episodes.csv``), then ``summary`` as
        ``summary.json``, which marks the run finished. Every other file of the run must be written before."""
        if episodes is not None:
            self.write_table(self.eval_episodes, episodes)
        write_json_atomic(self.summary, summary)
        return summary


def checkpoint_dir(run_dir: str | Path) -> Path:
    return RunFolder(run_dir).checkpoints


#: the file in :func:`checkpoint_dir` naming the newest complete checkpoint
LATEST = "latest"


def best_checkpoint(run_dir: str | Path) -> Path:
    """The learner of the best validation so far (:func:`kddrl_trl.training.checkpoint.save_best_checkpoint`)."""
    return checkpoint_dir(run_dir) / "best.pt"


def checkpoint_candidates(run_dir: str | Path) -> list[Path]:
    """The training checkpoints of ``run_dir``, newest first: the one ``latest`` names (when it exists), then the
    other ``ep<NNNNNN>.pt`` files by decreasing episode count. A missing or unreadable pointer only changes the
    order: whatever checkpoint files are there are still found (the loader falls back along this list)."""
    folder = checkpoint_dir(run_dir)
    files = sorted(folder.glob("ep*.pt"), reverse=True)
    pointer = folder / LATEST
    try:
        named = folder / pointer.read_text().strip() if pointer.is_file() else None
    except (OSError, UnicodeDecodeError):
        named = None
    if named is not None and named.is_file():
        files = [named] + [f for f in files if f != named]
    return files


def latest_checkpoint(run_dir: str | Path) -> Path | None:
    """The newest checkpoint of ``run_dir`` (:func:`checkpoint_candidates`), or None if it has none."""
    candidates = checkpoint_candidates(run_dir)
    return candidates[0] if candidates else None


def run_checkpoint(run_dir: str | Path) -> Path | None:
    """The newest checkpoint of a run folder, or of a seed batch's folder (``seed_batch.json``): the newest of its
    seed folders'; None if there is none."""
    own = latest_checkpoint(run_dir)
    if own is not None or not (Path(run_dir) / RunFolder.SEED_BATCH).is_file():
        return own
    found = [c for d in sorted(Path(run_dir).iterdir()) if d.is_dir() and (c := latest_checkpoint(d)) is not None]
    return max(found, key=lambda c: c.stat().st_mtime) if found else None


def resume_requested(resume) -> bool:
    """Whether a ``resume`` option asks to resume (``true`` or a run folder; ``false`` / null do not)."""
    return resume not in (None, False, "", "false", "False")


def find_resume_dir(resume, runs_root: str | Path, prefix: str) -> Path | None:
    """The run directory to resume: ``resume`` a path -> that directory; ``resume=True`` -> the newest
    ``<runs_root>/<prefix>*`` directory holding a checkpoint (:func:`run_checkpoint`: a seed batch's folder too);
    ``False`` / None -> None."""
    if not resume_requested(resume):
        return None
    if resume is True or str(resume).lower() == "true":
        candidates = [d for d in Path(runs_root).glob(f"{prefix}*") if run_checkpoint(d) is not None]
        if not candidates:
            raise FileNotFoundError(
                f"resume=true: no run directory {Path(runs_root) / (prefix + '*')} holds a "
                "checkpoint (pass resume=<run dir> to pick one)"
            )
        return max(candidates, key=lambda d: run_checkpoint(d).stat().st_mtime)
    path = Path(str(resume))
    if run_checkpoint(path) is None:
        raise FileNotFoundError(f"resume={resume}: {checkpoint_dir(path)} holds no checkpoint")
    return path


def find_sweep_dir(resume, prefix: str, stamp: str) -> Path:
    """The folder of a sweep (``-m``): ``resume=true`` -> the newest ``<prefix>*`` folder; ``resume=<dir>`` -> that
    folder; otherwise a new ``<prefix><stamp>``. Its jobs then resume or skip one by one (:mod:`kddrl_trl.train`)."""
    if not resume_requested(resume):
        return Path(f"{prefix}{stamp}")
    if resume is True or str(resume).lower() == "true":
        candidates = [d for d in Path(prefix).parent.glob(f"{Path(prefix).name}*") if d.is_dir()]
        if not candidates:
            raise FileNotFoundError(f"resume=true: no sweep folder {prefix}* to resume (pass resume=<sweep dir>)")
        return max(candidates, key=lambda d: d.stat().st_mtime)
    return Path(str(resume))


#: options that do not change what a run computes (a sweep may be resumed with other values)
NON_RESULT_KEYS = ("resume", "progress", "torch_threads", "gui")


def config_differences(saved: dict, current: dict, prefix: str = "") -> list[str]:
    """The dotted keys whose values differ between two configs (``NON_RESULT_KEYS`` ignored at the top; a key the
    saved config lacks is an option added since, whose default keeps what the run computed)."""
    out = []
    for key in sorted(set(saved) | set(current)):
        if (not prefix and key in NON_RESULT_KEYS) or key not in saved:
            continue
        a, b = saved.get(key, "<missing>"), current.get(key, "<missing>")
        if isinstance(a, dict) and isinstance(b, dict):
            out += config_differences(a, b, f"{prefix}{key}.")
        elif a != b:
            out.append(f"{prefix}{key}: {a!r} there, {b!r} now")
    return out


def trained_run(run) -> Path:
    """``run``, if it is a folder made by ``kddrl_trl.train`` (it holds ``config.yaml``), or the folder of a shipped
    policy (``shipped:<name>``, :mod:`kddrl_trl.policies`)."""
    from .policies import is_shipped, shipped_policy

    if is_shipped(run):
        return shipped_policy(run)
    if not RunFolder(str(run)).config.is_file():
        raise FileNotFoundError(f"run={run}: no config.yaml there (is it a directory made by kddrl_trl.train?)")
    return Path(str(run))


#: folders that did not exist when an entry point's output folder was chosen inside them, so Hydra makes them: a
#: refused command removes them again while they are empty (:func:`no_folder_if_refused`)
_MADE_FOR_OUTPUT: list[Path] = []


def output_parent(folder) -> Path:
    """``folder`` as the parent of an entry point's output folder, chosen before Hydra makes it. Its missing part is
    noted, so that a refusal (a ``run=`` that is not a training run, checked inside the entry point where it can end
    with one line) leaves none of the folders Hydra made for it."""
    path = Path(str(folder))
    missing = [p for p in (path, *path.parents) if not p.exists()]
    if missing:
        _MADE_FOR_OUTPUT.append(missing[-1].resolve())
    return path


def _hydra_only(folder: Path) -> bool:
    """Whether ``folder`` holds nothing but what Hydra writes before an entry point runs (``.hydra/``, ``*.log``,
    a sweep's ``multirun.yaml``)."""
    return folder.is_dir() and all(
        p.name in (".hydra", "multirun.yaml") or p.suffix == ".log" for p in folder.iterdir()
    )


def _close_log_files(folder: Path) -> None:
    """Close and detach the log file handlers writing into ``folder``, before it is removed."""
    root = logging.getLogger()
    for handler in list(root.handlers):
        if isinstance(handler, logging.FileHandler) and Path(handler.baseFilename).parent == folder.resolve():
            root.removeHandler(handler)
            handler.close()


def remove_refused_run_dir(run_dir: str | Path, sweep_dir: str | Path | None = None) -> bool:
    """Remove the folder Hydra made for a run whose config was then refused, so a bad value leaves no empty
    ``runs/<...>`` behind; returns whether it was removed. Only a folder holding nothing but Hydra's own files
    goes (a resumed run's folder, holding ``config.yaml`` and checkpoints, is kept); the log file handlers
    writing into it are closed first. ``sweep_dir``: a sweep's folder, removed too when this leaves it with only
    its ``multirun.yaml``."""
    run_dir = Path(run_dir)
    if not _hydra_only(run_dir):
        return False
    _close_log_files(run_dir)
    shutil.rmtree(run_dir, ignore_errors=True)
    top = run_dir
    if sweep_dir is not None and _hydra_only(Path(sweep_dir)):
        shutil.rmtree(sweep_dir, ignore_errors=True)
        top = Path(sweep_dir)
    _remove_empty_parents(top.parent)
    return True


def _remove_empty_parents(folder: Path) -> None:
    """The folders Hydra made above a removed run folder, while they are empty: up to the working directory (never
    it, nor anything outside it: ``runs/``), and the ones noted by :func:`output_parent` wherever they are."""
    here, folder = Path.cwd().resolve(), folder.resolve()
    made = [m for m in _MADE_FOR_OUTPUT if m == folder or m in folder.parents]
    top = min(made, key=lambda m: len(m.parts)) if made else None
    while (
        folder.is_dir()
        and not any(folder.iterdir())
        and (
            (folder != here and here in folder.parents)
            or (top is not None and (folder == top or top in folder.parents))
        )
    ):
        folder.rmdir()
        folder = folder.parent


@contextmanager
def no_folder_if_refused(outputs: bool = False):
    """Inside a Hydra entry point: an error raised in the block (a refused config) removes the output folder
    Hydra made for the run (:func:`remove_refused_run_dir`), then propagates. A refusal (``ValueError``: a bad value
    or an unknown key; ``FileNotFoundError``: a missing input; the message naming it) ends the command with that one
    line, without a traceback, unless ``HYDRA_FULL_ERROR=1``; outside a Hydra run (a test, a script) it propagates as
    it is. ``outputs=True``: the folder goes even when the block wrote into it (an evaluation's folder holds its
    results alone, and a failed evaluation has none worth keeping; a training run's folder is kept to resume)."""
    try:
        yield
    except BaseException as err:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        if not HydraConfig.initialized():
            raise
        hydra_cfg = HydraConfig.get()
        output_dir = Path(hydra_cfg.runtime.output_dir)
        if outputs and output_dir.is_dir():
            _close_log_files(output_dir)
            shutil.rmtree(output_dir, ignore_errors=True)
            _remove_empty_parents(output_dir.parent)
        remove_refused_run_dir(output_dir, hydra_cfg.sweep.dir if hydra_cfg.mode == RunMode.MULTIRUN else None)
        if isinstance(err, (ValueError, FileNotFoundError)) and os.environ.get("HYDRA_FULL_ERROR") != "1":
            raise SystemExit(f"error: {err}") from None
        raise
