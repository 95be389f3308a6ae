"""``WorkerEnv``: the picklable env factory of one collection worker (docs/usage.md, "Worker processes").

``python -m kddrl_trl.train collector.workers=N`` runs N envs, each in its own process (its own SUMO through
libsumo, which allows one simulation per process, its own K roads and transform stack), through TorchRL's
multi-process collector (:meth:`~kddrl_trl.collectors.MultiTimescaleCollector.from_env`). Each worker gets one
``WorkerEnv``, pickled to the worker and called there: it seeds that process's torch generator (the exploring
policy's draws: ε-greedy coins, Gaussian acting noise), applies the job's torch settings there
(:class:`~kddrl_trl.process_settings.TorchSettings`: a new process starts with torch's defaults) and builds the env with the
worker's env seed (:func:`kddrl_trl.protocol.worker_seed`). Nothing here is specific to SUMO: ``make`` is any
env factory taking ``seed=``; the validation worker builds its env through one too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torchrl.envs import EnvBase

from ..process_settings import TorchSettings


@dataclass(frozen=True)
class WorkerEnv:
    """``make(seed=seed)``, after ``settings.apply()`` when given and ``torch.manual_seed(seed)`` when ``seed_torch``.

    ``seed_torch=False`` for an env built in the learner process itself (one worker, ``backend=process``: the
    single-process path), whose torch generator the entry point has already seeded; a worker process starts with
    torch's fixed default seed, so without seeding every worker would draw the same exploration noise.
    """

    make: Callable[..., EnvBase]
    seed: int
    seed_torch: bool = True
    settings: TorchSettings | None = None

    def __call__(self) -> EnvBase:
        if self.settings is not None:
            self.settings.apply()
        if self.seed_torch:
            torch.manual_seed(int(self.seed))
        return self.make(seed=int(self.seed))
