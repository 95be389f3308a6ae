"""Shipped default weights and ``python -m kddrl_trl.pretrain`` as a user types it."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import torch

from kddrl_trl import keys as K
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.generative import SHIPPED_TRAFFIC, default_checkpoint, load_predictor, read_checkpoint
from kddrl_trl.generative.shipped import metrics_path, read_shipped_metrics
from kddrl_trl.transforms import IDMPrior, KeyGapsFromPrior


def observation(num_envs=4):
    env = FakeHighwayEnv("congested", num_roads=num_envs, seed=0)
    td = env.rollout(25, break_when_any_done=False)[:, -1]["next"]
    return KeyGapsFromPrior()(IDMPrior()(td))


@pytest.mark.parametrize("traffic", SHIPPED_TRAFFIC)
@pytest.mark.parametrize("kind", ["trajgan", "lcgan"])
def test_shipped_weights_load_and_match_their_declared_shapes(kind, traffic):
    path = default_checkpoint(kind, traffic)
    assert path.is_file() and path.stat().st_size < 1_000_000
    payload = torch.load(path, map_location="cpu", weights_only=True)
    assert payload["kind"] == kind and payload["dataset_hash"]
    module = load_predictor(kind, traffic=traffic)
    td = observation()
    out = module(td.clone())
    if kind == "trajgan":
        traj = out[K.PRED_TRAJ]
        assert traj.shape == (4, 3, 20) and torch.isfinite(traj).all()
        absent = ~td[K.NEIGHBORS_MASK][..., :3]
        assert torch.equal(traj[absent], td[K.PRED_PRIOR_TRAJ][absent])
        # a refined future stays near the physics prior and moves forward
        present = ~absent
        assert (traj[present][:, -1] > traj[present][:, 0]).all()
    else:
        p = out[K.PRIOR_P_LCGAN]
        assert p.shape == (4, 3) and torch.allclose(p.sum(-1), torch.ones(4), atol=1e-5)
        lane = td[K.EGO_LANE].squeeze(-1)
        assert (p[lane == 0, K.RIGHT] == 0).all() and (p[lane == 2, K.LEFT] == 0).all()
    assert read_checkpoint(path)["architecture"]


@pytest.mark.parametrize("traffic", SHIPPED_TRAFFIC)
@pytest.mark.parametrize("kind", ["trajgan", "lcgan"])
def test_shipped_metrics_belong_to_the_shipped_weights(kind, traffic):
    """``weights/[<traffic>/]<kind>.metrics.json`` ships beside the weights, names the dataset the weights were
    trained on (their own recorded hash) and the command that made it, and holds the test metrics the issue asks
    for."""
    weights = default_checkpoint(kind, traffic)
    data = read_shipped_metrics(kind, weights)
    assert data is not None, f"{metrics_path(weights)} is missing"
    assert data["dataset_hash"] == read_checkpoint(weights)["dataset_hash"]
    for field in ("command", "weights_command"):
        assert data[field].startswith("python -m kddrl_trl.pretrain") and f"gan={kind}" in data[field]
        assert ("env=highwayenv" in data[field]) == (traffic == "highwayenv")
    test = data["test"]
    if kind == "lcgan":
        for name in K.LC_ACTIONS:
            assert 0.0 <= test[f"recall_{name}"] <= 1.0 and 0.0 <= test[f"precision_{name}"] <= 1.0
        counts = torch.tensor(test["confusion_counts"])
        assert counts.shape == (3, 3) and counts.sum(1).tolist() == test["n_per_class"]
        assert abs(counts.diagonal().sum().item() / counts.sum().item() - test["accuracy"]) < 1e-9
        from kddrl_trl.report import SHIPPED_LCGAN_METRICS, read_lcgan_metrics

        if traffic == "sumo":
            assert read_lcgan_metrics(SHIPPED_LCGAN_METRICS) == test  # what the report draws Figs. 16-17 from
    else:
        for part in ("braking", "normal"):
            assert test[part]["n"] > 0 and test[part]["trajgan"]["mae_step20"] > 0
        assert test["braking"]["n"] + test["normal"]["n"] == test["n"]


def test_rl_runtime_does_not_import_the_data_layer():
    """The transforms, the generative models and the modules load without ``kddrl_trl.data`` (and pandas)."""
    code = (
        "import sys; import kddrl_trl.transforms, kddrl_trl.generative, kddrl_trl.modules; "
        "print(sorted(m for m in sys.modules if m.startswith('kddrl_trl.data') or m.split('.')[0] == 'pandas'))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout


def run(module, args, cwd):
    return subprocess.run(
        [sys.executable, "-m", module, "progress=false", *args], cwd=cwd, capture_output=True, text=True, timeout=600
    )


def test_pretrain_runs_as_typed_and_exports(tmp_path):
    prep = run("kddrl_trl.prepare", ["record.duration_s=60", "record.num_roads=1", "calibrate=false"], tmp_path)
    assert prep.returncode == 0, prep.stderr
    for kind in ("trajgan", "lcgan"):
        done = run(
            "kddrl_trl.pretrain",
            [
                f"gan={kind}",
                "gan.train.epochs=1",
                f"export={tmp_path}/{kind}.pt",
                f"hydra.run.dir={tmp_path}/run_{kind}",
            ],
            tmp_path,
        )
        assert done.returncode == 0, done.stderr
        metrics = json.loads((tmp_path / f"run_{kind}" / "metrics.json").read_text())
        key = "mae_step20" if kind == "trajgan" else "recall_left"
        assert key in metrics and (tmp_path / f"{kind}.pt").is_file()
        assert load_predictor(kind, tmp_path / f"{kind}.pt") is not None
        shipped = json.loads((tmp_path / f"{kind}.metrics.json").read_text())
        assert shipped["dataset_hash"] == read_checkpoint(tmp_path / f"{kind}.pt")["dataset_hash"]
        assert str(shipped["test"][key]) == str(metrics[key]) and f"gan={kind}" in shipped["command"]  # NaN-safe
    # evaluate=PATH re-measures shipped weights without training, and refuses weights of another dataset
    (tmp_path / "lcgan.metrics.json").unlink()
    done = run(
        "kddrl_trl.pretrain", ["gan=lcgan", f"evaluate={tmp_path}/lcgan.pt", f"hydra.run.dir={tmp_path}/ev"], tmp_path
    )
    assert done.returncode == 0, done.stderr
    assert "evaluate=" in json.loads((tmp_path / "lcgan.metrics.json").read_text())["command"]
    other = run(
        "kddrl_trl.pretrain",
        ["gan=lcgan", f"evaluate={default_checkpoint('lcgan')}", f"hydra.run.dir={tmp_path}/ev2"],
        tmp_path,
    )
    assert other.returncode != 0 and "another dataset" in other.stderr
    bad = run("kddrl_trl.pretrain", ["gan=trajgan", "device=cuda"], tmp_path) if not torch.cuda.is_available() else None
    if bad is not None:
        assert bad.returncode != 0 and "no CUDA device" in bad.stderr
