"""The Hydra :class:`~hydra.plugins.launcher.Launcher` of ``hydra/launcher=ray`` (the work is in :mod:`._core`)."""

from __future__ import annotations

from typing import Optional, Sequence

from hydra.core.utils import JobReturn
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


class RayLauncher(Launcher):
    """Launches each job of a sweep as one Ray task (``num_cpus`` / ``num_gpus`` per run) on a local Ray or the
    cluster at ``address``; ``init`` holds further ``ray.init`` keyword arguments."""

    def __init__(
        self, address: Optional[str] = None, num_cpus: float = 1, num_gpus: float = 0, init: Optional[dict] = None
    ) -> None:
        self.address, self.num_cpus, self.num_gpus = address, num_cpus, num_gpus
        self.init = dict(init or {})
        self.config: Optional[DictConfig] = None
        self.task_function: Optional[TaskFunction] = None
        self.hydra_context: Optional[HydraContext] = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        from . import _core

        _core.import_ray()  # refused before the sweeper makes the sweep folder: Ray missing or a bad value
        _core.init_kwargs(self)
        self.config, self.task_function, self.hydra_context = config, task_function, hydra_context

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        from . import _core

        return _core.launch(self, job_overrides, initial_job_idx)
