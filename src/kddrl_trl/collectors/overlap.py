"""``OverlappedCollector``: collection that runs while the learner updates (``collector.sync=false``).

With TorchRL's synchronous collectors the learner's updates and the collection take turns: a run's wall time is
their sum. Here the env runs in one worker process that collects the next batch while the learner updates on the
last one, so on a machine with a core free beside the learner a run takes about the larger of the two.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from torchrl.collectors import MultiAsyncCollector
from torchrl.envs import EnvBase

from .snapshot import PolicySnapshot


class OverlappedCollector(MultiAsyncCollector):
    """TorchRL's ``MultiAsyncCollector`` over **one** worker process, acting with a :class:`PolicySnapshot` of the
    learner's policy that is refreshed only while the worker waits between two batches.

    The worker's policy is the snapshot itself (TorchRL moves a CPU policy's tensors into shared memory when the
    worker starts, so the worker reads the snapshot's tensors). TorchRL's iterator (``update_at_each_batch``)
    calls :meth:`update_policy_weights_` when a batch arrives, before it tells the worker to go on; here that
    copies the learner's current weights and exploration state (ε, σ) into the snapshot. So, counting the yielded
    batches, batch ``i + 1`` is collected while the learner updates on batch ``i``, with the weights the learner
    had after its updates on batch ``i - 1``: one batch more lag than the synchronous collectors (there, batch
    ``i + 1`` acts with the weights after the updates on batch ``i``), and the same whatever the timing: a run
    repeats exactly.

    One worker only: with several, refreshing the shared snapshot when one worker's batch arrives would change
    the weights under the others while they collect, and the run would depend on timing.
    """

    def __init__(self, create_env_fn: Sequence[Callable[[], EnvBase]], snapshot: PolicySnapshot, **kwargs):
        if len(create_env_fn) != 1:
            raise ValueError(
                f"OverlappedCollector runs one worker process (collector.sync=false needs "
                f"collector.workers=1), got {len(create_env_fn)} env factories"
            )
        if not isinstance(snapshot, PolicySnapshot):
            raise TypeError(f"OverlappedCollector acts with a PolicySnapshot, got {type(snapshot).__name__}")
        self.snapshot = snapshot
        super().__init__(list(create_env_fn), policy=snapshot, update_at_each_batch=True, **kwargs)

    def update_policy_weights_(self, *args, **kwargs) -> None:
        """The snapshot takes the learner's current weights and exploration state, then TorchRL's own weight sync
        runs as it would for any policy (the worker's tensors are the snapshot's, so it moves nothing new; skipping
        it left TorchRL's weight-sync queues unstarted, and their clean-up at interpreter exit then hung). Called by
        TorchRL's iterator while the worker waits for its next batch (class docstring)."""
        self.snapshot.sync()
        super().update_policy_weights_(*args, **kwargs)
