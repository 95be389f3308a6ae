"""Builders that turn the Hydra ``env`` / ``algo`` nodes into the training env and the learner."""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from omegaconf import OmegaConf
from torchrl.envs import Compose, TransformedEnv

from ..collectors import DecisionClock
from ..envs.factory import make_env
from .learner import HierarchicalLearner


def _plain(node) -> dict:
    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else dict(node)


def make_training_env(env_cfg: Mapping[str, Any], algo_cfg: Mapping[str, Any], seed: int, fake: bool = False):
    """The batched highway env + the algo's predictive-state transforms + its :class:`DecisionClock`."""
    from ..transforms import make_kddrl_transforms

    base = make_env(env_cfg, seed=seed, fake=fake)
    stack = []
    t = _plain(algo_cfg.get("transforms", {}) or {})
    if t.pop("enabled", True):
        stack.append(make_kddrl_transforms(**t, seed=seed, num_lanes=base.config.num_lanes))
    stack.append(DecisionClock(int(algo_cfg["lc_period"])))
    return TransformedEnv(base, Compose(*stack))


def make_learner(algo_cfg: Mapping[str, Any]) -> HierarchicalLearner:
    """A :class:`HierarchicalLearner` from the ``algo.learner`` node."""
    return HierarchicalLearner(**_plain(algo_cfg["learner"]))
