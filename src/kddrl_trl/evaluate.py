"""``python -m kddrl_trl.evaluate run=<training run dir> [+scenario=congested|braking] [eval_episodes=N]``.

Loads the trained learner of a run (its ``config.yaml`` and latest checkpoint), evaluates it with exploration
off on the requested traffic with the same code as the final evaluation of ``kddrl_trl.train``, and writes
``summary.json`` and ``eval_episodes.csv`` into ``<run>/eval__<scenario>__<seed>__<time>/``. Wires parts only.
"""
from __future__ import annotations

from pathlib import Path

import hydra
import pandas as pd
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from . import conf as _conf  # noqa: F401  (registers the typed env schema with Hydra)
from .conf.resolvers import trained_run
from .envs.factory import highway_config
from .eval.metrics import format_summary, summarize
from .io import write_json_atomic, write_text_atomic
from .loggers import make_logger


def load_trained_learner(run: Path):
    """(training config, learner with the latest checkpoint's weights) of a training run directory."""
    from .training import latest_checkpoint, load_training_checkpoint, make_learner

    train_cfg = OmegaConf.load(Path(trained_run(run)) / "config.yaml")
    kind = train_cfg.algo.get("kind", "rule")
    if kind != "hierarchical":
        raise ValueError(f"run={run} is algo={train_cfg.algo.name} ({kind}): nothing was trained; evaluate it with "
                         f"python -m kddrl_trl.train algo={train_cfg.algo.name} +scenario=...")
    path = latest_checkpoint(run)
    if path is None:
        raise FileNotFoundError(f"run={run}: no checkpoint in {run / 'checkpoints'}")
    train_cfg.algo.learner.compile = False  # acting only: nothing to gain from compiling the updates
    learner = make_learner(train_cfg.algo)
    learner.load_full_state_dict(load_training_checkpoint(path)["learner"])
    return train_cfg, learner, path


@hydra.main(version_base="1.3", config_path="conf", config_name="evaluate")
def main(cfg: DictConfig) -> dict:
    from .train import evaluate, seed_everything
    from .training import make_training_env

    out_dir = Path(HydraConfig.get().runtime.output_dir)
    run = Path(cfg.run)
    train_cfg, learner, ckpt = load_trained_learner(run)
    seed_everything(cfg.seed)
    env = make_training_env(cfg.env, train_cfg.algo, seed=cfg.seed)
    policy = learner.policy(explore=False)
    policy.eval()
    episodes, stats = evaluate(env, policy, cfg, make_logger(cfg.logger, out_dir))
    summary = summarize(episodes)
    summary.update(scenario=cfg.env.scenario, algo=train_cfg.algo.name, trained_on=train_cfg.env.scenario,
                   checkpoint=str(ckpt), seed=cfg.seed, env_stats=stats, flow_vph=highway_config(cfg.env).flow)
    write_text_atomic(out_dir / "eval_episodes.csv", pd.DataFrame(episodes).to_csv(index=False))
    write_json_atomic(out_dir / "summary.json", summary)
    print(f"\n{train_cfg.algo.name} trained on {train_cfg.env.scenario}, evaluated on {cfg.env.scenario}, "
          f"seed {cfg.seed}, exploration off ({ckpt.name})")
    print(format_summary(summary))
    print(f"results in {out_dir}")
    return summary


if __name__ == "__main__":
    main()
