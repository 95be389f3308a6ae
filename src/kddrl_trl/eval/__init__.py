"""Evaluation: running a policy for a number of episodes and the driving metrics of paper Tables II-V."""
from .metrics import summarize
from .rollout import run_episodes

__all__ = ["run_episodes", "summarize"]
