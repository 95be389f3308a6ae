"""Learning: the two agents and their updates (:class:`HierarchicalLearner`), the Algorithm 1 loop
(:class:`Trainer`), atomic checkpoints with resume, training curves. Built from the config by
:mod:`kddrl_trl.factories`."""
from .checkpoint import (
    CheckpointError, load_latest_training_checkpoint, load_training_checkpoint, save_training_checkpoint,
)
from .curves import plot_training_curves
from .learner import HierarchicalLearner
from .trainer import Trainer, make_buffer

__all__ = [
    "CheckpointError",
    "HierarchicalLearner",
    "Trainer",
    "load_latest_training_checkpoint",
    "load_training_checkpoint",
    "make_buffer",
    "plot_training_curves",
    "save_training_checkpoint",
]
