"""How many torch threads a job's process computes with (the top-level key ``torch_threads``).

torch starts with one intra-op thread per core. Beside other busy processes that is one thread too many: torch's
OpenMP threads wait for each other at every parallel region, and a thread the scheduler has parked stalls the
others, so a job beside another slows several times while the same job on one thread barely notices. The job's
networks are small (hidden 128, batches of 128), where a second thread buys little even alone.

``torch_threads``:

* an integer: that many threads, always;
* ``auto`` (the default): ``OMP_NUM_THREADS`` where it is set (the user's own choice), else the cores this process
  may use (``os.sched_getaffinity``) less the work already running on them, at least one. That work is read from the
  kernel's count of runnable threads (``/proc/loadavg``, sampled for a moment, this process's own threads not
  counted; the 1-minute load average elsewhere) plus the job's own busy worker processes. It is read again while the
  job trains (:class:`ThreadGovernor`, every :data:`RECHECK_S` seconds), so that a job started alone gives back its
  second thread when another starts beside it, and takes it again when that one ends.

The thread count does not change a run's numbers: the records of a run are byte-identical at one and two threads
(``tests/test_threads.py``), so the choice is free to follow the machine. When the machine's work exceeds its cores,
one warning says so, with the fix.
"""

from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

log = logging.getLogger(__name__)

#: seconds between two readings of the machine while a job trains
RECHECK_S = 10.0
#: samples of the run queue per reading, and the pause between them (seconds)
SAMPLES, SAMPLE_PAUSE_S = 5, 0.02


def cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _own_running() -> int:
    """This process's threads the kernel has running or runnable now (``/proc/self/task/*/stat``, state R)."""
    running = 0
    for stat in Path("/proc/self/task").glob("*/stat"):
        try:
            text = stat.read_text()
        except OSError:  # a thread that ended while we looked
            continue
        running += text[text.rfind(")") + 2 : text.rfind(")") + 3] == "R"
    return running


def busy_elsewhere() -> float:
    """The runnable threads of other processes on this machine: the mean over :data:`SAMPLES` readings of the
    kernel's run queue (``/proc/loadavg``'s fourth field) less this process's own; the 1-minute load average where
    there is no ``/proc``."""
    loadavg = Path("/proc/loadavg")
    if not loadavg.exists():
        return float(os.getloadavg()[0]) if hasattr(os, "getloadavg") else 0.0
    readings = []
    for i in range(SAMPLES):
        running = int(loadavg.read_text().split()[3].split("/")[0])
        readings.append(max(0, running - _own_running()))
        if i < SAMPLES - 1:
            time.sleep(SAMPLE_PAUSE_S)
    return sum(readings) / len(readings)


def _others(elsewhere: float) -> int:
    """Whole busy cores from a mean of run-queue readings: a thread runnable in most samples holds a core."""
    return max(0, math.ceil(elsewhere - 0.25))


@dataclass(frozen=True)
class ThreadChoice:
    """A job's torch threads and why: ``setting`` (``auto`` or the integer asked for), ``threads`` chosen,
    ``cores`` available, ``elsewhere`` (runnable threads of other processes when chosen), ``workers`` (the job's own
    busy worker processes), ``reason``."""

    setting: str
    threads: int
    cores: int
    elsewhere: float
    workers: int
    reason: str

    @property
    def busy(self) -> bool:
        """The machine's work, this job's one thread at least included, exceeds its cores (the readings rounded as
        :func:`choose_threads` rounds them)."""
        return _others(self.elsewhere) + self.workers + 1 > self.cores

    def record(self) -> dict:
        return asdict(self)


def choose_threads(setting, workers: int = 0) -> ThreadChoice:
    """The thread count for ``setting`` (``"auto"`` or a positive integer); ``workers``: the job's own worker
    processes that compute while the learner does (each takes a core)."""
    n = cores()
    if str(setting) != "auto":
        threads = int(setting)
        if threads < 1:
            raise ValueError(f"torch_threads must be auto or a positive integer, got {setting!r}")
        return ThreadChoice(str(setting), threads, n, 0.0, workers, "torch_threads")
    env = os.environ.get("OMP_NUM_THREADS", "").strip()
    if env:
        if not env.isdigit() or int(env) < 1:
            raise ValueError(f"OMP_NUM_THREADS={env!r}: torch_threads=auto needs a positive integer there")
        return ThreadChoice("auto", int(env), n, 0.0, workers, "OMP_NUM_THREADS")
    elsewhere = busy_elsewhere()
    threads = max(1, min(n, n - _others(elsewhere) - workers))
    return ThreadChoice("auto", threads, n, elsewhere, workers, "free cores")


def apply_threads(choice: ThreadChoice) -> None:
    if torch.get_num_threads() != choice.threads:
        torch.set_num_threads(choice.threads)


class ThreadGovernor:
    """Keeps a job's torch threads at :func:`choose_threads` while it runs: :meth:`tick` (called once per collected
    batch) reads the machine again every :data:`RECHECK_S` seconds under ``auto``; a fixed setting, or
    ``OMP_NUM_THREADS``, is applied once. The first busy reading logs one warning with the fix. ``choice`` is the
    latest; ``changes`` counts how often the count moved (each change logged at debug level: a job beside a
    periodic validation worker changes it at every validation, and summary.json keeps the count)."""

    def __init__(self, setting, workers: int = 0, clock=time.monotonic):
        self.setting, self.workers, self.clock = setting, workers, clock
        self.changes, self.warned = 0, False
        self.choice = choose_threads(setting, workers)
        apply_threads(self.choice)
        self._last = clock()
        log.info(
            "torch_threads=%s: %d thread(s) (%s; %d cores, %.1f runnable elsewhere)",
            self.choice.setting,
            self.choice.threads,
            self.choice.reason,
            self.choice.cores,
            self.choice.elsewhere,
        )
        self._warn_if_busy()

    @property
    def adaptive(self) -> bool:
        return self.choice.reason == "free cores"

    def tick(self) -> None:
        if not self.adaptive or self.clock() - self._last < RECHECK_S:
            return
        self._last = self.clock()
        choice = choose_threads(self.setting, self.workers)
        if choice.threads != self.choice.threads:
            self.changes += 1
            log.debug("torch_threads=auto: %d -> %d thread(s) (%.1f runnable elsewhere)", self.choice.threads,
                     choice.threads, choice.elsewhere)  # fmt: skip
        self.choice = choice
        apply_threads(choice)
        self._warn_if_busy()

    def _warn_if_busy(self) -> None:
        if self.warned or not self.choice.busy:
            return
        self.warned = True
        log.warning(
            "this machine is busy: %.1f threads of other processes are runnable on its %d cores; this job computes "
            "on %d torch thread(s) and will run slower than alone (torch_threads=auto follows the load; "
            "torch_threads=N or OMP_NUM_THREADS=N fixes the count)",
            self.choice.elsewhere,
            self.choice.cores,
            self.choice.threads,
        )

    def record(self) -> dict:
        """What ``summary.json`` keeps: the latest choice and how often the count changed."""
        return self.choice.record() | {"changes": self.changes}
