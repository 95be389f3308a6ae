"""Generative predictors of KDDRL (paper §III.B-C): trajGAN and lcGAN, their training and inference.

One subpackage per model (``trajgan/``, ``lcgan/``: model / training task / figures / predictor), the
generic training loop (``pretraining.py``), checkpoints (``checkpoint.py``) and the base of both RL-time
predictors (``predictor.py``). No RL code and no ``kddrl_trl.data`` (pandas) is imported here. Default weights
ship with the package (:func:`default_checkpoint`), made by
``python -m kddrl_trl.pretrain gan=<kind> export=src/kddrl_trl/generative/weights/<kind>.pt``, with their test
metrics beside them (``weights/<kind>.metrics.json``, :mod:`.shipped`).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from .checkpoint import CheckpointError, load_checkpoint, read_checkpoint, save_checkpoint
from .gan_report import format_metrics
from .lcgan import LCGANPredictor, LCGANTask
from .predictor import GANPredictor
from .trajgan import TrajGANPredictor, TrajGANTask

TASKS = {"trajgan": TrajGANTask, "lcgan": LCGANTask}
PREDICTORS = {"trajgan": TrajGANPredictor, "lcgan": LCGANPredictor}


def default_checkpoint(kind: str) -> Path:
    """Path of the weights shipped with the package for ``kind`` ("trajgan" / "lcgan")."""
    if kind not in TASKS:
        raise ValueError(f"unknown generative model {kind!r}; known: {', '.join(TASKS)}")
    return Path(str(resources.files("kddrl_trl.generative").joinpath("weights", f"{kind}.pt")))


def load_predictor(kind: str, path: str | Path | None = None, **kwargs):
    """The batched inference module of ``kind`` from ``path`` (default: the shipped weights)."""
    return PREDICTORS[kind].from_checkpoint(path or default_checkpoint(kind), **kwargs)


__all__ = [
    "CheckpointError",
    "GANPredictor",
    "LCGANPredictor",
    "LCGANTask",
    "PREDICTORS",
    "TASKS",
    "TrajGANPredictor",
    "TrajGANTask",
    "default_checkpoint",
    "format_metrics",
    "load_checkpoint",
    "load_predictor",
    "read_checkpoint",
    "save_checkpoint",
]
