"""``python -m kddrl_trl.evaluate run=<training run dir> [+scenario=congested|braking] [eval_episodes=N]
[checkpoint=latest|best]``.

Loads the trained learner of a run (its ``config.yaml`` and latest or best checkpoint), evaluates it with exploration
off on the requested traffic with the same code as the final evaluation of ``kddrl_trl.train``
(:func:`kddrl_trl.factories.evaluate`), and writes ``summary.json`` and ``eval_episodes.csv`` into
``<run>/eval__<scenario>__<seed>__<time>/``. Wires the parts of :mod:`kddrl_trl.factories` only.
"""
from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from . import conf as _conf  # noqa: F401  (registers the typed schemas and the scenarios with Hydra)
from .conf.schema import EvaluateJob
from .eval.protocol import check_disjoint, test_seed
from .factories import (
    evaluate, load_trained_learner, make_env, make_job, make_logger, make_policy, report, seed_everything,
)


@hydra.main(version_base="1.3", config_path="conf", config_name="evaluate")
def main(cfg: DictConfig) -> dict:
    job: EvaluateJob = make_job(cfg)  # typed, ranges checked before any simulator starts; refused: no folder left
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    algo, learner, ckpt, saved = load_trained_learner(Path(job.run), job.checkpoint, job.torch_device)
    env_seed, trained_on = test_seed(job.seed, job.eval_seed), str(saved.env.scenario)
    check_disjoint("eval_seed", env_seed, int(saved.seed), int(saved.episodes))  # the run's own training traffic
    seed_everything(job.seed)
    env = make_env(job.env, algo, seed=env_seed, compile=job.compile)
    episodes, stats = evaluate(env, make_policy(algo, job.env, learner), job, make_logger(job.logger, out_dir),
                               out_dir, algo.name)
    return report(out_dir, episodes, f"{algo.name} trained on {trained_on}, evaluated on {job.env.scenario}, "
                  f"seed {job.seed}, exploration off ({ckpt.name})", scenario=job.env.scenario, algo=algo.name,
                  trained_on=trained_on, checkpoint=str(ckpt), seed=job.seed, eval_seed=env_seed, env_stats=stats,
                  flow_vph=job.env.flow)


if __name__ == "__main__":
    main()
