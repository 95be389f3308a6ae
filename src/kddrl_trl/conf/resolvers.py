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
  (:func:`kddrl_trl.highway_config.scenario_label`: ``highwayenv_congested`` on HighwayEnv), so that the run folder
  already carries the simulator;
* ``${kddrl_seed_label:${seed},${seeds}}``: the seed part of a run folder's name: ``seed``, or for a seed batch
  (``seeds=[...]``) ``seeds<first>-<last>`` (:func:`seed_label`);
* ``${kddrl_seeds:<first>,<stop>}``: the seeds ``first .. stop - 1`` as a list, a range for ``seeds``
  (``seeds='${kddrl_seeds:200,210}'``: ten seeds).
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import OmegaConf

from ..highway_config import scenario_label
from ..policies import output_folder
from ..run_folder import find_resume_dir, find_sweep_dir, output_parent


def train_dir(resume, runs_root: str, prefix: str, stamp: str) -> str:
    """Output folder of ``kddrl_trl.train``: the resumed run's folder, or a new ``<runs_root>/<prefix><stamp>``."""
    found = find_resume_dir(resume, runs_root, prefix)
    return str(found) if found is not None else str(Path(runs_root) / f"{prefix}{stamp}")


def seed_label(seed, seeds) -> str:
    """``seed`` (a single run), or ``seeds<first>-<last>`` for the seed batch ``seeds`` (its seeds in order:
    ``seeds200-209``; seeds that do not run consecutively are all named, ``seeds3_7_9``)."""
    if seeds is None:
        return str(seed)
    seeds = [int(s) for s in seeds]
    if seeds == list(range(seeds[0], seeds[0] + len(seeds))) and len(seeds) > 1:
        return f"seeds{seeds[0]}-{seeds[-1]}"
    return "seeds" + "_".join(map(str, seeds))


def seed_range(first, stop) -> list[int]:
    """The seeds ``first`` to ``stop - 1`` (refused when empty)."""
    first, stop = int(first), int(stop)
    if stop <= first:
        raise ValueError(f"kddrl_seeds:{first},{stop}: no seeds (the range stops before it starts)")
    return list(range(first, stop))


def register() -> None:
    """Register the resolvers (idempotent; cached so a config resolves them once)."""
    for name, fn in (
        ("kddrl_train_dir", train_dir),
        ("kddrl_trained_run", lambda run: str(output_parent(output_folder(run)))),
        ("kddrl_sweep_dir", lambda resume, prefix, stamp: str(find_sweep_dir(resume, prefix, stamp))),
        ("kddrl_scenario", scenario_label),
        ("kddrl_seed_label", seed_label),
        ("kddrl_seeds", seed_range),
    ):
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, fn, use_cache=True)
