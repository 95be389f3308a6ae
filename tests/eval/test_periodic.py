"""``PeriodicEvaluator``: validation episodes in a worker process, without touching the training process's torch
threads (a thread-count change mid-run re-traces every compiled graph: TorchDynamo guards it). That a validation is
of the policy as it was when it started, beside the training: ``tests/training/test_validation.py``."""

from __future__ import annotations

import os
from functools import partial

import torch
from testkit import run_script

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


def test_validation_keeps_threads_a_collector_lowered_after_the_evaluator_was_built():
    """A multi-process collector (``collector.workers`` > 1, ``collector.sync=false``) lowers the training process's
    threads when its workers start, after the evaluator was built and before the evaluator's own worker starts (at
    the first validation): that start must not raise them back (the learner would compete with the workers)."""
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    evaluator = PeriodicEvaluator(partial(FakeHighwayEnv, num_roads=2, seed=0), episodes=2, seed=5)
    try:
        torch.set_num_threads(1)  # as TorchRL's collector does when its one worker starts
        evaluator(RandomDrivingPolicy(generator=torch.Generator().manual_seed(0)))
        assert torch.get_num_threads() == 1
    finally:
        evaluator.close()
        torch.set_num_threads(before)


def test_an_unguarded_script_is_refused_before_the_worker_starts(tmp_path):
    """A script that validates at import time, with no ``__main__`` guard: the spawned worker would import it again
    and die while starting. The evaluator names the script's line before it starts the worker."""
    done = run_script(
        tmp_path,
        """
        from functools import partial
        from kddrl_trl.envs import FakeHighwayEnv
        from kddrl_trl.eval.periodic import PeriodicEvaluator

        evaluator = PeriodicEvaluator(partial(FakeHighwayEnv, num_roads=1, seed=0), episodes=1, seed=5)
        """,
    )
    assert done.returncode != 0
    assert "script.py, line 6: periodic validation (train.eval_every) spawns worker processes" in done.stderr


def test_a_worker_that_dies_while_starting_is_named(tmp_path):
    """A worker whose env cannot be built dies before it answers: the training process says so (the worker's own
    error is printed above it) instead of raising TorchRL's bare ``EOFError``."""
    done = run_script(
        tmp_path,
        """
        import multiprocessing
        import torch
        from kddrl_trl.baselines.random_policy import RandomDrivingPolicy
        from kddrl_trl.envs import FakeHighwayEnv
        from kddrl_trl.eval.periodic import PeriodicEvaluator

        def make_env():
            if multiprocessing.parent_process() is not None:  # in the worker
                raise SystemExit("no env in the worker")
            return FakeHighwayEnv(num_roads=1, seed=0)

        if __name__ == "__main__":
            evaluator = PeriodicEvaluator(make_env, episodes=1, seed=5)
            evaluator(RandomDrivingPolicy(generator=torch.Generator().manual_seed(0)))
        """,
    )
    assert done.returncode != 0
    assert "the validation env's worker process ended before it answered" in done.stderr, done.stderr[-3000:]


def test_the_worker_runs_at_the_lowest_priority():
    """The validation runs beside the training: its worker yields the cores to the training's threads."""
    evaluator = PeriodicEvaluator(partial(FakeHighwayEnv, num_roads=1, seed=0), episodes=1, seed=5)
    try:
        evaluator(RandomDrivingPolicy(generator=torch.Generator().manual_seed(0)))
        assert evaluator.pool.submit(os.nice, 0).result(timeout=60) == 19
    finally:
        evaluator.close()
