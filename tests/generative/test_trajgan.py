"""trajGAN (paper §III.B, Eq. 13-15): training, checkpoints, evaluation and the batched predictor."""

from __future__ import annotations

import json

import pytest
import torch
from tensordict import TensorDict

from kddrl_trl import keys as K
from kddrl_trl.generative.checkpoint import CheckpointError, load_checkpoint
from kddrl_trl.generative.pretraining import PretrainConfig, run_pretraining
from kddrl_trl.generative.trajgan import TrajGANConfig, TrajGANPredictor, TrajGANTask
from kddrl_trl.physics.idm import idm_rollout

H, T, DT = 10, 20, 0.1
SIX = ("mae", "rmse", "mae_step10", "rmse_step10", "mae_step20", "rmse_step20")
SMALL = {"g_hidden": [32, 32], "d_hidden": [32, 32], "noise_dim": 4, "eval_batch_size": 64}


def leader_samples(n: int, seed: int) -> TensorDict:
    """``leaders`` samples (schema of ``data/extract.py``): constant-acceleration histories; from the same
    observed state a "timid" driver (code 1) brakes and an "aggressive" one (code 3) accelerates, so the
    future given the condition is bimodal."""
    g = torch.Generator().manual_seed(seed)
    u = lambda lo, hi, *shape: lo + (hi - lo) * torch.rand(*shape, generator=g)
    y0, v0, a_hist = u(0, 300, n), u(20, 30, n), u(-0.5, 0.5, n)
    th = (torch.arange(H) - (H - 1)) * DT  # -0.9 .. 0
    hy = y0[:, None] + v0[:, None] * th + 0.5 * a_hist[:, None] * th**2
    hv = v0[:, None] + a_hist[:, None] * th
    driver = torch.where(torch.rand(n, generator=g) < 0.5, 1, 3)
    a_fut = a_hist + torch.where(driver == 1, -1.5, 1.5)
    tf = torch.arange(1, T + 1) * DT
    future = y0[:, None] + v0[:, None] * tf + 0.5 * a_fut[:, None] * tf**2
    present = torch.rand(n, generator=g) < 0.7
    ahead = torch.stack([y0 + u(20, 80, n), v0 + u(-3, 3, n), present.float()], -1) * present[:, None]
    prior = idm_rollout(y0, v0, ahead[:, 0], ahead[:, 1], present, steps=T, dt=DT)
    return TensorDict(
        {
            "ego": torch.stack([y0 - 30, v0], -1),
            "slot": torch.ones(n, dtype=torch.long),
            "history": torch.stack([hy, hv], -1),
            "ahead": ahead,
            "ahead_length": torch.full((n,), 5.0),
            "prior": prior,
            "future": future,
            "leader_length": torch.full((n,), 4.5),
            "recording_id": torch.ones(n, dtype=torch.long),
            "vehicle_id": torch.arange(n),
            "leader_id": torch.arange(n) + n,
            "frame": torch.arange(n),
            "leader_driver": driver,
        },
        batch_size=[n],
    )


@pytest.fixture(scope="module")
def data():
    return {"train": leader_samples(384, 0), "val": leader_samples(128, 1), "test": leader_samples(128, 2)}


def train_steps(task: TrajGANTask, train: TensorDict, steps: int, batch: int = 64) -> list[dict]:
    g = torch.Generator().manual_seed(123)
    out = []
    for _ in range(steps):
        idx = torch.randperm(len(train), generator=g)[:batch]
        out.append(task.train_batch(train[idx]))
    return out


def test_losses_decrease_and_shapes(data):
    task = TrajGANTask({**SMALL, "omega": 1.0, "seed": 0}, data["train"])
    logs = train_steps(task, data["train"], 60)
    first = lambda k: sum(r[k] for r in logs[:5]) / 5
    last = lambda k: sum(r[k] for r in logs[-10:]) / 10
    assert last("loss_g") < 0.7 * first("loss_g")
    assert last("mae") < 0.7 * first("mae")
    # in the joint game D hovers near its equilibrium (2 ln 2); against a frozen G it must learn to tell
    # the bimodal real futures TR from the generated TG: Eq. 14 falls well below 2 ln 2
    frozen = TrajGANTask({**SMALL, "lr_g": 1e-8, "seed": 0}, data["train"])
    d_logs = [r["loss_d"] for r in train_steps(frozen, data["train"], 60)]
    assert sum(d_logs[:5]) / 5 > 1.3 and sum(d_logs[-10:]) / 10 < 0.9
    s = task.sample(data["test"][:7], k=5, generator=torch.Generator().manual_seed(0))
    assert s.shape == (7, 5, T) and torch.isfinite(s).all()
    assert s.std(dim=1).mean() > 0  # the noise matters
    assert task.validation_loss(data["val"]) == task.validation_loss(data["val"])  # seeded


