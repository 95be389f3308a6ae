"""Option ``train.prioritized`` (issue 14, "Learning signal"): prioritized replay in buffers L and H with TorchRL's
``TensorDictPrioritizedReplayBuffer``; every learner reports its transitions' ``|δ|`` and weights its losses by the
importance weights; the trainer updates the priorities, anneals beta and keeps both across a resume."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from testkit import SMALL_NETS, compose_job, fake_trainer

from kddrl_trl import keys as K
from kddrl_trl.objectives import td_priority
from kddrl_trl.training import make_buffer
from kddrl_trl.training.trainer import is_prioritized

ALGOS = ["kddrl", "peng", "d3qn_unified", "pasac_unified"]  # TD3, DDPG, a joint D3QN, PASAC: every loss kind
#: the loss whose batch each algo's buffer-L update reads
FRAME_LOSS = {"kddrl": "cf_value", "peng": "cf_value", "d3qn_unified": "joint", "pasac_unified": "pasac"}


def test_td_priority_is_the_largest_absolute_error_over_critics():
    squared = torch.tensor([[1.0, 4.0, 0.0], [9.0, 1.0, 0.25]])  # [critics, B]
    torch.testing.assert_close(td_priority(squared, 3), torch.tensor([3.0, 2.0, 0.5]))
    torch.testing.assert_close(td_priority(torch.tensor([[4.0], [0.0]]), 2), torch.tensor([2.0, 0.0]))  # [B, 1]


def test_prioritized_buffer_samples_by_priority_with_importance_weights():
    uniform = make_buffer(100, 64, seed=0)
    uniform.extend(TensorDict({"x": torch.arange(10.0)}, [10]))
    assert not is_prioritized(uniform) and K.PRIORITY_WEIGHT not in uniform.sample().keys()
    rb = make_buffer(100, 64, seed=0, prioritized=(1.0, 1.0))
    assert is_prioritized(rb)
    rb.extend(TensorDict({"x": torch.arange(10.0)}, [10]))
    batch = rb.sample()
    assert K.PRIORITY_WEIGHT in batch.keys() and "index" in batch.keys()
    # new transitions enter at the largest priority so far: uniform at first, all weights 1
    torch.testing.assert_close(batch[K.PRIORITY_WEIGHT], torch.ones(64))
    batch.set(K.PRIORITY, torch.where(batch["index"] == 3, 1.0, 0.1))
    rb.update_tensordict_priority(batch)
    counts = torch.bincount(torch.cat([rb.sample()["index"] for _ in range(20)]), minlength=10)
    assert counts[3] > 0.35 * counts.sum()  # index 3 holds 1 / 1.9 of the priority mass (uniform: 1 / 10)
    heavy = rb.sample()
    w = heavy[K.PRIORITY_WEIGHT]
    # (p_i / p_min)^-beta: the high-priority transition is down-weighted (1 / 10) against the others (1)
    torch.testing.assert_close(w, torch.where(heavy["index"] == 3, 0.1, 1.0), rtol=1e-4, atol=1e-5)
    # the same seed draws the same indices (reproducible runs)
    torch.testing.assert_close(first_sample(seed=0), first_sample(seed=0))


def first_sample(seed: int) -> torch.Tensor:
    """The indices of a fresh prioritized buffer's first sample (10 transitions, equal priorities)."""
    rb = make_buffer(100, 64, seed=seed, prioritized=(1.0, 1.0))
    rb.extend(TensorDict({"x": torch.arange(10.0)}, [10]))
    return rb.sample()["index"]


def test_priority_options_are_checked():
    with pytest.raises(ValueError, match="train.priority_alpha"):
        compose_job("train.prioritized=true", "train.priority_alpha=0")
    with pytest.raises(ValueError, match="train.priority_beta"):
        compose_job("train.prioritized=true", "train.priority_beta=1.5")


def small_job(algo: str, *extra: str):
    nets = SMALL_NETS.get(algo, ["algo.learner.d3qn.hidden=[16]", "algo.learner.td3.hidden=[16]"])
    return compose_job(f"algo={algo}", "env.num_roads=2", "compile=false", *nets, *extra)


