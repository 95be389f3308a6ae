"""lcGAN (paper Eq. 16-19): networks, losses, the pretraining run, checkpoints and the batched predictor."""

from __future__ import annotations

import json
import math

import pytest
import torch
from tensordict import TensorDict

from kddrl_trl import keys as K
from kddrl_trl.generative.checkpoint import CheckpointError, load_checkpoint
from kddrl_trl.generative.gan_inputs import lane_change_condition
from kddrl_trl.generative.lcgan import (
    LCGANConfig,
    LCGANPredictor,
    LCGANTask,
    class_weights,
    classification_metrics,
    focal_loss,
)
from kddrl_trl.generative.pretraining import PretrainConfig, run_pretraining

SMALL = {"hidden": 32, "layers": 2, "noise_dim": 4, "lr_g": 3e-3, "lr_d": 1e-3}


def samples(n: int, seed: int, rare: float = 0.04) -> TensorDict:
    """Tiny ``lane_changes`` samples whose label follows the condition: left = moving left behind a slow
    leader, right = moving right; a share ``rare`` of each lane-change class, the rest keep."""
    g = torch.Generator().manual_seed(seed)
    lane = torch.randint(0, 3, (n,), generator=g)
    u = torch.rand(n, generator=g)
    label = torch.full((n,), K.KEEP)
    label[(u < rare) & (lane < 2)] = K.LEFT
    label[(u > 1 - rare) & (lane > 0)] = K.RIGHT
    v = 25.0 + 5.0 * torch.rand(n, generator=g)
    lat = torch.where(label == K.LEFT, 1.6, torch.where(label == K.RIGHT, -1.6, 0.0))
    mask = torch.rand(n, 6, generator=g) < 0.7
    mask[:, 0] &= lane < 2  # no left neighbours from the leftmost lane
    mask[:, 3] &= lane < 2
    mask[:, 2] &= lane > 0
    mask[:, 5] &= lane > 0
    rel = torch.randn(n, 6, 4, generator=g)
    rel[:, :3, 1] = 10.0 + 40.0 * torch.rand(n, 3, generator=g)  # leaders ahead
    rel[:, 3:, 1] = -10.0 - 40.0 * torch.rand(n, 3, generator=g)  # followers behind
    rel[:, 1, 3] = torch.where(label == K.LEFT, -6.0, 0.0) + 0.5 * torch.randn(n, generator=g)
    mask[label == K.LEFT, 1] = True
    rel = torch.where(mask.unsqueeze(-1), rel, torch.zeros_like(rel))
    t_key = torch.tensor([1.0, 2.0])  # key steps 10 and 20 at 10 Hz
    gaps = rel[:, :3, 1:2] + (v.reshape(n, 1, 1) + rel[:, :3, 3:4]) * t_key
    key_mask = mask[:, :3].clone()
    gaps = torch.where(key_mask.unsqueeze(-1), gaps, torch.zeros_like(gaps))
    offset = torch.where(label == K.LEFT, 0.8, torch.where(label == K.RIGHT, -0.8, 0.0))
    nb_offset = torch.where(mask, 0.2 * torch.randn(n, 6, generator=g), torch.zeros(n, 6))
    return TensorDict(
        {
            "label": label,
            "s_av": torch.stack([v, lat, lane.float(), offset], -1),
            "rel": rel,
            "mask": mask,
            "lane_offset": nb_offset,
            "key_gaps": gaps,
            "key_gaps_mask": key_mask,
            "num_lanes": torch.full((n,), 3),
            "recording_id": torch.zeros(n, dtype=torch.int64),
            "vehicle_id": torch.arange(n),
            "frame": torch.zeros(n, dtype=torch.int64),
            "driver": torch.zeros(n, dtype=torch.int64),
        },
        batch_size=[n],
    )


@pytest.fixture(scope="module")
def data():
    return samples(1500, 0), samples(600, 1), samples(600, 2)


def epochs(task: LCGANTask, train: TensorDict, n: int, batch: int = 128) -> list[dict]:
    g = torch.Generator().manual_seed(0)
    out = []
    for _ in range(n):
        rows = [task.train_batch(train[idx]) for idx in torch.randperm(train.batch_size[0], generator=g).split(batch)]
        out.append({k: sum(r[k] for r in rows) / len(rows) for k in rows[0]})
    return out


