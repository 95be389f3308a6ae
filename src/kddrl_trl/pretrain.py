"""Pretrain trajGAN or lcGAN: ``python -m kddrl_trl.pretrain gan=trajgan|lcgan [key=value ...]``.

Wires parts together: the naturalistic dataset (built first if missing), the model's task
(:mod:`kddrl_trl.generative`), the generic loop (:func:`~kddrl_trl.generative.pretraining.run_pretraining`:
validation each epoch, early stopping, atomic checkpoints, resume) and the report. Runs on a GPU when
one is present (``device=auto``), else on the CPU.
"""
from __future__ import annotations

import hashlib
import json
import random
import shutil
from pathlib import Path

import hydra
import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from . import conf as _conf  # noqa: F401  (registers the typed env schema with Hydra)
from .data.extract import load_dataset
from .data.prepare import synthetic_dataset
from .generative import TASKS, format_metrics
from .generative.pretraining import PretrainConfig, run_pretraining
from .loggers import make_logger

#: which sample kind each model learns from (data/extract.py)
DATA_KIND = {"trajgan": "leaders", "lcgan": "lane_changes"}


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise SystemExit("device=cuda but no CUDA device is available (use device=auto or device=cpu)")
    return torch.device(name)


def dataset_hash(meta: dict, kind: str) -> str:
    """What the weights were trained on: the input recordings and the extraction parameters."""
    return hashlib.sha256(json.dumps([meta["input_hash"], meta["params"], kind], sort_keys=True).encode()).hexdigest()


@hydra.main(version_base="1.3", config_path="conf", config_name="pretrain")
def main(cfg: DictConfig) -> dict:
    kind = cfg.gan.kind
    if kind not in TASKS:
        raise SystemExit(f"gan.kind={kind!r}: known models are {', '.join(TASKS)}")
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    random.seed(cfg.seed)
    np.random.seed(cfg.seed)
    torch.manual_seed(cfg.seed)
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    device = resolve_device(cfg.device)
    data_dir = Path(cfg.data_dir)
    if (data_dir / "meta.json").is_file():
        meta = json.loads((data_dir / "meta.json").read_text())
    else:
        meta = synthetic_dataset(cfg.env, data_dir, cfg.recordings_dir, seed=int(cfg.seed), progress=bool(cfg.progress))
    splits = {s: load_dataset(data_dir, DATA_KIND[kind], s).to_tensordict().to(device)
              for s in ("train", "val", "test")}
    task = TASKS[kind](OmegaConf.to_container(cfg.gan.model, resolve=True), splits["train"], device=device)
    train = PretrainConfig(**OmegaConf.to_container(cfg.gan.train, resolve=True), seed=int(cfg.seed),
                           resume=bool(cfg.resume))
    metrics = run_pretraining(task, splits["train"], splits["val"], splits["test"], train, run_dir,
                              dataset_hash(meta, kind), config=OmegaConf.to_container(cfg, resolve=True),
                              progress=bool(cfg.progress), logger=make_logger(cfg.logger, run_dir))
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
