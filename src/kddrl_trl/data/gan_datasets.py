"""The datasets the generative models learn from (``python -m kddrl_trl.pretrain``): their splits, their hash (the
input recordings and the extraction parameters, which a checkpoint records) and their description."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import torch

from .extract import LABELS, load_dataset
from .synthetic import synthetic_dataset

#: which sample kind each generative model learns from (``kddrl_trl.data.extract``)
GAN_DATA_KIND = {"trajgan": "leaders", "lcgan": "lane_changes"}
#: extraction parameters that do not shape a model's samples, left out of its dataset hash (the lcGAN window label
#: does not change the trajGAN leader samples, so it does not invalidate trajGAN weights)
_OTHER_KIND_PARAMS = {"trajgan": ("label",), "lcgan": ()}


def dataset_description(data_dir: Path) -> dict:
    """The extraction parameters of the dataset in ``data_dir`` and, in words, its lcGAN window label."""
    params = json.loads((Path(data_dir) / "meta.json").read_text())["params"]
    label = params.get("label", "end")  # datasets extracted before the option had the net change
    return {
        "params": params,
        "label_definition": f"{label}: {LABELS[label]} (window = {params['window']} frames at {params['hz']} Hz)",
    }


def gan_dataset(
    kind: str,
    data_dir: Path,
    env,
    recordings_dir: Path,
    seed: int,
    device: torch.device,
    progress: bool = True,
) -> tuple[dict, str]:
    """The train / val / test splits (on ``device``) that model ``kind`` learns from, and the dataset's hash
    (the input recordings and the extraction parameters). ``data_dir`` without a dataset: the default one is
    built first from our own recordings of the traffic of ``env`` (the ``env`` node: its simulator's traffic,
    :func:`kddrl_trl.data.synthetic.traffic_recorder`)."""
    if (data_dir / "meta.json").is_file():
        meta = json.loads((data_dir / "meta.json").read_text())
    else:
        meta = synthetic_dataset(env, data_dir, recordings_dir, seed=seed, progress=progress)
    splits = {
        s: load_dataset(data_dir, GAN_DATA_KIND[kind], s).to_tensordict().to(device) for s in ("train", "val", "test")
    }
    params = {k: v for k, v in meta["params"].items() if k not in _OTHER_KIND_PARAMS[kind]}
    digest = hashlib.sha256(json.dumps([meta["input_hash"], params, kind], sort_keys=True).encode()).hexdigest()
    return splits, digest
