"""Checkpoints of the generative models: state dicts + config + the hash of the data they were trained on.

A checkpoint is a plain dict of tensors, numbers and strings, so it loads with
``torch.load(weights_only=True)`` (no pickled code runs). Loading checks that the architecture recorded
in the file equals the one asked for, and (optionally) the dataset hash, and says what differs.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import torch
from torch import nn

from ..atomic_files import CheckpointError, torch_save_atomic

FORMAT = "kddrl_trl.generative/1"


def save_checkpoint(
    path: str | os.PathLike,
    *,
    kind: str,
    architecture: Mapping[str, Any],
    modules: Mapping[str, nn.Module],
    dataset_hash: str,
    config: Mapping[str, Any] | None = None,
    state: Mapping[str, Any] | None = None,
) -> Path:
    """Write atomically: ``kind`` ("trajgan" / "lcgan"), ``architecture`` (what must match to load),
    the modules' state dicts, the dataset hash, the full config and any extra ``state`` (optimisers,
    counters, normalisation statistics, ... — tensors, numbers, strings, lists and dicts only)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": FORMAT,
        "kind": kind,
        "architecture": dict(architecture),
        "dataset_hash": dataset_hash,
        "config": dict(config or {}),
        "modules": {name: m.state_dict() for name, m in modules.items()},
        "state": dict(state or {}),
    }
    return torch_save_atomic(path, payload)


def read_checkpoint(path: str | os.PathLike) -> dict:
    """The raw checkpoint dict, loaded with ``weights_only=True``; a clear error for a missing or foreign file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any unpickling failure means "not ours"
        raise CheckpointError(f"{path} is not a kddrl_trl checkpoint loadable with weights_only=True: {err}") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a kddrl_trl generative checkpoint (format {FORMAT!r})")
    return payload


def load_checkpoint(
    path: str | os.PathLike,
    *,
    kind: str,
    architecture: Mapping[str, Any],
    modules: Mapping[str, nn.Module],
    dataset_hash: str | None = None,
) -> dict:
    """Load the state dicts into ``modules`` after checking kind, architecture and (if given) dataset hash.

    Returns the checkpoint dict (``config``, ``state``, ``dataset_hash``, ...)."""
    payload = read_checkpoint(path)
    if payload["kind"] != kind:
        raise CheckpointError(f"{path} holds a {payload['kind']!r} model, not {kind!r}")
    saved = payload["architecture"]
    diff = {k: (saved.get(k), v) for k, v in architecture.items() if saved.get(k) != v}
    diff.update({k: (v, None) for k, v in saved.items() if k not in architecture})
    if diff:
        detail = ", ".join(f"{k}: checkpoint {a!r} vs wanted {b!r}" for k, (a, b) in sorted(diff.items()))
        raise CheckpointError(f"{path} was trained with another architecture ({detail})")
    if dataset_hash is not None and payload["dataset_hash"] != dataset_hash:
        raise CheckpointError(
            f"{path} was trained on another dataset (hash {payload['dataset_hash'][:12]} vs "
            f"{dataset_hash[:12]}); retrain or pass dataset_hash=None to accept it"
        )
    missing = set(modules) - set(payload["modules"])
    if missing:
        raise CheckpointError(f"{path} lacks the modules {sorted(missing)}")
    for name, module in modules.items():
        try:
            module.load_state_dict(payload["modules"][name])
        except RuntimeError as err:
            raise CheckpointError(f"{path}: module {name!r} does not match: {err}") from None
    return payload
