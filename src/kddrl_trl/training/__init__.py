"""Learning: the learners (:class:`Learner`: :class:`HierarchicalLearner` of KDDRL and the hierarchical comparison
systems, :class:`JointD3QNLearner` and :class:`PASACLearner` of the unified ones), the Algorithm 1 loop
(:class:`Trainer`), atomic checkpoints with resume, training curves. Built from the config by
:mod:`kddrl_trl.factories`."""

from .checkpoint import (
    CheckpointError,
    load_latest_training_checkpoint,
    load_policy,
    load_training_checkpoint,
    save_policy,
    save_training_checkpoint,
)
from .curves import plot_training_curves
from .hierarchical import HierarchicalLearner
from .joint_d3qn import JointD3QNLearner
from .learner import Learner
from .pasac import PASACLearner
from .trainer import Trainer, make_buffer

__all__ = [
    "CheckpointError",
    "HierarchicalLearner",
    "JointD3QNLearner",
    "Learner",
    "PASACLearner",
    "Trainer",
    "load_latest_training_checkpoint",
    "load_policy",
    "load_training_checkpoint",
    "make_buffer",
    "plot_training_curves",
    "save_policy",
    "save_training_checkpoint",
]
