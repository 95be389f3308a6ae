"""``PeriodicEvaluator``: validation episodes in a worker process, without touching the training process's torch
threads (a thread-count change mid-run re-traces every compiled graph: TorchDynamo guards it)."""
from __future__ import annotations

from functools import partial

import torch

from kddrl_trl.baselines.random_policy import RandomDrivingPolicy
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.eval.periodic import PeriodicEvaluator


def test_validation_keeps_the_training_process_threads():
    before = torch.get_num_threads()
    torch.set_num_threads(2)  # what a 2-core machine's training process has (TorchRL's default would make it 1)
    evaluator = PeriodicEvaluator(partial(FakeHighwayEnv, num_roads=2, seed=0), episodes=2, seed=5)
    try:
        episodes, summary = evaluator(RandomDrivingPolicy(generator=torch.Generator().manual_seed(0)))
        assert len(episodes) == 2 and "score" in summary
        assert torch.get_num_threads() == 2
    finally:
        evaluator.close()
        torch.set_num_threads(before)
