"""The generic offline training loop of the generative models (paper Algorithm 1, lines 2-3).

A model plugs in as a :class:`GANTask`; :func:`run_pretraining` owns everything around it: seeded
mini-batches, epochs with a progress bar, validation after each epoch, early stopping on the validation
loss, atomic checkpoints (``last.pt`` every epoch, ``best.pt`` on improvement) that a killed run resumes
from, and the final evaluation on the test split with the best weights.
"""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Protocol

import torch
from tensordict import TensorDict
from torch import nn
from tqdm.auto import tqdm

from ..atomic_files import write_json_atomic
from .checkpoint import load_checkpoint, save_checkpoint

log = logging.getLogger(__name__)


class GANTask(Protocol):
    """What a generative model provides to the training loop."""

    kind: str  # "trajgan" / "lcgan"

    def architecture(self) -> dict:
        """Everything a checkpoint must match to be loaded into this model (sizes, feature layout)."""

    def modules(self) -> dict[str, nn.Module]:
        """Trainable modules saved in checkpoints (e.g. generator, discriminator)."""

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """Their optimisers (saved in ``last.pt`` for resuming)."""

    def state(self) -> dict:
        """Extra state to checkpoint (e.g. normalisation statistics), tensors/numbers/strings only."""

    def load_state(self, state: Mapping[str, Any]) -> None:
        """Inverse of :meth:`state`."""

    def train_batch(self, batch: TensorDict) -> dict[str, float]:
        """One optimisation step on a mini-batch; returns the losses to log."""

    def validation_loss(self, data: TensorDict) -> float:
        """Lower is better; drives early stopping and ``best.pt``."""

    def evaluate(self, test: TensorDict, out_dir: Path) -> dict:
        """Metrics (and PNG figures written into ``out_dir``) on the test split."""


@dataclass
class PretrainConfig:
    epochs: int = 30
    batch_size: int = 512
    patience: int = 5  # epochs without validation improvement before stopping
    max_train_samples: int = 0  # 0 = all; otherwise a seeded subset per epoch (keeps CPU runs short)
    seed: int = 0
    resume: bool = True


def _batches(n: int, batch_size: int, generator: torch.Generator, limit: int = 0):
    order = torch.randperm(n, generator=generator)
    if limit and limit < n:
        order = order[:limit]
    return order.split(batch_size)


def run_pretraining(
    task: GANTask,
    train: TensorDict,
    val: TensorDict,
    test: TensorDict,
    cfg: PretrainConfig,
    run_dir: str | Path,
    dataset_hash: str,
    config: Mapping[str, Any] | None = None,
    progress: bool = True,
    logger=None,
) -> dict:
    """Train ``task`` with early stopping; evaluate the best weights on ``test``; return the metrics.

    Writes into ``run_dir``: ``last.pt`` (every epoch, with optimisers: resume point), ``best.pt`` (best
    validation loss), ``history.json`` and ``metrics.json`` (plus the task's figures).
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    last, best = run_dir / "last.pt", run_dir / "best.pt"
    gen = torch.Generator().manual_seed(cfg.seed)
    start, best_loss, stale, history = 0, math.inf, 0, []
    if cfg.resume and last.is_file():
        payload = load_checkpoint(
            last, kind=task.kind, architecture=task.architecture(), modules=task.modules(), dataset_hash=dataset_hash
        )
        st = payload["state"]
        for name, opt in task.optimizers().items():
            opt.load_state_dict(st["optimizers"][name])
        task.load_state(st["task"])
        gen.set_state(st["generator"])
        start, best_loss, stale, history = st["epoch"], st["best_loss"], st["stale"], json.loads(st["history"])
        log.info("resumed from %s at epoch %d", last, start)
    epochs = range(start, cfg.epochs)
    bar = tqdm(
        epochs, desc=f"pretrain {task.kind}", unit="epoch", disable=not progress, initial=start, total=cfg.epochs
    )
    for epoch in bar:
        if stale >= cfg.patience:
            break
        t0 = time.perf_counter()
        sums: dict[str, float] = {}
        batches = _batches(train.batch_size[0], cfg.batch_size, gen, cfg.max_train_samples)
        for idx in batches:
            for k, v in task.train_batch(train[idx]).items():
                sums[k] = sums.get(k, 0.0) + float(v)
        losses = {k: v / max(len(batches), 1) for k, v in sums.items()}
        val_loss = float(task.validation_loss(val))
        if not math.isfinite(val_loss):
            raise FloatingPointError(f"{task.kind}: validation loss is {val_loss} at epoch {epoch + 1}")
        improved = val_loss < best_loss
        best_loss, stale = (val_loss, 0) if improved else (best_loss, stale + 1)
        row = {
            "epoch": epoch + 1,
            "val_loss": val_loss,
            "best": improved,
            "seconds": time.perf_counter() - t0,
            **{f"train_{k}": v for k, v in losses.items()},
        }
        history.append(row)
        if logger is not None:
            for k, v in row.items():
                if isinstance(v, (int, float)) and k != "epoch":
                    logger.log_scalar(f"pretrain/{k}", float(v), step=epoch + 1)
        bar.set_postfix(val=f"{val_loss:.4f}", best=f"{best_loss:.4f}")
        common = dict(
            kind=task.kind,
            architecture=task.architecture(),
            modules=task.modules(),
            dataset_hash=dataset_hash,
            config=config,
        )
        if improved:
            save_checkpoint(best, **common, state={"task": task.state(), "epoch": epoch + 1, "val_loss": val_loss})
        save_checkpoint(
            last,
            **common,
            state={
                "task": task.state(),
                "optimizers": {n: o.state_dict() for n, o in task.optimizers().items()},
                "generator": gen.get_state(),
                "epoch": epoch + 1,
                "best_loss": best_loss,
                "stale": stale,
                "history": json.dumps(history),
            },
        )
    bar.close()
    write_json_atomic(run_dir / "history.json", history)
    if not best.is_file():
        raise RuntimeError(f"{task.kind}: no epoch was trained (epochs={cfg.epochs})")
    payload = load_checkpoint(
        best, kind=task.kind, architecture=task.architecture(), modules=task.modules(), dataset_hash=dataset_hash
    )
    task.load_state(payload["state"]["task"])
    metrics = task.evaluate(test, run_dir)
    metrics.update(
        best_epoch=payload["state"]["epoch"],
        best_val_loss=payload["state"]["val_loss"],
        epochs_run=len(history),
        train_seconds=sum(r["seconds"] for r in history),
    )
    write_json_atomic(run_dir / "metrics.json", metrics)
    return metrics
