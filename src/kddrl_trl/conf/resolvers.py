"""OmegaConf resolvers that choose a run's output folder before Hydra creates it.

Hydra makes ``hydra.run.dir`` before the entry point runs, so an entry point that only then learns the folder
is another one (a resumed run) or that its input does not exist (a missing run to evaluate) leaves an empty
folder behind. These resolvers decide while the config is composed, once (:mod:`kddrl_trl.run_folder` holds the rules):

* ``${kddrl_train_dir:${resume},runs,<prefix>,<stamp>}``: the run folder to resume (``resume=true``: the
  newest ``runs/<prefix>*`` with a checkpoint; ``resume=<dir>``: that one), else ``runs/<prefix><stamp>``;
* ``${kddrl_sweep_dir:${resume},<prefix>,<stamp>}``: the sweep folder to resume (``resume=true``: the newest
  ``<prefix>*``; ``resume=<dir>``: that one), else ``<prefix><stamp>``;
* ``${kddrl_trained_run:${run}}``: ``run`` itself, the parent of an evaluation's folder; whether it is a training
  run folder is checked inside the entry point (one line naming it), and the folders Hydra makes for a ``run`` that
  does not exist are then removed (:func:`kddrl_trl.run_folder.output_parent`);
* ``${kddrl_scenario:<name>,${env.simulator}}``: the ``env.scenario`` a ``+scenario=<name>`` preset sets
  (:func:`kddrl_trl.envs.config.scenario_label`: ``highwayenv_congested`` on HighwayEnv), so that the run folder
  already carries the simulator.
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import OmegaConf

from ..envs.config import scenario_label
from ..policies import output_folder
from ..run_folder import find_resume_dir, find_sweep_dir, output_parent


def train_dir(resume, runs_root: str, prefix: str, stamp: str) -> str:
    """Output folder of ``kddrl_trl.train``: the resumed run's folder, or a new ``<runs_root>/<prefix><stamp>``."""
    found = find_resume_dir(resume, runs_root, prefix)
    return str(found) if found is not None else str(Path(runs_root) / f"{prefix}{stamp}")


def register() -> None:
    """Register the resolvers (idempotent; cached so a config resolves them once)."""
    for name, fn in (
        ("kddrl_train_dir", train_dir),
        ("kddrl_trained_run", lambda run: str(output_parent(output_folder(run)))),
        ("kddrl_sweep_dir", lambda resume, prefix, stamp: str(find_sweep_dir(resume, prefix, stamp))),
        ("kddrl_scenario", scenario_label),
    ):
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, fn, use_cache=True)
