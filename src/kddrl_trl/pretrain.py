"""Pretrain trajGAN or lcGAN: ``python -m kddrl_trl.pretrain gan=trajgan|lcgan [key=value ...]``.

``export=PATH`` copies the best weights to PATH and writes their test metrics beside them
(``PATH`` -> ``<stem>.metrics.json``, :mod:`kddrl_trl.generative.shipped`); ``evaluate=PATH`` trains nothing and
(re)writes that metrics file for the weights at PATH (they must have been trained on this dataset).

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
from .data.gan_datasets import dataset_description, gan_dataset
from .factories import make_device, make_logger
from .generative import TASKS, format_metrics
from .generative.pretraining import PretrainConfig, run_pretraining
from .generative.shipped import evaluate_checkpoint, write_shipped_metrics
from .process_settings import seed_everything


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
    splits, dataset_hash = gan_dataset(
        kind,
        data_dir,
        OmegaConf.to_object(cfg.env),
        Path(cfg.recordings_dir),
        int(cfg.seed),
        device,
        progress=bool(cfg.progress),
    )
    task = TASKS[kind](OmegaConf.to_container(cfg.gan.model, resolve=True), splits["train"], device=device)
    command = " ".join(["python -m kddrl_trl.pretrain", *HydraConfig.get().overrides.task])
    dataset = {
        "data_dir": str(data_dir),
        "recordings_dir": str(cfg.recordings_dir),
        "seed": int(cfg.seed),
        **dataset_description(data_dir),
    }
    if cfg.evaluate:
        metrics = evaluate_checkpoint(task, cfg.evaluate, splits["test"], run_dir, dataset_hash)
        print(format_metrics(kind, metrics))
        print(
            f"metrics of {cfg.evaluate} written to {write_shipped_metrics(cfg.evaluate, metrics, command, dataset, trained=False)}"
        )
        return metrics
    train = PretrainConfig(
        **OmegaConf.to_container(cfg.gan.train, resolve=True), seed=int(cfg.seed), resume=bool(cfg.resume)
    )
    metrics = run_pretraining(
        task,
        splits["train"],
        splits["val"],
        splits["test"],
        train,
        run_dir,
        dataset_hash,
        config=OmegaConf.to_container(cfg, resolve=True),
        progress=bool(cfg.progress),
        logger=make_logger(cfg.logger, run_dir),
    )
    print(
        f"\n{kind} on {data_dir} ({device}), best epoch {metrics['best_epoch']} of {metrics['epochs_run']}, "
        f"{metrics['train_seconds']:.0f} s training"
    )
    print(format_metrics(kind, metrics))
    if cfg.export:
        Path(cfg.export).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run_dir / "best.pt", cfg.export)
        print(
            f"exported best weights to {cfg.export} and their test metrics to "
            f"{write_shipped_metrics(cfg.export, metrics, command, dataset)}"
        )
    print(f"results in {run_dir}")
    return metrics


if __name__ == "__main__":
    main()
