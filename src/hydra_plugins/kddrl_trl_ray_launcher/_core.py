"""The jobs of a sweep as Ray tasks: one task per run, calling Hydra's ``run_job`` as Hydra's joblib launcher does.
A run holds its worker process (and that process's one libsumo) from start to end; a worker then takes the next
run, as Hydra's basic launcher runs one run after the other in one process, so a worker imports torch and
kddrl_trl once, not once per run. The runs write to ``hydra.sweep.dir`` as with any launcher, so resumed sweeps
and ``kddrl_trl.report`` read them unchanged."""

from __future__ import annotations

import logging
import os
import socket
from pathlib import Path
from typing import Any, Dict, Sequence

from hydra.core.hydra_config import HydraConfig
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, configure_log, filter_overrides, run_job, setup_globals
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict

log = logging.getLogger(__name__)


def execute_job(
    idx: int,
    overrides: Sequence[str],
    hydra_context: HydraContext,
    config: DictConfig,
    task_function: TaskFunction,
    singleton_state: Dict[Any, Any],
    cwd: str,
) -> JobReturn:
    """One job, inside its Ray worker: the driver's working folder (relative paths, ``hydra.sweep.dir`` among
    them, mean the same on every node: shared storage), Hydra's global state, the job's config, ``run_job``."""
    if not os.path.isdir(cwd):
        raise RuntimeError(
            f"hydra/launcher=ray: node {socket.gethostname()} lacks the driver's working folder {cwd}: "
            "the runs write to hydra.sweep.dir relative to it, so every node needs it (shared storage)"
        )
    os.chdir(cwd)
    setup_globals()
    Singleton.set_state(singleton_state)
    sweep_config = hydra_context.config_loader.load_sweep_config(config, list(overrides))
    with open_dict(sweep_config):
        sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{idx}"
        sweep_config.hydra.job.num = idx
    HydraConfig.instance().set_config(sweep_config)
    return run_job(
        hydra_context=hydra_context,
        config=sweep_config,
        task_function=task_function,
        job_dir_key="hydra.sweep.dir",
        job_subdir_key="hydra.sweep.subdir",
    )


def import_ray():
    """``ray``, or a clear error naming the extra that installs it."""
    try:
        import ray
    except ImportError as e:
        raise ImportError(
            "hydra/launcher=ray needs Ray, the optional extra of kddrl_trl: "
            "python -m pip install '.[ray]' (or: python -m pip install 'ray>=2.40,<3')"
        ) from e
    return ray


def init_kwargs(launcher) -> dict:
    """``ray.init``'s keyword arguments from the launcher's config; bad values refused naming the key."""
    for key in ("num_cpus", "num_gpus"):
        value = getattr(launcher, key)
        if (
            not isinstance(value, (int, float))
            or isinstance(value, bool)
            or value < 0
            or (key == "num_cpus" and value == 0)
        ):
            raise ValueError(
                f"hydra.launcher.{key}={value!r}: the {key[4:-1].upper()}s of each run, a number "
                f"{'> 0' if key == 'num_cpus' else '>= 0'}"
            )
    init = launcher.init
    init = OmegaConf.to_container(init, resolve=True) if isinstance(init, DictConfig) else dict(init)
    if "address" in init:
        raise ValueError(f"hydra.launcher.init.address={init['address']!r}: give the cluster as hydra.launcher.address")
    if launcher.address is not None:
        return {"address": launcher.address, **init}
    # a local Ray for this sweep: without Ray's dashboard (its processes take a share of a small machine's CPUs and
    # seconds of the start); hydra.launcher.init.include_dashboard=true brings it back
    return {"include_dashboard": False, **init}


def launch(launcher, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
    """Runs every job of ``job_overrides`` as a Ray task and returns their :class:`JobReturn` in order."""
    setup_globals()
    assert launcher.config is not None and launcher.task_function is not None and launcher.hydra_context is not None
    kwargs, ray = init_kwargs(launcher), import_ray()
    configure_log(launcher.config.hydra.hydra_logging, launcher.config.hydra.verbose)
    sweep_dir = Path(str(launcher.config.hydra.sweep.dir))
    sweep_dir.mkdir(parents=True, exist_ok=True)

    started_here = not ray.is_initialized()
    if started_here:
        try:
            ray.init(**kwargs)
        except TypeError as e:  # an unknown keyword of hydra.launcher.init
            raise ValueError(f"hydra.launcher.init={kwargs}: not arguments of ray.init ({e})") from e
    log.info(
        "Ray launcher (%s; %g CPUs and %g GPUs per run) is launching %d jobs, sweep output dir: %s",
        launcher.address or "local Ray",
        launcher.num_cpus,
        launcher.num_gpus,
        len(job_overrides),
        sweep_dir,
    )
    for idx, overrides in enumerate(job_overrides):
        log.info("\t#%d : %s", initial_job_idx + idx, " ".join(filter_overrides(overrides)))
    remote = ray.remote(num_cpus=launcher.num_cpus, num_gpus=launcher.num_gpus)(execute_job)  # (Ray's default
    # max_calls: CPU workers are reused, a GPU task's worker exits after it, handing its GPU memory back)
    shared = [
        ray.put(x) for x in (launcher.hydra_context, launcher.config, launcher.task_function, Singleton.get_state())
    ]
    context, config, task_function, singleton_state = shared
    tasks = [
        remote.remote(
            initial_job_idx + idx, list(overrides), context, config, task_function, singleton_state, os.getcwd()
        )
        for idx, overrides in enumerate(job_overrides)
    ]
    try:
        runs = ray.get(tasks)
    except BaseException:  # interrupted or failed: no run left behind on the cluster (resume=true continues them)
        for task in tasks:
            ray.cancel(task, force=True)
        raise
    finally:
        if started_here:
            ray.shutdown()
    assert all(isinstance(run, JobReturn) for run in runs)
    return runs