@pytest.mark.parametrize("adversarial", [True, False])
def test_losses_decrease_and_rare_classes_are_learnt(data, adversarial):
    train, val, _ = data
    task = LCGANTask(dict(SMALL, adversarial=adversarial), train)
    before = task.validation_loss(val)
    hist = epochs(task, train, 8)
    assert hist[-1]["loss_focal"] < 0.5 * hist[0]["loss_focal"]
    assert ("loss_d" in hist[0]) == adversarial
    after = task.validation_loss(val)
    assert after < before and after < 0.1  # balanced accuracy > 90 % on a learnable rule


def test_probabilities_are_a_simplex_that_respects_lanes(data):
    train, val, _ = data
    task = LCGANTask(SMALL, train)
    epochs(task, train, 1)
    p = task.predict(val)
    lane = val["s_av"][:, 2]
    assert p.shape == (600, 3) and torch.isfinite(p).all() and (p >= 0).all()
    assert torch.allclose(p.sum(-1), torch.ones(600), atol=1e-6)
    assert (p[lane == 2, K.LEFT] == 0).all() and (p[lane == 0, K.RIGHT] == 0).all()
    assert (p[lane == 1, K.LEFT] > 0).all()


def test_focal_loss_matches_hand_computation():
    p = torch.tensor([[0.2, 0.7, 0.1], [0.5, 0.3, 0.2]])
    target = torch.tensor([K.KEEP, K.RIGHT])
    alpha = torch.tensor([2.0, 0.5, 3.0])
    hand = (-0.5 * 0.3**2 * math.log(0.7) - 3.0 * 0.8**2 * math.log(0.2)) / 2
    assert focal_loss(p.log(), target, alpha, gamma=2.0).item() == pytest.approx(hand, rel=1e-6)
    # γ = 0 and α = 1: plain cross-entropy
    ce = torch.nn.functional.nll_loss(p.log(), target)
    assert focal_loss(p.log(), target, torch.ones(3), gamma=0.0).item() == pytest.approx(ce.item(), rel=1e-6)


def test_class_weights():
    freq = torch.tensor([0.01, 0.98, 0.01])
    a = class_weights(freq, "inv_sqrt")
    assert (
        a.mean().item() == pytest.approx(1.0)
        and a[0] == pytest.approx(a[2])
        and a[0] / a[1] == pytest.approx(math.sqrt(98), rel=1e-4)
    )
    assert class_weights(freq, "none").tolist() == [1.0, 1.0, 1.0]
    assert class_weights(freq, [1, 2, 3]).tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(ValueError):
        class_weights(freq, "bogus")


def test_config_and_balanced_share(data):
    train = data[0]
    with pytest.raises(ValueError, match="unknown lcGAN config"):
        LCGANTask({"hiden": 3}, train)
    cfg = LCGANConfig.from_any({"hidden": 16, "epochs": 3, "batch_size": 64})  # loop keys are ignored
    assert cfg.hidden == 16
    task = LCGANTask(dict(SMALL, balanced_fraction=0.5), train)
    big = task._with_balanced_share(train[:100])
    assert big.batch_size[0] == 200 and (big["label"][100:] != K.KEEP).all()
    freq = task.stream_frequencies()
    assert freq.sum().item() == pytest.approx(1.0) and freq[K.LEFT] > 0.25 and freq[K.RIGHT] > 0.25


def weights(task):
    return torch.cat([p.detach().flatten() for m in task.modules().values() for p in m.parameters()])


def test_same_seed_same_weights(data):
    train = data[0]
    runs = []
    for seed in (0, 0, 1):
        task = LCGANTask(dict(SMALL, seed=seed), train)
        epochs(task, train[:512], 1)
        runs.append(weights(task))
    assert torch.equal(runs[0], runs[1]) and not torch.equal(runs[0], runs[2])


def test_metrics():
    m = classification_metrics(torch.tensor([0, 1, 1, 1, 2, 1]), torch.tensor([0, 1, 1, 1, 2, 2]))
    assert m["accuracy"] == pytest.approx(5 / 6) and m["recall_right"] == pytest.approx(0.5)
    assert m["balanced_accuracy"] == pytest.approx((1.0 + 1.0 + 0.5) / 3)
    assert m["confusion"][2] == [0.0, 0.5, 0.5] and m["n_per_class"] == [1, 3, 2]
    assert sum(m["pred_shares"]) == pytest.approx(1.0)


