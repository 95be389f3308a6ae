"""``MultiTimescaleCollector``: a TorchRL collector feeding two replay buffers on two clocks (DESIGN.md
"Clocks"; paper Algorithm 1 lines 8-9, 25, 37)."""
from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import NamedTuple

from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import ReplayBuffer

from .macro import MacroTransitionWriter


class MultiTimescaleBatch(NamedTuple):
    frames: TensorDictBase           # [B, T] every frame (buffer L)
    macros: TensorDictBase | None    # [N] macro-transitions closed in this batch (buffer H), None if none


class MultiTimescaleCollector:
    """Wraps any TorchRL collector whose env carries a :class:`~kddrl_trl.collectors.DecisionClock` and whose
    policy acts on two clocks (:class:`~kddrl_trl.collectors.MultiRatePolicy`).

    Each iteration yields a :class:`MultiTimescaleBatch`: the frames ``[B, T]`` and the macro-transitions that
    closed in them (:class:`MacroTransitionWriter`); when given, ``frame_buffer`` (buffer L) receives every
    frame and ``macro_buffer`` (buffer H) every macro-transition, restricted to ``frame_keys`` /
    ``macro_keys`` when given (what the learner needs: keeps the buffers small).

    Use :meth:`from_env` for the single-process case (TorchRL ``Collector`` over a batched env), or build a
    ``MultiSyncCollector`` over several env factories yourself for more cores: its batches keep the same row
    order from one iteration to the next, which is all the writer needs.
    """

    def __init__(self, collector, *, frame_buffer: ReplayBuffer | None = None,
                 macro_buffer: ReplayBuffer | None = None, writer: MacroTransitionWriter | None = None,
                 frame_keys: Sequence[NestedKey] | None = None, macro_keys: Sequence[NestedKey] | None = None):
        self.collector = collector
        self.frame_buffer, self.macro_buffer = frame_buffer, macro_buffer
        self.writer = writer if writer is not None else MacroTransitionWriter()
        self.frame_keys = list(frame_keys) if frame_keys is not None else None
        self.macro_keys = list(macro_keys) if macro_keys is not None else self.frame_keys

    @classmethod
    def from_env(cls, env, policy: Callable, *, frames_per_env: int, **kwargs) -> MultiTimescaleCollector:
        """A TorchRL ``Collector`` over the batched ``env`` collecting ``frames_per_env`` consecutive frames per
        environment of the batch per iteration (``[B, frames_per_env]``), endlessly."""
        from torchrl.collectors import Collector

        if int(frames_per_env) < 1:
            raise ValueError(f"frames_per_env must be >= 1, got {frames_per_env!r}")
        collector = Collector(env, policy, frames_per_batch=int(frames_per_env) * env.batch_size.numel(),
                              total_frames=-1, trust_policy=True,
                              auto_register_policy_transforms=False)
        return cls(collector, **kwargs)

    def __iter__(self) -> Iterator[MultiTimescaleBatch]:
        for frames in self.collector:
            if frames.batch_dims == 1:  # unbatched env: [T] -> [1, T]
                frames = frames.unsqueeze(0)
            macros = self.writer(frames)
            if self.frame_buffer is not None:
                flat = frames.reshape(-1)
                self.frame_buffer.extend(flat.select(*self.frame_keys) if self.frame_keys else flat)
            if self.macro_buffer is not None and macros is not None:
                self.macro_buffer.extend(macros.select(*self.macro_keys) if self.macro_keys else macros)
            yield MultiTimescaleBatch(frames, macros)

    def shutdown(self, close_env: bool = True) -> None:
        self.collector.shutdown(close_env=close_env)
