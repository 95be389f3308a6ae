"""Training checkpoints of a run directory: written atomically, the latest one found by ``resume``.

Layout: ``<run_dir>/checkpoints/ep<NNNNNN>.pt`` (one file: learner networks, targets, optimisers,
exploration schedules, counters, the training-episode history, the unfinished macro-transitions and — unless
``keep_buffers=false`` — the contents of both replay buffers) and ``<run_dir>/checkpoints/latest`` (the
file name of the newest complete checkpoint). A file is complete before ``latest`` names it, so a run killed
at any moment resumes from its last complete checkpoint. Older checkpoints are deleted after the pointer moves.
"""
from __future__ import annotations

from pathlib import Path

import torch

from ..io import torch_save_atomic, write_text_atomic

FORMAT = "kddrl_trl.training/1"


def checkpoint_dir(run_dir: str | Path) -> Path:
    return Path(run_dir) / "checkpoints"


def save_training_checkpoint(run_dir: str | Path, episodes: int, payload: dict, keep: int = 1) -> Path:
    """Write ``payload`` as the checkpoint after ``episodes`` training episodes; keep the newest ``keep``."""
    folder = checkpoint_dir(run_dir)
    path = torch_save_atomic(folder / f"ep{episodes:06d}.pt", {"format": FORMAT, **payload})
    write_text_atomic(folder / "latest", path.name + "\n")
    for old in sorted(folder.glob("ep*.pt"))[:-max(int(keep), 1)]:
        old.unlink(missing_ok=True)
    return path


def latest_checkpoint(run_dir: str | Path) -> Path | None:
    """The newest complete checkpoint of ``run_dir``, or None if it has none."""
    pointer = checkpoint_dir(run_dir) / "latest"
    if not pointer.is_file():
        return None
    path = checkpoint_dir(run_dir) / pointer.read_text().strip()
    if not path.is_file():
        raise FileNotFoundError(f"{pointer} names {path.name}, which does not exist")
    return path


def load_training_checkpoint(path: str | Path) -> dict:
    """Load a checkpoint written by :func:`save_training_checkpoint` (our own file: full unpickling)."""
    payload = torch.load(path, map_location="cpu", weights_only=False)
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"{path} is not a kddrl_trl training checkpoint (format {FORMAT!r})")
    return payload


def find_resume_dir(resume, runs_root: str | Path, prefix: str) -> Path | None:
    """The run directory to resume: ``resume`` a path -> that directory; ``resume=True`` -> the newest
    ``<runs_root>/<prefix>*`` directory holding a checkpoint; ``False`` / None -> None."""
    if resume in (None, False, "", "false", "False"):
        return None
    if resume is True or str(resume).lower() == "true":
        candidates = [d for d in Path(runs_root).glob(f"{prefix}*") if latest_checkpoint(d) is not None]
        if not candidates:
            raise FileNotFoundError(f"resume=true: no run directory {Path(runs_root) / (prefix + '*')} holds a "
                                    "checkpoint (pass resume=<run dir> to pick one)")
        return max(candidates, key=lambda d: latest_checkpoint(d).stat().st_mtime)
    path = Path(str(resume))
    if latest_checkpoint(path) is None:
        raise FileNotFoundError(f"resume={resume}: {checkpoint_dir(path)} holds no checkpoint")
    return path