@pytest.mark.parametrize("adversarial", [True, False])
def test_run_pretraining_end_to_end(data, tmp_path, adversarial):
    train, val, test = data
    task = LCGANTask(dict(SMALL, adversarial=adversarial), train)
    m = run_pretraining(
        task, train, val, test, PretrainConfig(epochs=2, batch_size=128), tmp_path, "hash-a", progress=False
    )
    saved = json.loads((tmp_path / "metrics.json").read_text())
    for key in (
        "accuracy",
        "recall_left",
        "recall_keep",
        "recall_right",
        "balanced_accuracy",
        "confusion",
        "true_shares",
        "pred_shares",
        "n_per_class",
        "mobil",
        "best_epoch",
        "epochs_run",
    ):
        assert key in saved, key
    assert saved["epochs_run"] == 2 and saved["adversarial"] == adversarial
    assert len(saved["confusion"]) == 3 and set(saved["mobil"]) >= {"accuracy", "recall_left", "confusion"}
    assert m["accuracy"] == saved["accuracy"]
    for png in ("lcgan_confusion.png", "lcgan_shares.png"):
        assert (tmp_path / png).stat().st_size > 1000
    payload = torch.load(tmp_path / "best.pt", weights_only=True)
    assert payload["kind"] == "lcgan" and ("discriminator" in payload["modules"]) == adversarial
    assert sum(t.numel() * t.element_size() for t in payload["modules"]["generator"].values()) < 1_000_000
    # a fresh shell restores the same predictions from the checkpoint
    shell = LCGANTask(dict(SMALL, adversarial=adversarial))
    st = load_checkpoint(
        tmp_path / "best.pt",
        kind="lcgan",
        architecture=shell.architecture(),
        modules=shell.modules(),
        dataset_hash="hash-a",
    )
    shell.load_state(st["state"]["task"])
    assert torch.equal(shell.predict(test), task.predict(test))
    pred = LCGANPredictor.from_checkpoint(tmp_path / "best.pt", dataset_hash="hash-a")
    assert torch.equal(pred.net.s_av_mean, task.generator.s_av_mean)


def test_checkpoint_mismatches_are_refused(data, tmp_path):
    train, val, test = data
    task = LCGANTask(SMALL, train)
    run_pretraining(
        task, train, val, test, PretrainConfig(epochs=1, batch_size=256), tmp_path, "hash-a", progress=False
    )
    best = tmp_path / "best.pt"
    for other in (dict(SMALL, hidden=16), dict(SMALL, adversarial=False), dict(SMALL, noise_dim=2)):
        t = LCGANTask(other)
        with pytest.raises(CheckpointError, match="another architecture"):
            load_checkpoint(best, kind="lcgan", architecture=t.architecture(), modules=t.modules())
    with pytest.raises(CheckpointError, match="another dataset"):
        load_checkpoint(
            best, kind="lcgan", architecture=task.architecture(), modules=task.modules(), dataset_hash="hash-b"
        )
    with pytest.raises(CheckpointError, match="another dataset"):
        LCGANPredictor.from_checkpoint(best, dataset_hash="hash-b")
    with pytest.raises(CheckpointError, match="not 'trajgan'"):
        load_checkpoint(best, kind="trajgan", architecture=task.architecture(), modules=task.modules())


def observation(batch: tuple[int, ...], seed: int = 0) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    mask = torch.rand(*batch, 6, generator=g) < 0.5
    rel = torch.randn(*batch, 6, 4, generator=g) * 10
    rel = torch.where(mask.unsqueeze(-1), rel, torch.full_like(rel, float("nan")))  # garbage where absent
    return TensorDict(
        {
            K.EGO_STATE: torch.cat(
                [
                    100 * torch.rand(*batch, 1, generator=g),
                    20 + 10 * torch.rand(*batch, 1, generator=g),
                    torch.randn(*batch, 1, generator=g),
                ],
                -1,
            ),
            K.EGO_LANE: torch.randint(0, 3, (*batch, 1), generator=g),
            K.NEIGHBORS_REL: rel,
            K.NEIGHBORS_MASK: mask,
            K.EGO_LANE_OFFSET: 0.5 * torch.randn(*batch, 1, generator=g),
            K.NEIGHBORS_LANE_OFFSET: torch.where(mask, 0.5 * torch.randn(*batch, 6, generator=g), float("nan")),
            K.PRED_KEY_GAPS: torch.where(
                mask[..., :3, None], 30 * torch.rand(*batch, 3, 2, generator=g), torch.zeros(*batch, 3, 2)
            ),
        },
        batch_size=batch,
    )