def test_config_rejects_unknown_keys(data):
    with pytest.raises(ValueError, match="unknown trajGAN config"):
        TrajGANTask({"omega_typo": 1.0}, data["train"])


def test_same_seed_same_weights_other_seed_differs(data):
    def weights(seed):
        task = TrajGANTask({**SMALL, "seed": seed}, data["train"])
        train_steps(task, data["train"], 8)
        return torch.cat([p.flatten() for m in task.modules().values() for p in m.state_dict().values()])

    a, b, c = weights(0), weights(0), weights(1)
    assert torch.equal(a, b)
    assert not torch.allclose(a, c)


def test_run_pretraining_end_to_end(data, tmp_path):
    task = TrajGANTask({**SMALL, "num_eval_samples": 4}, data["train"])
    cfg = PretrainConfig(epochs=2, batch_size=64, patience=5, seed=0)
    metrics = run_pretraining(
        task, data["train"], data["val"], data["test"], cfg, tmp_path, "hash-a", config={"gan": SMALL}, progress=False
    )
    saved = json.loads((tmp_path / "metrics.json").read_text())
    for block in (saved, saved["idm_prior"], saved["const_velocity"]):
        for key in SIX:
            assert block[key] >= 0 and block[key] == block[key]
    assert set(saved["min_of_k"]) >= {"mae", "mae_step20"} and saved["spread_step20"] >= 0
    assert set(saved["per_driver"]) == {"timid", "aggressive"}
    for row in saved["per_driver"].values():
        assert set(row) == {"n", "mae_step20", "idm_prior_mae_step20", "min_of_k_mae_step20", "spread_step20"}
    assert sum(r["n"] for r in saved["per_driver"].values()) == len(data["test"])
    # min over K samples can only be at least as good as the first sample on average, modulo noise draws
    assert saved["min_of_k"]["mae_step20"] <= saved["mae_step20"] + 0.5
    assert metrics["epochs_run"] == 2
    for png in ("trajgan_errors.png", "trajgan_samples.png"):
        assert (tmp_path / png).stat().st_size > 1000
    payload = torch.load(tmp_path / "best.pt", weights_only=True)
    assert payload["kind"] == "trajgan" and payload["dataset_hash"] == "hash-a"
    assert (tmp_path / "best.pt").stat().st_size < 1_000_000

    # the same architecture reloads; another hidden size or another data set is refused clearly
    same = TrajGANTask(SMALL, data["train"])
    load_checkpoint(
        tmp_path / "best.pt",
        kind="trajgan",
        architecture=same.architecture(),
        modules=same.modules(),
        dataset_hash="hash-a",
    )
    assert same.validation_loss(data["val"]) == pytest.approx(metrics["best_val_loss"])
    other = TrajGANTask({**SMALL, "g_hidden": [16, 16]}, data["train"])
    with pytest.raises(CheckpointError, match="g_hidden"):
        load_checkpoint(
            tmp_path / "best.pt",
            kind="trajgan",
            architecture=other.architecture(),
            modules=other.modules(),
            dataset_hash="hash-a",
        )
    with pytest.raises(CheckpointError, match="another dataset"):
        load_checkpoint(
            tmp_path / "best.pt",
            kind="trajgan",
            architecture=same.architecture(),
            modules=same.modules(),
            dataset_hash="hash-b",
        )
    with pytest.raises(CheckpointError, match="another dataset"):
        TrajGANPredictor.from_checkpoint(tmp_path / "best.pt", dataset_hash="hash-b")
    with pytest.raises(CheckpointError, match="g_hidden"):
        TrajGANPredictor.from_checkpoint(tmp_path / "best.pt", architecture=other.architecture())

    # the predictor rebuilt from the checkpoint equals the one built from the trained task
    td = env_observation(data["test"], [4])
    a = TrajGANPredictor.from_checkpoint(tmp_path / "best.pt", seed=3)(td.clone())[K.PRED_TRAJ]
    b = TrajGANPredictor.from_task(same, seed=3)(td.clone())[K.PRED_TRAJ]
    torch.testing.assert_close(a, b)


