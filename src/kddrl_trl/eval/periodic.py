"""``PeriodicEvaluator``: greedy episodes of the policy being trained, on fixed validation traffic.

libsumo runs one simulation per process and the training env holds this process's, so the validation env
lives in a worker process: a TorchRL ``ParallelEnv`` of one worker (spawned, never forked from a process
that already runs SUMO). ``ParallelEnv`` reads the env's specs from a transient instance made in this process,
so the evaluator is built before the training env starts (:func:`kddrl_trl.factories.make_evaluator`). The policy acts here, on the learner's current weights: nothing is copied. Every call
reseeds the env with the same seed (:func:`kddrl_trl.eval.protocol.validation_seed`), so successive
evaluations meet the same traffic and compare.
"""

from __future__ import annotations

from typing import Callable

import torch
from torchrl.envs import EnvBase, ParallelEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ..spawning import require_main_guard
from .metrics import summarize
from .rollout import evaluate_policy

#: the validation score a ``best`` checkpoint maximises: name -> (score of a summary, higher is better)
BEST_METRICS = {
    "return": lambda s: s["return_lc"] + s["return_cf"],  # both agents' undiscounted returns (Eq. 26 + Eq. 32)
    "mean_speed_kmh": lambda s: s["mean_speed_kmh"],
    "collision_rate": lambda s: -s["collision_rate"],
}


def _spawnable_start_method() -> None:
    """A spawned child re-applies its parent's default start method; inside a joblib (loky) worker that is
    ``"loky"``, which the child's ``multiprocessing`` does not know: make it ``"spawn"`` there."""
    import multiprocessing

    if multiprocessing.get_start_method(allow_none=True) not in (None, "spawn", "fork", "forkserver"):
        multiprocessing.set_start_method("spawn", force=True)


class PeriodicEvaluator:
    """``episodes`` greedy episodes per call on env seed ``seed``; the env (``make_env()``, run in a worker
    process) is set up here, before any other simulation of this process starts. Each call returns the per-episode records (:class:`~kddrl_trl.eval.EpisodeTracker`)
    and their :func:`~kddrl_trl.eval.summarize` summary with the ``best_metric`` score as ``"score"``."""

    def __init__(self, make_env: Callable[[], EnvBase], episodes: int, seed: int, best_metric: str = "return"):
        if best_metric not in BEST_METRICS:
            raise ValueError(f"train.best_metric={best_metric!r}: known metrics are {', '.join(BEST_METRICS)}")
        self.make_env, self.episodes, self.seed = make_env, int(episodes), int(seed)
        self.score = BEST_METRICS[best_metric]
        require_main_guard("periodic validation (train.eval_every)")
        _spawnable_start_method()
        # worker starts on use; ``num_threads``: this process keeps its torch threads. Left to TorchRL, starting the
        # worker sets them to (threads - 1) here, mid-run: the learner would lose a thread at the first validation,
        # and every compiled loss would be traced again (TorchDynamo guards the thread count)
        self.env: ParallelEnv | None = ParallelEnv(
            1, make_env, mp_start_method="spawn", num_threads=torch.get_num_threads()
        )

    def __call__(self, policy) -> tuple[list[dict], dict]:
        if self.env is None:
            raise RuntimeError("PeriodicEvaluator: closed")
        threads = torch.get_num_threads()
        starting = self.env.is_closed  # TorchRL starts the worker on its first use: this call
        try:
            with set_exploration_type(ExplorationType.DETERMINISTIC):
                episodes = evaluate_policy(self.env, policy, self.episodes, self.seed, progress=False)
        except EOFError as err:  # TorchRL reads the worker's pipe: a dead worker surfaces as a bare EOFError
            if not starting:  # it ran before: its own error above says why it ended
                raise
            raise RuntimeError(
                "PeriodicEvaluator: the validation env's worker process ended before it answered; its own error "
                "is printed above"
            ) from err
        finally:
            # the worker's start (first call) sets this process's threads to the count read at construction; by
            # then a collector may have lowered them (TorchRL's multi-process collectors leave a core per worker:
            # collector.workers > 1, collector.sync=false), and the learner would compete with its workers
            torch.set_num_threads(threads)
        summary = summarize(episodes)
        summary["score"] = float(self.score(summary))
        return episodes, summary

    def close(self) -> None:
        if self.env is not None and not self.env.is_closed:
            self.env.close()
        self.env = None
