"""The evidence shipped beside each default weight file: ``weights/<kind>.metrics.json``.

Written by ``python -m kddrl_trl.pretrain gan=<kind> export=src/kddrl_trl/generative/weights/<kind>.pt`` (train
and ship) or ``... evaluate=src/kddrl_trl/generative/weights/<kind>.pt`` (re-measure shipped weights): the
test-split metrics of the weights on the dataset they were trained on, that dataset's hash (equal to the
``dataset_hash`` recorded in the weights; ``tests/test_shipped_metrics.py`` checks it) and the command that made
the file. The report (Figs. 16-17) reads it with :func:`read_shipped_metrics`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..atomic_files import write_json_atomic
from .checkpoint import load_checkpoint, read_checkpoint


def metrics_path(weights: str | Path) -> Path:
    """``.../<kind>.pt`` -> ``.../<kind>.metrics.json``."""
    weights = Path(weights)
    return weights.with_name(f"{weights.stem}.metrics.json")


def evaluate_checkpoint(task, checkpoint: str | Path, test, out_dir: str | Path, dataset_hash: str) -> dict:
    """Test metrics of ``checkpoint`` loaded into ``task`` (refused if it was trained on another dataset)."""
    payload = load_checkpoint(
        checkpoint, kind=task.kind, architecture=task.architecture(), modules=task.modules(), dataset_hash=dataset_hash
    )
    task.load_state(payload["state"]["task"])
    metrics = task.evaluate(test, out_dir)
    metrics.update(best_epoch=payload["state"].get("epoch"), best_val_loss=payload["state"].get("val_loss"))
    return metrics


def write_shipped_metrics(
    weights: str | Path,
    metrics: Mapping[str, Any],
    command: str,
    dataset: Mapping[str, Any] | None = None,
    trained: bool = True,
) -> Path:
    """Write ``metrics_path(weights)``: ``kind``, ``dataset_hash`` (read from the weights themselves, so the two
    cannot disagree), ``command`` (what measured the metrics), ``weights_command`` (what trained the weights:
    ``command`` itself when ``trained``, else kept from the file being replaced if it describes the same weights),
    ``dataset`` (where and how it was made) and ``test`` (the metrics)."""
    payload = read_checkpoint(weights)
    out = metrics_path(weights)
    weights_command = command if trained else None
    if not trained and out.is_file():
        old = json.loads(out.read_text())
        if old.get("dataset_hash") == payload["dataset_hash"]:
            weights_command = old.get("weights_command", old.get("command"))
    write_json_atomic(
        out,
        {
            "kind": payload["kind"],
            "dataset_hash": payload["dataset_hash"],
            "command": command,
            "weights_command": weights_command,
            "dataset": dict(dataset or {}),
            "split": "test",
            "test": dict(metrics),
        },
    )
    return out


def read_shipped_metrics(kind: str, weights: str | Path | None = None) -> dict | None:
    """The metrics JSON beside ``weights`` (default: the shipped weights of ``kind``); ``None`` if absent."""
    if weights is None:
        from . import default_checkpoint

        weights = default_checkpoint(kind)
    path = metrics_path(weights)
    if not path.is_file():
        return None
    data = json.loads(path.read_text())
    if data.get("kind") != kind:
        raise ValueError(f"{path} holds the metrics of {data.get('kind')!r}, not {kind!r}")
    return data