@pytest.mark.parametrize("algo", ALGOS)
def test_every_learner_reports_priorities_and_weights_its_losses(algo, tmp_path):
    """Each learner's value loss gives one finite ``|δ|`` per transition, and its losses read the sample's
    importance weights: all-ones weights leave the loss as it is, uneven ones change it."""
    job = small_job(algo, "train.prioritized=true")
    env, learner, trainer, collector = fake_trainer(
        job, tmp_path, warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10
    )
    trainer.run(collector)
    env.close()
    assert is_prioritized(trainer.buffer_cf) and trainer.counters["cf_updates"] > 0
    sample = trainer.buffer_cf.sample()
    assert K.PRIORITY_WEIGHT in sample.keys()
    name = FRAME_LOSS[algo]
    losses = {}
    for kind in ("none", "ones", "uneven"):
        batch = sample.exclude(K.PRIORITY_WEIGHT)
        if kind != "none":
            w = torch.ones(16) if kind == "ones" else torch.linspace(0.05, 1.0, 16)
            batch.set(K.PRIORITY_WEIGHT, w)
        torch.manual_seed(0)  # the same target noise / sampled actions each time
        with torch.no_grad():
            losses[kind], priority = learner.loss(name, batch)
    assert priority.shape == (16,) and torch.isfinite(priority).all() and (priority >= 0).all()
    assert priority.std() > 0
    torch.testing.assert_close(losses["ones"], losses["none"])
    assert not torch.allclose(losses["uneven"], losses["none"])
    # an update writes the sample's new priorities, which the buffer takes
    batch = trainer.buffer_cf.sample()
    learner.update_frame(batch)
    assert batch[K.PRIORITY].shape == (16,) and torch.isfinite(batch[K.PRIORITY]).all()


def test_trainer_updates_priorities_anneals_beta_and_resumes(tmp_path):
    """Training with ``train.prioritized=true`` on the fake env: both buffers' priorities move away from the
    uniform start, beta is annealed toward 1 with the episodes, and a resumed trainer keeps the priority trees."""
    job = small_job("kddrl", "train.prioritized=true", "train.priority_beta=0.4")
    env, learner, trainer, collector = fake_trainer(
        job, tmp_path, warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10
    )
    trainer.run(collector)
    env.close()
    assert trainer.counters["cf_updates"] > 0 and trainer.counters["lc_updates"] > 0
    for rb in (trainer.buffer_cf, trainer.buffer_lc):
        tree = rb.sampler._sum_tree
        p = torch.tensor([tree[i] for i in range(len(rb))])
        assert p.std() > 0, "the priorities were never updated"
        assert 0.4 < rb.sampler.beta <= 1.0
    env, _, resumed, _ = fake_trainer(
        job, tmp_path, warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10
    )
    env.close()
    assert resumed.load(tmp_path) == 3
    for old, new in ((trainer.buffer_cf, resumed.buffer_cf), (trainer.buffer_lc, resumed.buffer_lc)):
        assert is_prioritized(new)
        assert [new.sampler._sum_tree[i] for i in range(len(old))] == [
            old.sampler._sum_tree[i] for i in range(len(old))
        ]


def test_tensor_trees_answer_as_segment_trees():
    """The trees of :class:`PortablePrioritizedSampler` where TorchRL's C++ extension does not load."""
    from kddrl_trl.training.priority_trees import TensorMinTree, TensorSumTree

    s, m = TensorSumTree(6), TensorMinTree(6)
    s[torch.tensor([0, 1, 2, 3])] = torch.tensor([1.0, 2.0, 0.0, 3.0])
    m[torch.tensor([0, 1, 2, 3])] = torch.tensor([1.0, 2.0, 0.5, 3.0])
    assert s.query(0, 4) == 6.0 and s.query(1, 3) == 2.0 and m.query(0, 4) == 0.5 and m.query(3, 6) == 3.0
    # cumulative sums 1, 3, 3, 6: a mass falls on the first index whose cumulative sum exceeds it (never a zero)
    assert s.scan_lower_bound(torch.tensor([0.0, 0.99, 1.0, 2.5, 3.0, 5.9])).tolist() == [0, 0, 1, 1, 3, 3]
    assert s[torch.tensor([3, 1])].tolist() == [3.0, 2.0]
