"""``PeriodicEvaluator``: greedy episodes of the policy being trained, on fixed validation traffic, run beside the
training.

libsumo runs one simulation per process and the training env holds this process's, so the validation runs in a
worker process of its own (spawned, never forked from a process that already runs SUMO), env and policy both. Each
validation takes a copy of the policy as it is when :meth:`PeriodicEvaluator.submit` is called (pickled there:
the learner may go on changing its weights at once), and returns a ``Future``, so that the training goes on while
the worker drives the episodes (:class:`~kddrl_trl.training.Trainer` collects the result later). Every validation
reseeds the env with the same seed (:func:`kddrl_trl.protocol.validation_seed`), so successive validations meet
the same traffic and compare, and it counts episodes in start order (:func:`~kddrl_trl.eval.rollout.evaluate_policy`).
TorchRL's own ``Evaluator`` (process backend) returns the first trajectories to *finish*, which with several roads
favours the short ones: hence this worker around :func:`~kddrl_trl.eval.rollout.evaluate_policy`.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Callable

import torch
from torchrl.data.utils import CloudpickleWrapper
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ..choices import BEST_METRICS
from ..main_guard import require_main_guard
from .metrics import summarize
from .rollout import evaluate_policy

#: the worker process's validation env (:func:`_start_worker`)
_ENV: EnvBase | None = None


def _start_worker(make_env: Callable[[], EnvBase]) -> None:
    """In the worker: the lowest priority and one torch thread (the policy acts on a few rows; the training keeps
    the cores), and the env, built once for all validations."""
    global _ENV
    os.nice(19)
    torch.set_num_threads(1)
    _ENV = make_env()


def _validate(policy: bytes, episodes: int, seed: int, groups: int | None = None) -> list[dict] | list[list[dict]]:
    """In the worker: the greedy episodes of the pickled ``policy`` (:func:`evaluate_policy`; ``groups``: a seed
    batch's, one list per seed)."""
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        return evaluate_policy(_ENV, pickle.loads(policy), episodes, seed, progress=False, groups=groups)


def _spawnable_start_method() -> None:
    """A spawned child re-applies its parent's default start method; inside a joblib (loky) worker that is
    ``"loky"``, which the child's ``multiprocessing`` does not know: make it ``"spawn"`` there."""
    if multiprocessing.get_start_method(allow_none=True) not in (None, "spawn", "fork", "forkserver"):
        multiprocessing.set_start_method("spawn", force=True)


class PeriodicEvaluator:
    """``episodes`` greedy episodes per validation on env seed ``seed``, in a worker process (started at the first
    validation) that builds its env with ``make_env()``. :meth:`submit` starts a validation and returns its
    ``Future``; :meth:`result` turns it into the per-episode records (:class:`~kddrl_trl.eval.EpisodeTracker`) and
    their :func:`~kddrl_trl.eval.summarize` summary with the ``best_metric`` score as ``"score"``; calling the
    evaluator does both, blocking.

    The worker runs beside the training at the lowest scheduling priority (``nice`` 19): on a machine whose cores
    the training fills, the validation takes what the training leaves idle, and the learner's threads do not wait
    for a core the worker holds (``python -m benchmarks.default_job`` measures the training time either way). The training
    process's torch threads are left as they are (TorchDynamo guards the thread count: a change mid-run would
    trace every compiled loss again)."""

    def __init__(
        self,
        make_env: Callable[[], EnvBase],
        episodes: int,
        seed: int,
        best_metric: str = "return",
        groups: int | None = None,
    ):
        """``groups=N``: a seed batch's validations (:class:`~kddrl_trl.eval.seed_validation.SeedBatchValidation`):
        ``make_env`` builds N x K roads, seed-major, each seed's on its own validation traffic; a validation drives
        a policy of N seeds and its result holds one list of episodes per seed (:meth:`result` ``index``)."""
        if best_metric not in BEST_METRICS:
            raise ValueError(f"train.best_metric={best_metric!r}: known metrics are {', '.join(BEST_METRICS)}")
        self.make_env, self.episodes, self.seed, self.groups = make_env, int(episodes), int(seed), groups
        self.score = BEST_METRICS[best_metric]
        require_main_guard("periodic validation (train.eval_every)")
        _spawnable_start_method()
        self.pool: ProcessPoolExecutor | None = None
        self.closed = False

    def submit(self, policy) -> Future:
        """Starts a validation of ``policy`` as it is now (a pickled copy); validations run one after the other, in
        order."""
        if self.closed:
            raise RuntimeError("PeriodicEvaluator: closed")
        payload = pickle.dumps(policy)
        if self.pool is None:
            context = multiprocessing.get_context("spawn")
            # the env factory travels by cloudpickle (a job's typed configs are classes made at run time)
            self.pool = ProcessPoolExecutor(
                1, mp_context=context, initializer=_start_worker, initargs=(CloudpickleWrapper(self.make_env),)
            )
        return self.pool.submit(_validate, payload, self.episodes, self.seed, self.groups)

    def result(self, future: Future, index: int | None = None) -> tuple[list[dict], dict]:
        """(episodes, summary) of a validation :meth:`submit` started (of seed ``index``, with ``groups``); waits
        for it."""
        try:
            episodes = future.result()
            if index is not None:
                episodes = episodes[index]
        except BrokenProcessPool as err:
            raise RuntimeError(
                "PeriodicEvaluator: the validation env's worker process ended before it answered; its own error "
                "is printed above"
            ) from err
        summary = summarize(episodes)
        summary["score"] = float(self.score(summary))
        return episodes, summary

    def __call__(self, policy) -> tuple[list[dict], dict]:
        return self.result(self.submit(policy))

    def close(self) -> None:
        """Stops the worker; a validation still pending is cancelled."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
        self.pool, self.closed = None, True
