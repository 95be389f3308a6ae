"""Training checkpoints of a run directory: written atomically, the latest one found by ``resume``.

Layout (:mod:`kddrl_trl.runs`): ``<run_dir>/checkpoints/ep<NNNNNN>.pt`` (one file: learner networks, targets,
optimisers, exploration schedules, counters, the training-episode history and — unless ``keep_buffers=false``
— the contents of both replay buffers; not the unfinished macro-transitions: the environments restart on
resume, so intervals open at the checkpoint are dropped) and ``<run_dir>/checkpoints/latest`` (the file name of
the newest complete checkpoint). A file is complete before ``latest`` names it, so a run killed at any moment
resumes from its last complete checkpoint. Older checkpoints are deleted after the pointer moves.
``<run_dir>/checkpoints/best.pt``: the learner with the best validation score so far (periodic evaluation,
:class:`~kddrl_trl.training.Trainer`) and that evaluation's record.
"""
from __future__ import annotations

from pathlib import Path

import torch

from ..io import torch_save_atomic, write_text_atomic
from ..runs import checkpoint_dir

FORMAT = "kddrl_trl.training/1"


def save_training_checkpoint(run_dir: str | Path, episodes: int, payload: dict, keep: int = 1) -> Path:
    """Write ``payload`` as the checkpoint after ``episodes`` training episodes; keep the newest ``keep``."""
    folder = checkpoint_dir(run_dir)
    path = torch_save_atomic(folder / f"ep{episodes:06d}.pt", {"format": FORMAT, **payload})
    write_text_atomic(folder / "latest", path.name + "\n")
    for old in sorted(folder.glob("ep*.pt"))[:-max(int(keep), 1)]:
        old.unlink(missing_ok=True)
    return path


def save_best_checkpoint(run_dir: str | Path, payload: dict) -> Path:
    """Write ``payload`` (``learner`` state and its ``validation`` record) as ``checkpoints/best.pt``."""
    return torch_save_atomic(checkpoint_dir(run_dir) / "best.pt", {"format": FORMAT, **payload})


def load_training_checkpoint(path: str | Path) -> dict:
    """Load a checkpoint written by :func:`save_training_checkpoint` (our own file: full unpickling)."""
    payload = torch.load(path, map_location="cpu", weights_only=False)
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"{path} is not a kddrl_trl training checkpoint (format {FORMAT!r})")
    return payload