@pytest.mark.parametrize("batch", [(), (4,), (2, 3)])
def test_predictor_batch_shapes(data, batch):
    task = LCGANTask(SMALL, data[0])
    epochs(task, data[0], 1)
    out = LCGANPredictor.from_task(task, seed=5)(observation(batch))
    p = out[K.PRIOR_P_LCGAN]
    assert p.shape == (*batch, 3) and torch.isfinite(p).all() and (p >= 0).all() and not p.requires_grad
    assert torch.allclose(p.sum(-1), torch.ones(batch), atol=1e-6)
    lane = out[K.EGO_LANE][..., 0]
    assert (p[..., K.LEFT][lane == 2] == 0).all() and (p[..., K.RIGHT][lane == 0] == 0).all()
    again = LCGANPredictor.from_task(task, seed=5, draws=1)(observation(batch))[K.PRIOR_P_LCGAN]
    assert torch.equal(p, again)  # deterministic given the seed
    mean = LCGANPredictor.from_task(task, seed=5, draws=8)(observation(batch))[K.PRIOR_P_LCGAN]
    assert mean.shape == p.shape and torch.allclose(mean.sum(-1), torch.ones(batch), atol=1e-6)


def test_predictor_matches_task_on_samples(data):
    """The predictor assembles the same condition from the raw observation keys as the task from samples."""
    train, _, test = data
    task = LCGANTask(dict(SMALL, noise_dim=1), train)
    epochs(task, train, 1)
    s = test[:50]
    n = 50
    obs = TensorDict(
        {
            K.EGO_STATE: torch.stack([torch.zeros(n), s["s_av"][:, 0], s["s_av"][:, 1]], -1),
            K.EGO_LANE: s["s_av"][:, 2:3].long(),
            K.NEIGHBORS_REL: s["rel"],
            K.NEIGHBORS_MASK: s["mask"],
            K.EGO_LANE_OFFSET: s["s_av"][:, 3:4],
            K.NEIGHBORS_LANE_OFFSET: s["lane_offset"],
            K.PRED_KEY_GAPS: s["key_gaps"],
        },
        batch_size=[n],
    )
    pred = LCGANPredictor.from_task(task, draws=1)
    c_task, a_task = task._condition(s)
    fields = lane_change_condition(
        obs[K.EGO_STATE][:, 1],
        obs[K.EGO_STATE][:, 2],
        obs[K.EGO_LANE][:, 0],
        obs[K.EGO_LANE_OFFSET][:, 0],
        obs[K.NEIGHBORS_REL],
        obs[K.NEIGHBORS_MASK],
        obs[K.NEIGHBORS_LANE_OFFSET],
        obs[K.PRED_KEY_GAPS],
    )
    c_pred, a_pred = pred.net.condition(**fields, num_lanes=3)
    assert torch.allclose(c_task, c_pred) and torch.equal(a_task, a_pred)
    p = pred(obs)[K.PRIOR_P_LCGAN]
    assert torch.allclose(p.sum(-1), torch.ones(n), atol=1e-6)


def test_condition_marks_unknown_key_gaps_absent():
    """One condition for the training samples and RL time: a leader's key gaps count where the leader is present
    and both gaps are finite (a track ending before step 20 gives NaN gaps at extraction)."""
    mask = torch.tensor([[True, True, False, True, False, False]])
    gaps = torch.tensor([[[10.0, 20.0], [float("nan"), 5.0], [1.0, 2.0]]])
    rel = torch.where(mask.unsqueeze(-1), 1.0, float("nan")).expand(1, 6, 4)  # garbage where absent
    nb_offset = torch.where(mask, 0.3, float("nan"))
    f = lane_change_condition(
        torch.tensor([25.0]), torch.tensor([0.5]), torch.tensor([1]), torch.tensor([-0.4]), rel, mask, nb_offset, gaps
    )
    assert f["key_gaps_mask"].tolist() == [[True, False, False]] and torch.equal(f["mask"], mask)
    assert f["key_gaps"].tolist() == [[[10.0, 20.0], [0.0, 0.0], [0.0, 0.0]]]
    assert torch.equal(f["rel"], mask.unsqueeze(-1).float().expand(1, 6, 4))
    assert torch.allclose(f["lane_offset"], torch.where(mask, 0.3, 0.0))
    assert torch.allclose(f["s_av"], torch.tensor([[25.0, 0.5, 1.0, -0.4]]))
