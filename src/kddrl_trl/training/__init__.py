"""Learning: the two agents and their updates (:class:`HierarchicalLearner`), the Algorithm 1 loop
(:class:`Trainer`), atomic checkpoints with resume, training curves."""
from .build import make_learner, make_training_env
from .checkpoint import find_resume_dir, latest_checkpoint, load_training_checkpoint, save_training_checkpoint
from .curves import plot_training_curves
from .learner import HierarchicalLearner
from .trainer import Trainer, make_buffer

__all__ = [
    "HierarchicalLearner",
    "Trainer",
    "find_resume_dir",
    "latest_checkpoint",
    "load_training_checkpoint",
    "make_buffer",
    "make_learner",
    "make_training_env",
    "plot_training_curves",
    "save_training_checkpoint",
]
