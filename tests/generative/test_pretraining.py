"""The generic pretraining loop and checkpoints, with a tiny stand-in model (fast, exact)."""

from __future__ import annotations

import json

import pytest
import torch
from tensordict import TensorDict
from torch import nn

from kddrl_trl.generative.checkpoint import CheckpointError, load_checkpoint, read_checkpoint, save_checkpoint
from kddrl_trl.generative.pretraining import PretrainConfig, run_pretraining


class LinearTask:
    """Least squares y = w x as a 'GAN task': enough to exercise the loop."""

    kind = "toy"

    def __init__(self, hidden: int = 1, seed: int = 0, lr: float = 0.1):
        torch.manual_seed(seed)
        self.net = nn.Linear(1, hidden, bias=False)
        self.opt = torch.optim.SGD(self.net.parameters(), lr=lr)
        self.hidden = hidden
        self.scale = torch.tensor(1.0)

    def architecture(self):
        return {"hidden": self.hidden}

    def modules(self):
        return {"net": self.net}

    def optimizers(self):
        return {"net": self.opt}

    def state(self):
        return {"scale": self.scale}

    def load_state(self, state):
        self.scale = state["scale"]

    def _loss(self, td):
        return ((self.net(td["x"]).mean(-1, keepdim=True) - td["y"]) ** 2).mean()

    def train_batch(self, batch):
        self.opt.zero_grad()
        loss = self._loss(batch)
        loss.backward()
        self.opt.step()
        return {"mse": loss.item()}

    def validation_loss(self, data):
        with torch.no_grad():
            return self._loss(data).item()

    def evaluate(self, test, out_dir):
        return {"mse": self.validation_loss(test)}


def data(n, seed):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(n, 1, generator=g)
    return TensorDict({"x": x, "y": 3.0 * x}, batch_size=[n])


def test_loop_trains_stops_early_and_evaluates(tmp_path):
    task = LinearTask()
    m = run_pretraining(
        task,
        data(256, 0),
        data(64, 1),
        data(64, 2),
        PretrainConfig(epochs=50, batch_size=32, patience=2),
        tmp_path,
        "hash-a",
        progress=False,
    )
    assert m["mse"] < 1e-3 and m["epochs_run"] < 50  # converged, then stopped early
    history = json.loads((tmp_path / "history.json").read_text())
    assert history[0]["val_loss"] > history[-1]["val_loss"]
    assert json.loads((tmp_path / "metrics.json").read_text())["best_epoch"] == m["best_epoch"]


def test_killed_run_resumes(tmp_path):
    cfg = dict(batch_size=32, patience=100, seed=3)
    full = run_pretraining(
        LinearTask(lr=0.01),
        data(256, 0),
        data(64, 1),
        data(64, 2),
        PretrainConfig(epochs=6, **cfg),
        tmp_path / "a",
        "h",
        progress=False,
    )
    run_pretraining(
        LinearTask(lr=0.01),
        data(256, 0),
        data(64, 1),
        data(64, 2),
        PretrainConfig(epochs=3, **cfg),
        tmp_path / "b",
        "h",
        progress=False,
    )  # "killed" after 3
    resumed = run_pretraining(
        LinearTask(lr=0.01),
        data(256, 0),
        data(64, 1),
        data(64, 2),
        PretrainConfig(epochs=6, **cfg),
        tmp_path / "b",
        "h",
        progress=False,
    )
    assert resumed["epochs_run"] == 6 and resumed["mse"] == pytest.approx(full["mse"], rel=1e-6)


def test_checkpoint_checks_kind_architecture_and_data(tmp_path):
    task = LinearTask(hidden=2)
    path = save_checkpoint(
        tmp_path / "c.pt",
        kind="toy",
        architecture=task.architecture(),
        modules=task.modules(),
        dataset_hash="abc",
        state={"epoch": 1},
    )
    assert read_checkpoint(path)["state"]["epoch"] == 1
    torch.load(path, weights_only=True)
    other = LinearTask(hidden=3)
    with pytest.raises(CheckpointError, match="hidden"):
        load_checkpoint(path, kind="toy", architecture=other.architecture(), modules=other.modules())
    with pytest.raises(CheckpointError, match="another dataset"):
        load_checkpoint(path, kind="toy", architecture=task.architecture(), modules=task.modules(), dataset_hash="xyz")
    with pytest.raises(CheckpointError, match="'toy' model, not 'lcgan'"):
        load_checkpoint(path, kind="lcgan", architecture=task.architecture(), modules=task.modules())
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError):
        read_checkpoint(tmp_path / "bad.pt")
    with pytest.raises(FileNotFoundError):
        read_checkpoint(tmp_path / "missing.pt")
