"""``MultiTimescaleCollector``: a TorchRL collector feeding two replay buffers on two clocks (docs/design.md
"Clocks"; paper Algorithm 1 lines 8-9, 25, 37), from one env in this process or from N worker processes."""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator, Sequence
from typing import NamedTuple

from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import ReplayBuffer
from torchrl.envs import EnvBase

from ..choices import check_backend
from ..main_guard import require_main_guard
from .macro import MacroTransitionWriter
from .overlap import OverlappedCollector
from .snapshot import PolicySnapshot

#: ``collector.backend`` values: TorchRL's local multi-process collector, or its Ray collector (the optional extra
#: ``.[ray]``)
#: ``total_frames`` of an endless Ray collection (TorchRL 0.14.1's ``RayCollector`` iterates while its collected
#: frames are below ``total_frames``, so its ``-1`` yields nothing)
ENDLESS_RAY_FRAMES = 2**62


class MultiTimescaleBatch(NamedTuple):
    frames: TensorDictBase  # [B, T] every frame (buffer L)
    macros: TensorDictBase | None  # [N] macro-transitions closed in this batch (buffer H), None if none
    #: a seed batch (``seeds``): each seed's macro-transitions (None where it closed none); ``macros`` is then None
    seed_macros: list | None = None


class MultiTimescaleCollector:
    """Wraps any TorchRL collector whose env carries a :class:`~kddrl_trl.transforms.DecisionClock` and whose
    policy acts on two clocks (:class:`~kddrl_trl.collectors.MultiRatePolicy`).

    Each iteration yields a :class:`MultiTimescaleBatch`: the frames ``[B, T]`` and the macro-transitions that
    closed in them (:class:`MacroTransitionWriter`); when given, ``frame_buffer`` (buffer L) receives every
    frame and ``macro_buffer`` (buffer H) every macro-transition, restricted to ``frame_keys`` /
    ``macro_keys`` when given (what the learner needs: keeps the buffers small).

    A multi-process collector's stacked batches ``[N, K, T]`` (N workers of K rows each, in worker order) are
    flattened to ``[N * K, T]``: row ``w * K + k`` is road ``k`` of worker ``w`` in every iteration, the stable
    row order the writer and the episode tracker need. Build it with :meth:`from_env` (one env in this process,
    or N env factories run by TorchRL's multi-process collector); :meth:`update_policy_weights_` hands the
    learner's current weights and exploration state to the acting policies.

    A seed batch (``seeds=N``, :mod:`kddrl_trl.modules.seed_batch`): the rows are N seeds' K roads, seed-major
    (rows ``i K`` to ``(i + 1) K - 1`` are seed ``i`` 's); ``frame_buffer`` and ``macro_buffer`` are then N buffers,
    seed ``i`` 's receiving only its rows' frames and the macro-transitions of its own writer (a copy of ``writer``
    per seed, fed its rows), so that each seed's buffers fill as a run of its own would fill them.
    """

    def __init__(
        self,
        collector,
        *,
        frame_buffer: ReplayBuffer | None = None,
        macro_buffer: ReplayBuffer | None = None,
        writer: MacroTransitionWriter | None = None,
        frame_keys: Sequence[NestedKey] | None = None,
        macro_keys: Sequence[NestedKey] | None = None,
        owns_envs: bool = False,
        local_env: EnvBase | None = None,
        frame_transform: Callable[[TensorDictBase], TensorDictBase] | None = None,
        policy=None,
        seeds: int | None = None,
    ):
        self.collector = collector
        self.frame_buffer, self.macro_buffer = frame_buffer, macro_buffer
        self.writer = writer if writer is not None else MacroTransitionWriter()
        self.seeds = None if seeds is None else int(seeds)
        if self.seeds is not None:
            for name, buffers in (("frame_buffer", frame_buffer), ("macro_buffer", macro_buffer)):
                if buffers is not None and len(buffers) != self.seeds:
                    raise ValueError(f"a batch of {self.seeds} seeds needs {self.seeds} buffers as {name}")
            self.writers = [copy.deepcopy(self.writer) for _ in range(self.seeds)]
            self.frame_transforms = [copy.deepcopy(frame_transform) for _ in range(self.seeds)]  # each its rows' window
        self.frame_keys = list(frame_keys) if frame_keys is not None else None
        self.macro_keys = list(macro_keys) if macro_keys is not None else self.frame_keys
        self.owns_envs = bool(owns_envs)
        #: an env built here from a factory (the single-process path), closed by :meth:`shutdown`: TorchRL's
        #: collector does not close a custom ``EnvBase`` (its ``is_closed`` is True until a batched env starts)
        self.local_env = local_env
        #: maps the frames ``[B, T]`` before they enter buffer L (e.g. :class:`~.nstep.NStepReturns`); the batch
        #: yielded, buffer H and the episode records keep the frames as collected
        self.frame_transform = frame_transform
        #: the acting policy given to :meth:`from_env`; one with a ``sync()`` (a CUDA learner's CPU copy) is
        #: refreshed by :meth:`update_policy_weights_`
        self.policy = policy

    @classmethod
    def from_env(
        cls,
        env: EnvBase | Sequence[Callable[[], EnvBase]],
        policy: Callable,
        *,
        frames_per_env: int,
        rows: int | None = None,
        backend: str = "process",
        sync: bool = True,
        **kwargs,
    ) -> MultiTimescaleCollector:
        """A TorchRL ``Collector`` collecting ``frames_per_env`` consecutive frames per env row per iteration
        (``[B, frames_per_env]``), endlessly, with ``policy`` (exploration on: TorchRL's default ``RANDOM``).

        ``env``: a batched env (built by the caller, who closes it), or a sequence of N env factories
        (picklable callables, e.g. :class:`~kddrl_trl.collectors.workers.WorkerEnv`), each building an env of
        ``rows`` rows; the collector builds these envs and closes them on :meth:`shutdown`. One factory with
        ``backend="process"`` is built and run in this process (the single-process path, the same as passing its
        env); otherwise ``Collector(factories, policy, backend=backend, num_collectors=N, sync=True)``: each env in
        its own worker process (``process``) or Ray actor (``ray``, :data:`BACKENDS`), every worker collecting
        its ``frames_per_env * rows`` frames per iteration, batches ``[N * rows, frames_per_env]``.

        ``sync=False`` (``collector.sync=false``): one factory, run by an :class:`~.overlap.OverlappedCollector` (a
        worker process that collects the next batch while the learner updates, acting with a
        :class:`~.snapshot.PolicySnapshot` of ``policy``; ``policy`` may already be one)."""
        from torchrl.collectors import Collector

        if int(frames_per_env) < 1:
            raise ValueError(f"frames_per_env must be >= 1, got {frames_per_env!r}")
        check_backend(backend)
        if isinstance(env, EnvBase):
            factories, rows, owns = [env], env.batch_size.numel(), False
        else:
            factories, owns = list(env), True
            if not factories or not all(callable(f) for f in factories):
                raise ValueError(f"env must be an EnvBase or a non-empty sequence of env factories, got {env!r}")
            if rows is None or int(rows) < 1:
                raise ValueError(f"rows (the batch size of each factory's env) must be >= 1, got {rows!r}")
        n = len(factories)
        if owns and backend == "process" and (n > 1 or not sync):  # worker processes, spawned
            require_main_guard(f"collector.workers={n}" if sync else "collector.sync=false")
        inner = {"auto_register_policy_transforms": False}  # the policy is ours: no transform registration
        if not sync:  # (the factory count: OverlappedCollector checks it)
            if backend != "process" or not owns:
                raise ValueError(
                    "collector.sync=false runs its env factory in a worker process (collector."
                    f"backend=process), got backend={backend!r} and "
                    f"{'an env built by the caller' if not owns else 'env factories'}"
                )
            snapshot = policy if isinstance(policy, PolicySnapshot) else PolicySnapshot(policy)
            collector = OverlappedCollector(
                factories,
                snapshot,
                frames_per_batch=int(frames_per_env) * int(rows),
                total_frames=-1,
                trust_policy=True,
                **inner,
            )
            return cls(collector, owns_envs=True, policy=snapshot, **kwargs)
        if n == 1 and backend == "process":
            options = inner
        elif backend == "process":
            options = {"backend": backend, "num_collectors": n, "sync": True, **inner}
        else:  # Ray: the actors' own collectors take the options of a single collector
            options = {"backend": backend, "num_collectors": n, "sync": True, "collector_kwargs": inner}
        # endless: -1, except for TorchRL 0.14's RayCollector, whose loop runs while collected < total_frames
        endless = ENDLESS_RAY_FRAMES if backend == "ray" else -1
        local = None
        if len(options) == 1 and owns:  # one factory, in this process: built here, closed by shutdown()
            local = factories[0] = factories[0]()
        collector = Collector(
            factories if len(options) > 1 else factories[0],
            policy,
            frames_per_batch=int(frames_per_env) * int(rows) * n,
            total_frames=endless,
            trust_policy=True,
            **options,
        )
        return cls(collector, owns_envs=owns, local_env=local, policy=policy, **kwargs)

    def __iter__(self) -> Iterator[MultiTimescaleBatch]:
        for frames in self.collector:
            if frames.batch_dims == 1:  # unbatched env: [T] -> [1, T]
                frames = frames.unsqueeze(0)
            elif frames.batch_dims == 3:  # N workers stacked: [N, K, T] -> [N * K, T], worker-major
                frames = frames.reshape(-1, frames.shape[-1])
            if self.seeds is not None:
                yield self._seed_batch(frames)
                continue
            macros = self._fill(frames, self.writer, self.frame_transform, self.frame_buffer, self.macro_buffer)
            yield MultiTimescaleBatch(frames, macros)

    def _fill(self, frames, writer, transform, frame_buffer, macro_buffer) -> TensorDictBase | None:
        """The macro-transitions ``writer`` closes in ``frames`` ``[B, T]``; the frames (through ``transform``) into
        ``frame_buffer`` and the macro-transitions into ``macro_buffer``, each restricted to its keys."""
        macros = writer(frames)
        if frame_buffer is not None:
            flat = (frames if transform is None else transform(frames)).reshape(-1)
            frame_buffer.extend(flat.select(*self.frame_keys) if self.frame_keys else flat)
        if macro_buffer is not None and macros is not None:
            macro_buffer.extend(macros.select(*self.macro_keys) if self.macro_keys else macros)
        return macros

    def _seed_batch(self, frames: TensorDictBase) -> MultiTimescaleBatch:
        """A seed batch's iteration: each seed's rows through its own writer and into its own buffers."""
        rows = frames.shape[0]
        if rows % self.seeds:
            raise ValueError(f"{rows} env rows do not split into {self.seeds} seeds' roads")
        k = rows // self.seeds
        per_seed = [
            self._fill(
                frames[i * k : (i + 1) * k],
                writer,
                transform,
                None if self.frame_buffer is None else self.frame_buffer[i],
                None if self.macro_buffer is None else self.macro_buffer[i],
            )
            for i, (writer, transform) in enumerate(zip(self.writers, self.frame_transforms))
        ]
        return MultiTimescaleBatch(frames, None, per_seed)

    def update_policy_weights_(self) -> None:
        """The acting policies take the policy's current weights and buffers (TorchRL's weight sync), the
        exploration state included (the ε of ε-greedy, the σ of the Gaussian acting noise: module buffers), so
        the workers explore on the learner's current schedule. In this process the policy is the learner's own
        modules. With the ``process`` backend and a CPU policy, TorchRL moves the policy's own tensors into shared
        memory when the workers start, so the workers already read the learner's tensors (``sync=True`` keeps them
        idle while the learner updates them) and this call only confirms it; where the weights are copies (Ray
        actors, a CUDA learner's CPU copy of its policy: its ``sync()`` first) this call is what sends them.
        An :class:`~.overlap.OverlappedCollector` refreshes its snapshot itself, between two batches of its
        worker: here, while that worker collects, nothing is done."""
        if isinstance(self.collector, OverlappedCollector):
            return
        sync = getattr(self.policy, "sync", None)
        if sync is not None:
            sync()
        self.collector.update_policy_weights_()

    def shutdown(self, close_env: bool = True) -> None:
        """Stops the collector. ``close_env=False`` leaves open an env the caller passed in; the envs the
        collector built from factories (in this process or in its workers) are closed with it."""
        from torchrl.collectors.distributed import RayCollector

        if isinstance(self.collector, RayCollector):  # its actors (and their envs) end with it
            self.collector.shutdown()
        else:
            self.collector.shutdown(close_env=close_env or self.owns_envs)
        if self.local_env is not None:
            self.local_env.close(raise_if_closed=False)
            self.local_env = None
