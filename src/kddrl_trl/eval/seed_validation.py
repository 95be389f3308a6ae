"""A seed batch's periodic validations: the N seeds' greedy policies driven at once, by one worker, on N x K roads
(seed ``i`` 's K roads on its own validation traffic, the traffic of its run alone), each seed's episodes counted on
its own rows (:func:`~kddrl_trl.eval.rollout.evaluate_policy` ``groups``).

Each seed's :class:`~kddrl_trl.training.Trainer` keeps its validations as a run alone keeps them (logged under
``eval/``, ``validation.csv``, ``checkpoints/best.pt``); what it sees as its evaluator is a :class:`SeedEvaluator`,
whose results are its seed's share of the batch's validation (:class:`SeedFuture`). A validation a resumed batch
finds under way in a seed's checkpoint is started again for that seed alone, on the weights it was given, by a
worker of the seed's own (as its run alone would start it again).
"""

from __future__ import annotations

from concurrent.futures import Future
from typing import Callable

from .periodic import PeriodicEvaluator


class SeedFuture:
    """Seed ``index`` 's share of a batched validation's ``future``."""

    def __init__(self, future: Future, index: int):
        self.future, self.index = future, int(index)

    def done(self) -> bool:
        return self.future.done()


class SeedBatchValidation:
    """The validations of a seed batch: ``shared`` (a :class:`PeriodicEvaluator` with ``groups=N``) drives the
    batch's greedy policy (:meth:`submit`); :meth:`evaluator` is seed ``i`` 's view of it. ``single(i)`` builds
    seed ``i`` 's own evaluator, for the validations a resumed batch starts again."""

    def __init__(self, shared: PeriodicEvaluator, single: Callable[[int], PeriodicEvaluator]):
        self.shared, self.single = shared, single
        self.views: dict[int, SeedEvaluator] = {}

    def submit(self, policy) -> Future:
        """A validation of the batch's greedy ``policy`` (all N seeds), as it is now."""
        return self.shared.submit(policy)

    def share(self, future: Future, i: int) -> SeedFuture:
        """Seed ``i`` 's share of the batched validation ``future`` (what its trainer keeps as under way)."""
        return SeedFuture(future, i)

    def evaluator(self, i: int) -> SeedEvaluator:
        return self.views.setdefault(i, SeedEvaluator(self, i))

    def close(self) -> None:
        """Stops the shared worker and every seed's own. Safe to call again."""
        self.shared.close()
        for view in self.views.values():
            view.close()


class SeedEvaluator:
    """Seed ``i`` 's evaluator in a seed batch (:class:`SeedBatchValidation`): the results of its share of the
    batch's validations, and its own worker for a validation of its policy alone (:meth:`submit`)."""

    def __init__(self, owner: SeedBatchValidation, i: int):
        self.owner, self.i = owner, int(i)
        self.own: PeriodicEvaluator | None = None

    def submit(self, policy) -> Future:
        """A validation of seed ``i`` 's ``policy`` alone, by a worker of its own (started at its first)."""
        if self.own is None:
            self.own = self.owner.single(self.i)
        return self.own.submit(policy)

    def result(self, future) -> tuple[list[dict], dict]:
        """(episodes, summary) of a validation: the seed's share of a batched one, or one of its own."""
        if isinstance(future, SeedFuture):
            return self.owner.shared.result(future.future, future.index)
        return self.own.result(future)

    def close(self) -> None:
        """Stops the seed's own worker (the shared one is its batch's to stop)."""
        if self.own is not None:
            self.own.close()
