"""``Learner``: what :class:`~kddrl_trl.training.Trainer`, the collector factory and the evaluation need from a
learning algo, whatever its agents. Three learners implement it:

=========================================  ==========================================  ===========================
learner                                    algos                                       buffers it learns from
=========================================  ==========================================  ===========================
:class:`~.learner.HierarchicalLearner`     kddrl, ablations, ni, peng                  L (frames) and H (decisions)
:class:`~.joint_d3qn.JointD3QNLearner`     d3qn_unified                                L (frames)
:class:`~.pasac.PASACLearner`              pasac_unified                               L (frames)
=========================================  ==========================================  ===========================

A learner acts through :meth:`Learner.policy` (a TensorDict module writing ``keys.LC_ACTION`` and
``keys.CF_ACTION``, the env's action keys), names the keys its updates read (:meth:`Learner.buffer_keys`), makes
one gradient step per call of :meth:`Learner.update_frame` (a buffer-L sample, once per collected frame) and,
when :attr:`Learner.learns_from_decisions`, of :meth:`Learner.update_decision` (a buffer-H sample of
macro-transitions, once per lane-change decision), and saves everything in one dict
(:meth:`Learner.full_state_dict`).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torch import nn

from .. import keys as K
from ..compiling import resolve_compile

#: keys a learner reads from a replay-buffer sample besides those of its own state (root and "next")
STATE_KEYS = (K.EGO_STATE, K.NEIGHBORS_REL, K.NEIGHBORS_MASK, K.EGO_ACCEL, K.LC_ACTION_MASK)
DONE_KEYS = ("done", "terminated", "truncated")


def adam(params, lr: float) -> torch.optim.Adam:
    """Adam with the fused kernel (one call per step for all tensors; on a CPU PyTorch's default is a
    per-tensor loop)."""
    params = [p for p in params if p.requires_grad]
    return torch.optim.Adam(params, lr=lr, fused=True)


def transition_keys(obs: Sequence[NestedKey], actions: Sequence[NestedKey]) -> list:
    """Keys of a stored transition: ``obs`` and ``actions`` at the root, ``obs``, both agents' rewards and the
    done flags under ``"next"``."""
    obs = list(dict.fromkeys(obs))
    rewards = [("next", K.LC_REWARD), ("next", K.CF_REWARD)] + [("next", k) for k in DONE_KEYS]
    return [*obs, *actions, *[("next", *(k if isinstance(k, tuple) else (k,))) for k in obs], *rewards]


class Learner(nn.Module):
    """Base of the learners (module docstring). Subclasses register their networks, losses and exploration
    modules as submodules (so that ``state_dict()`` holds them) and implement the methods that raise here."""

    #: whether :meth:`update_decision` learns from buffer H (the lane-change agent's macro-transitions)
    learns_from_decisions: bool = False

    def _compile(self, compile: bool | str) -> None:
        """The learner's one compile site: ``torch.compile`` of :meth:`loss` (fixed minibatch shapes, one graph
        per loss name); optimiser steps stay eager. ``"auto"``: when a C++ compiler is found."""
        self.compiled = resolve_compile(compile)
        self._loss = torch.compile(self.loss, dynamic=False) if self.compiled else self.loss

    # ------------------------------------------------------------------------------- to implement
    def policy(self, explore: bool = True):
        """The acting policy (exploration modules act only under ``ExplorationType.RANDOM``)."""
        raise NotImplementedError

    def buffer_keys(self) -> list:
        """Keys a replay-buffer entry must keep for the updates (root and under ``"next"``)."""
        raise NotImplementedError

    def loss(self, name: str, batch: TensorDictBase) -> torch.Tensor:
        """The loss ``name`` of a replay-buffer sample: tensor maths only, what ``compile`` compiles."""
        raise NotImplementedError

    def update_frame(self, batch: TensorDictBase) -> dict[str, float]:
        """One gradient step on a buffer-L sample (frames); returns the losses."""
        raise NotImplementedError

    def update_decision(self, batch: TensorDictBase) -> dict[str, float]:
        """One gradient step on a buffer-H sample (macro-transitions); returns the losses."""
        raise NotImplementedError(f"{type(self).__name__} learns from buffer L only")

    def explore_step(self, decisions: int, frames: int) -> None:
        """Advances the exploration schedules by the decisions and frames just collected."""

    def exploration(self) -> dict[str, float]:
        """Exploration scalars logged under ``train/`` per training episode (ε, temperatures, ...)."""
        return {}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        raise NotImplementedError

    # -------------------------------------------------------------------------------- shared parts
    def _descend(self, loss: torch.Tensor, *optimizers: torch.optim.Optimizer | None) -> None:
        """Zero the optimisers' gradients, back-propagate ``loss``, step them (None entries skipped)."""
        opts = [o for o in optimizers if o is not None]
        for o in opts:
            o.zero_grad(set_to_none=True)
        loss.backward()
        for o in opts:
            o.step()

    def full_state_dict(self) -> dict:
        """Networks, targets, exploration schedules, counters and optimiser states."""
        return {"modules": self.state_dict(), "optimizers": {k: o.state_dict() for k, o in self.optimizers().items()}}

    def load_full_state_dict(self, state: Mapping) -> None:
        self.load_state_dict(state["modules"])
        for name, opt in self.optimizers().items():
            opt.load_state_dict(state["optimizers"][name])
