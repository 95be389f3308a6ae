"""Evaluation: per-episode metrics from collected frames, running a policy for a number of episodes, and the
driving metrics of paper Tables II-V."""

from ..envs.episode_metrics import EpisodeTracker
from .metrics import summarize
from .rollout import evaluate_policy, unwrap_env

__all__ = ["EpisodeTracker", "evaluate_policy", "summarize", "unwrap_env"]
