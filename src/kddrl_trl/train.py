"""Main entry point: ``python -m kddrl_trl.train [+scenario=congested|braking] [algo=...] [key=value ...]``.

Wires parts together and holds no algorithm. Today it runs the rule-based ``algo=idm_mobil`` for
``episodes`` episodes and writes their metrics; the learning systems plug in here (DESIGN.md).
Outputs go to ``runs/<scenario>__<algo>__<seed>__<time>/``: ``episodes.csv``, ``summary.json``, CSV logs.
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
from .envs.factory import make_env
from .eval.metrics import PAPER_IDM_MOBIL, format_summary, summarize
from .eval.rollout import run_episodes
from .io import write_json_atomic, write_text_atomic
from .loggers import make_logger

log = logging.getLogger(__name__)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> dict:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    if cfg.algo.name not in RULE_BASED:
        raise SystemExit(f"algo={cfg.algo.name}: only the rule-based algos ({', '.join(RULE_BASED)}) run so far")
    seed_everything(cfg.seed)
    env = make_env(cfg.env, seed=cfg.seed)
    policy = make_rule_policy(cfg.algo, num_lanes=env.config.num_lanes, lane_width=env.config.lane_width)
    logger = make_logger(cfg.logger, run_dir)
    write_text_atomic(run_dir / "config.yaml", OmegaConf.to_yaml(cfg, resolve=True))

    def on_episode(ep: dict) -> None:
        for key in ("mean_speed_kmh", "mean_accel", "mean_abs_accel", "lane_changes", "frames", "return_lc", "return_cf"):
            logger.log_scalar(f"eval/{key}", ep[key], step=ep["index"])
        logger.log_scalar("eval/collision", float(ep["collision"]), step=ep["index"])

    try:
        episodes = run_episodes(env, policy, cfg.episodes, progress=cfg.progress, on_episode=on_episode)
        stats = dict(env.stats)
    finally:
        env.close()
    summary = summarize(episodes)
    summary.update(scenario=cfg.env.scenario, algo=cfg.algo.name, seed=cfg.seed, env_stats=stats,
                   flow_vph=env.config.flow, run_dir=str(run_dir))
    write_text_atomic(run_dir / "episodes.csv", pd.DataFrame(episodes).to_csv(index=False))
    write_json_atomic(run_dir / "summary.json", summary)
    reference = PAPER_IDM_MOBIL if cfg.algo.name == "idm_mobil" and cfg.env.scenario == "baseline" else None
    print(f"\n{cfg.algo.name} on {cfg.env.scenario} ({env.config.flow:.0f} veh/h), seed {cfg.seed}:")
    print(format_summary(summary, reference))
    print(f"results in {run_dir}")
    return summary


if __name__ == "__main__":
    main()
