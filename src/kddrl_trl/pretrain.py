"""Pretrain trajGAN or lcGAN: ``python -m kddrl_trl.pretrain gan=trajgan|lcgan [key=value ...]``.

Wires parts together: the naturalistic dataset (built first if missing), the model's task
(:mod:`kddrl_trl.generative`), the generic loop (:func:`~kddrl_trl.generative.pretraining.run_pretraining`:
validation each epoch, early stopping, atomic checkpoints, resume) and the report. Runs on a GPU when
one is present (``device=auto``), else on the CPU.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from . import conf as _conf  # noqa: F401  (registers the typed schemas and the scenarios with Hydra)
from .factories import make_device, make_gan_data, make_logger, seed_everything
from .generative import TASKS, format_metrics
from .generative.pretraining import PretrainConfig, run_pretraining


@hydra.main(version_base="1.3", config_path="conf", config_name="pretrain")
def main(cfg: DictConfig) -> dict:
    kind = cfg.gan.kind
    if kind not in TASKS:
        raise SystemExit(f"gan.kind={kind!r}: known models are {', '.join(TASKS)}")
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    seed_everything(cfg.seed)
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    device = make_device(cfg.device)
    data_dir = Path(cfg.data_dir)
    splits, dataset_hash = make_gan_data(kind, data_dir, OmegaConf.to_object(cfg.env).highway(),
                                         Path(cfg.recordings_dir), int(cfg.seed), device, progress=bool(cfg.progress))
    task = TASKS[kind](OmegaConf.to_container(cfg.gan.model, resolve=True), splits["train"], device=device)
    train = PretrainConfig(**OmegaConf.to_container(cfg.gan.train, resolve=True), seed=int(cfg.seed),
                           resume=bool(cfg.resume))
    metrics = run_pretraining(task, splits["train"], splits["val"], splits["test"], train, run_dir, dataset_hash,
                              config=OmegaConf.to_container(cfg, resolve=True), progress=bool(cfg.progress),
                              logger=make_logger(cfg.logger, run_dir))
    print(f"\n{kind} on {data_dir} ({device}), best epoch {metrics['best_epoch']} of {metrics['epochs_run']}, "
          f"{metrics['train_seconds']:.0f} s training")
    print(format_metrics(kind, metrics))
    if cfg.export:
        Path(cfg.export).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run_dir / "best.pt", cfg.export)
        print(f"exported best weights to {cfg.export}")
    print(f"results in {run_dir}")
    return metrics


if __name__ == "__main__":
    main()