def env_observation(samples: TensorDict, batch: list[int], absent: float = 0.3, seed: int = 0) -> TensorDict:
    """Environment observations of shape ``batch`` whose leaders a, b, c are drawn from ``samples``;
    absent leaders are zero-filled like the environment does."""
    g = torch.Generator().manual_seed(seed)
    n = 3 * int(torch.tensor(batch).prod()) if batch else 3
    idx = torch.randint(len(samples), (n,), generator=g)
    s = samples[idx]
    present = torch.rand(n, generator=g) >= absent
    present[0] = True
    mask = torch.cat([present.reshape(*batch, 3), torch.ones(*batch, 3, dtype=torch.bool)], -1)
    z = lambda x: x * present.reshape(-1, *[1] * (x.dim() - 1))
    return TensorDict(
        {
            K.LEADERS_HISTORY: z(s["history"]).reshape(*batch, 3, H, 2),
            K.LEADERS_AHEAD: z(s["ahead"]).reshape(*batch, 3, 3),
            K.NEIGHBORS_MASK: mask,
            K.PRED_PRIOR_TRAJ: s["prior"].reshape(*batch, 3, T),  # an upstream transform may fill absent ones
        },
        batch_size=batch,
    )


@pytest.fixture(scope="module")
def trained(data):
    task = TrajGANTask(SMALL, data["train"])
    train_steps(task, data["train"], 20)
    return task


@pytest.mark.parametrize("batch", [[], [4], [2, 3]])
@pytest.mark.parametrize("reduce", ["sample", "mean"])
def test_predictor_shapes_absent_and_seed(trained, data, batch, reduce):
    td = env_observation(data["test"], batch)
    pred = TrajGANPredictor.from_task(trained, num_samples=4, reduce=reduce, seed=7)
    out = pred(td.clone())[K.PRED_TRAJ]
    assert out.shape == (*batch, 3, T) and torch.isfinite(out).all()
    absent = ~td[K.NEIGHBORS_MASK][..., :3]
    prior = td[K.PRED_PRIOR_TRAJ]
    assert torch.equal(out[absent], prior[absent])
    assert not torch.equal(out[~absent], prior[~absent])  # present leaders are refined
    # plausible: close to the truth-scale motion of a leader (within 10 m of its prior over 2 s)
    assert (out - prior).abs().max() < 10
    again = TrajGANPredictor.from_task(trained, num_samples=4, reduce=reduce, seed=7)(td.clone())[K.PRED_TRAJ]
    assert torch.equal(out, again)
    other = TrajGANPredictor.from_task(trained, num_samples=4, reduce=reduce, seed=8)(td.clone())[K.PRED_TRAJ]
    assert not torch.equal(out, other)
    pred.reset()
    assert torch.equal(pred(td.clone())[K.PRED_TRAJ], out)


def test_predictor_one_call_for_all_envs(trained, data):
    """A batch [2, 3] gives what each environment gets on its own through one flat [6] batch."""
    td = env_observation(data["test"], [2, 3], absent=0.0)
    a = TrajGANPredictor.from_task(trained, seed=1)(td.clone())[K.PRED_TRAJ]
    b = TrajGANPredictor.from_task(trained, seed=1)(td.reshape(6).clone())[K.PRED_TRAJ]
    torch.testing.assert_close(a.reshape(6, 3, T), b)


def test_predictor_never_nan(trained, data):
    td = env_observation(data["test"], [4], absent=0.5)
    absent = ~td[K.NEIGHBORS_MASK][..., :3]
    td[K.PRED_PRIOR_TRAJ][absent] = float("nan")  # no prior for absent leaders either
    td[K.LEADERS_HISTORY][absent] = float("nan")
    out = TrajGANPredictor.from_task(trained)(td)[K.PRED_TRAJ]
    assert torch.isfinite(out).all()
    assert (out[absent] == 0).all()


def test_predictor_rejects_other_history_length(trained, data):
    td = env_observation(data["test"], [2])
    del td[K.LEADERS_HISTORY]
    td.set(K.LEADERS_HISTORY, torch.zeros(2, 3, H + 2, 2))
    with pytest.raises(ValueError, match="history"):
        TrajGANPredictor.from_task(trained)(td)


def test_config_defaults_are_small():
    cfg = TrajGANConfig()
    assert cfg.num_eval_samples >= 2 and 0 < cfg.omega
