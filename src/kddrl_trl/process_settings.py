"""What a job sets once in each of its processes: its seeds (:func:`seed_everything`) and its torch arithmetic
(:class:`TorchSettings`, the same in every process of the job).

torch keeps two of its arithmetic settings per process: the float32 matmul precision
(``torch.set_float32_matmul_precision``) and the CPU's flush-to-zero mode (``torch.set_flush_denormal``). A job sets
them in its own process (:func:`kddrl_trl.factories.make_job`, from the top-level keys ``matmul_precision`` and
``flush_denormal``) and carries them into each process it starts, which begins with torch's defaults: the
collection workers (:class:`~kddrl_trl.collectors.workers.WorkerEnv`, process or Ray backend) and the validation
worker (:class:`~kddrl_trl.eval.periodic.PeriodicEvaluator`). So every network of a job, wherever it acts or
learns, computes under one set of rules.
"""

from __future__ import annotations

import logging
import random
from dataclasses import dataclass

import numpy as np
import torch


def seed_everything(seed: int) -> None:
    """``random``, ``numpy`` and ``torch`` of this process from one seed (each env seeds its own traffic)."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


#: a float32 denormal: half the smallest normal float32
_DENORMAL = torch.finfo(torch.float32).tiny / 2


def apply_flush_denormal(on: bool) -> bool:
    """``torch.set_flush_denormal(on)``: flush-to-zero and denormals-are-zero for the CPU's float32 (and float64)
    arithmetic, the intra-op threads' too (tested). Adam's moments of a parameter whose gradient stays zero decay
    through the denormal range, where each vector operation costs many times a normal one; flushed, they are read
    and written as zero, below anything a parameter can show. Returns whether the mode is on: a CPU without it
    (neither x86 with SSE3 nor AArch64) keeps its denormals, with a warning, and the job runs on."""
    supported = torch.set_flush_denormal(bool(on))
    if on and not supported:
        logging.getLogger(__name__).warning("flush_denormal=true: this CPU has no flush-to-zero mode; denormals kept")
    return bool(on) and supported


@dataclass(frozen=True)
class TorchSettings:
    """A job's ``matmul_precision`` (``highest`` | ``high`` | ``medium``, checked by the job's schema) and
    ``flush_denormal``; picklable, to travel with a worker's env factory."""

    matmul_precision: str = "highest"
    flush_denormal: bool = True

    def apply(self) -> bool:
        """Sets both in this process; returns whether the flush-to-zero mode is on (:func:`apply_flush_denormal`)."""
        torch.set_float32_matmul_precision(self.matmul_precision)
        return apply_flush_denormal(self.flush_denormal)

    @classmethod
    def in_force(cls) -> TorchSettings:
        """The settings this process computes under: torch's matmul precision, and whether a denormal times one
        comes out as zero (on the calling thread)."""
        flushed = bool(torch.tensor(_DENORMAL, dtype=torch.float32) * 1.0 == 0)
        return cls(torch.get_float32_matmul_precision(), flushed)
