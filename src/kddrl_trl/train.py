"""Main entry point: ``python -m kddrl_trl.train [+scenario=congested|braking] [algo=...] [key=value ...]``.

Wires parts together and holds no algorithm:

- learning algos (``algo.kind: hierarchical``: ``kddrl`` by default, ``d3qn_td3``, ``d3qn_td3_lg``,
  ``kddrl_same_clock``, ``ni``): train for ``episodes`` episodes (:class:`~kddrl_trl.training.Trainer`,
  checkpoints every ``train.checkpoint_every`` episodes, ``resume=true`` continues), then evaluate
  ``eval_episodes`` episodes with exploration off on a fresh env;
- rule-based algos (``algo=idm_mobil``): evaluate ``eval_episodes`` episodes.

Outputs go to ``runs/<scenario>__<algo>__<seed>__<time>/``: ``config.yaml``, ``train_episodes.csv``,
``training_curves.png``, ``checkpoints/``, ``eval_episodes.csv``, ``summary.json``, TorchRL CSV logs.
"""
from __future__ import annotations

import logging
import random
from pathlib import Path

import hydra
import numpy as np
import pandas as pd
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from . import conf as _conf  # noqa: F401  (registers the typed env schema with Hydra)
from .baselines.factory import RULE_BASED, make_rule_policy
from .envs.factory import highway_config, make_env
from .eval.metrics import PAPER_IDM_MOBIL, format_summary, summarize
from .eval.rollout import run_episodes, unwrap_env
from .io import write_json_atomic, write_text_atomic
from .loggers import make_logger, trim_logs

log = logging.getLogger(__name__)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def evaluate(env, policy, cfg: DictConfig, logger) -> tuple[list[dict], dict]:
    """``eval_episodes`` episodes of ``policy`` (counted in start order), logged under ``eval/``; closes env."""
    def on_episode(ep: dict) -> None:
        for key in ("mean_speed_kmh", "mean_accel", "mean_abs_accel", "lane_changes", "frames", "return_lc", "return_cf"):
            logger.log_scalar(f"eval/{key}", ep[key], step=ep["index"])
        logger.log_scalar("eval/collision", float(ep["collision"]), step=ep["index"])

    try:
        episodes = run_episodes(env, policy, cfg.eval_episodes, progress=cfg.progress, on_episode=on_episode)
        stats = dict(unwrap_env(env).stats)
    finally:
        env.close()
    return episodes, stats


def train_learner(cfg: DictConfig, run_dir: Path, logger, resume: bool) -> tuple[list[dict], object, dict]:
    """Trains the learner of ``cfg.algo`` (continuing ``run_dir``'s latest checkpoint when ``resume``); returns
    the training history, the learner and the trainer's counters."""
    from .training import Trainer, make_learner, make_training_env, plot_training_curves

    learner = make_learner(cfg.algo)
    train_cfg = {**OmegaConf.to_container(cfg.train, resolve=True), "episodes": cfg.episodes}
    trainer = Trainer(learner, train_cfg, run_dir, logger, seed=cfg.seed, progress=cfg.progress)
    done = trainer.load(run_dir) if resume else 0
    if done:
        trim_logs(run_dir, last_step=done - 1)
    # a resumed run meets new traffic: the env's streams start from seed + episodes already done
    env = make_training_env(cfg.env, cfg.algo, seed=cfg.seed + done)
    try:
        history = trainer.run(env)
    finally:
        env.close()
    write_text_atomic(run_dir / "train_episodes.csv", pd.DataFrame(history).to_csv(index=False))
    plot_training_curves(history, run_dir / "training_curves.png",
                         title=f"{cfg.algo.name} on {cfg.env.scenario}, seed {cfg.seed}")
    return history, learner, trainer.counters


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> dict:
    from .training import find_resume_dir, make_training_env

    run_dir = Path(HydraConfig.get().runtime.output_dir)
    kind = cfg.algo.get("kind", "rule" if cfg.algo.name in RULE_BASED else "hierarchical")
    # hydra.run.dir already is the folder to resume (conf/resolvers.py); found again here by the same rule
    resume_dir = find_resume_dir(cfg.resume, run_dir.parent, f"{cfg.env.scenario}__{cfg.algo.name}__{cfg.seed}__")
    if resume_dir is not None:
        log.info("resuming %s", resume_dir)
        run_dir = resume_dir
    seed_everything(cfg.seed)
    logger = make_logger(cfg.logger, run_dir)
    if resume_dir is None:
        write_text_atomic(run_dir / "config.yaml", OmegaConf.to_yaml(cfg, resolve=True))

    summary_extra: dict = {}
    if kind == "rule":
        env = make_env(cfg.env, seed=cfg.seed)
        policy = make_rule_policy(cfg.algo, num_lanes=env.config.num_lanes, lane_width=env.config.lane_width)
    elif kind == "hierarchical":
        history, learner, counters = train_learner(cfg, run_dir, logger, resume=resume_dir is not None)
        tail = history[-100:]
        summary_extra["training"] = {**counters, "episodes": len(history),
                                     "last100": {k: float(np.mean([h[k] for h in tail]))
                                                 for k in ("return_lc", "return_cf", "mean_speed_kmh", "collision")}}
        env = make_training_env(cfg.env, cfg.algo, seed=cfg.seed)
        policy = learner.policy(explore=False)
        policy.eval()
    else:
        raise SystemExit(f"algo={cfg.algo.name}: unknown kind {kind!r} (rule | hierarchical)")

    episodes, stats = evaluate(env, policy, cfg, logger)
    summary = summarize(episodes)
    summary.update(scenario=cfg.env.scenario, algo=cfg.algo.name, seed=cfg.seed, env_stats=stats,
                   flow_vph=highway_config(cfg.env).flow, run_dir=str(run_dir), **summary_extra)
    write_text_atomic(run_dir / "eval_episodes.csv", pd.DataFrame(episodes).to_csv(index=False))
    write_json_atomic(run_dir / "summary.json", summary)
    reference = PAPER_IDM_MOBIL if cfg.algo.name == "idm_mobil" and cfg.env.scenario == "baseline" else None
    print(f"\n{cfg.algo.name} on {cfg.env.scenario}, seed {cfg.seed}: evaluation, exploration off")
    print(format_summary(summary, reference))
    print(f"results in {run_dir}")
    return summary


if __name__ == "__main__":
    main()
