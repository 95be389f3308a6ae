"""Generative predictors of KDDRL (paper §III.B-C): trajGAN and lcGAN, their training and inference.

One subpackage per model (``trajgan/``, ``lcgan/``: model / training task / figures / predictor), the
generic training loop (``pretraining.py``), checkpoints (``checkpoint.py``) and the base of both RL-time
predictors (``predictor.py``). No RL code and no ``kddrl_trl.data`` (pandas) is imported here. Default weights
ship with the package (:func:`default_checkpoint`), made by
``python -m kddrl_trl.pretrain gan=<kind> export=src/kddrl_trl/generative/weights/<kind>.pt``, with their test
metrics beside them (``weights/<kind>.metrics.json``, :mod:`.shipped`); the weights trained on HighwayEnv's
traffic lie in ``weights/highwayenv/`` (``python -m kddrl_trl.pretrain gan=<kind> env=highwayenv
export=src/kddrl_trl/generative/weights/highwayenv/<kind>.pt``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from ..choices import SHIPPED_TRAFFIC  # the shipped weights' traffic: our SUMO highway (weights/<kind>.pt,

# the default) and HighwayEnv's own (weights/highwayenv/<kind>.pt: 4 m lanes, HighwayEnv's drivers)
from .checkpoint import CheckpointError, load_checkpoint, read_checkpoint, save_checkpoint
from .lcgan import LCGANPredictor, LCGANTask
from .metrics_table import format_metrics
from .predictor import GANPredictor
from .trajgan import TrajGANPredictor, TrajGANTask

TASKS = {"trajgan": TrajGANTask, "lcgan": LCGANTask}
PREDICTORS = {"trajgan": TrajGANPredictor, "lcgan": LCGANPredictor}


def shipped_traffic(weights: str, simulator: str) -> str:
    """The traffic of the shipped weights a ``weights`` choice names (``algo.transforms.weights``): itself, or for
    ``auto`` the traffic of ``simulator`` where weights trained on it ship, else our SUMO traffic's."""
    if weights != "auto":
        return weights
    return simulator if simulator in SHIPPED_TRAFFIC else "sumo"


def default_checkpoint(kind: str, traffic: str = "sumo") -> Path:
    """Path of the weights shipped with the package for ``kind`` ("trajgan" / "lcgan"), trained on ``traffic``
    (one of :data:`SHIPPED_TRAFFIC`)."""
    if kind not in TASKS:
        raise ValueError(f"unknown generative model {kind!r}; known: {', '.join(TASKS)}")
    if traffic not in SHIPPED_TRAFFIC:
        raise ValueError(f"no shipped weights for traffic {traffic!r}; known: {', '.join(SHIPPED_TRAFFIC)}")
    folder = ("weights",) if traffic == "sumo" else ("weights", traffic)
    return Path(str(resources.files("kddrl_trl.generative").joinpath(*folder, f"{kind}.pt")))


def load_predictor(kind: str, path: str | Path | None = None, traffic: str = "sumo", **kwargs):
    """The batched inference module of ``kind`` from ``path`` (default: the weights shipped for ``traffic``)."""
    return PREDICTORS[kind].from_checkpoint(path or default_checkpoint(kind, traffic), **kwargs)


__all__ = [
    "CheckpointError",
    "GANPredictor",
    "LCGANPredictor",
    "LCGANTask",
    "PREDICTORS",
    "SHIPPED_TRAFFIC",
    "TASKS",
    "TrajGANPredictor",
    "TrajGANTask",
    "default_checkpoint",
    "format_metrics",
    "load_checkpoint",
    "load_predictor",
    "read_checkpoint",
    "save_checkpoint",
    "shipped_traffic",
]
