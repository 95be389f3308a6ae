"""``training.trainer.minibatches``: one storage read for a collection batch's updates on a uniform buffer, the same
minibatches as one ``sample()`` per update; a prioritized buffer still drawn once per update."""

from __future__ import annotations

import torch
from tensordict import TensorDict

from kddrl_trl.training import make_buffer
from kddrl_trl.training.trainer import MINIBATCHES_PER_DRAW, minibatches


def _filled(prioritized=None, seed=7):
    rb = make_buffer(500, 16, seed, prioritized=prioritized)
    n = 300
    rb.extend(
        TensorDict(
            {
                "x": torch.arange(n, dtype=torch.float32)[:, None].repeat(1, 3),
                "next": {"y": -torch.arange(n), "done": torch.arange(n) % 2 == 0},
            },
            [n],
        )
    )
    return rb


def test_uniform_minibatches_are_the_per_update_samples_across_draws():
    n = MINIBATCHES_PER_DRAW + 6  # two storage reads
    ours, reference = _filled(), _filled()
    got = list(minibatches(ours, n))
    assert len(got) == n
    for batch in got:
        want = reference.sample()
        assert batch.batch_size == torch.Size([16])
        assert torch.equal(batch["x"], want["x"]) and torch.equal(batch["next", "y"], want["next", "y"])
        assert torch.equal(batch["next", "done"], want["next", "done"])
    assert torch.equal(ours.sample()["x"], reference.sample()["x"])  # the streams go on alike
    assert list(minibatches(ours, 0)) == []


def test_a_prioritized_buffer_is_sampled_after_each_priority_update():
    rb = _filled(prioritized=(1.0, 0.4))
    draws = []
    sample = rb.sample
    rb.sample = lambda *a, **kw: draws.append(a) or sample(*a, **kw)
    batches = minibatches(rb, 3)
    first = next(batches)
    assert len(draws) == 1 and first.batch_size == torch.Size([16])
    # all priority on item 5: the next minibatch, drawn only now, sees it
    rb.update_priority(torch.arange(300), torch.full((300,), 1e-9))
    rb.update_priority(torch.tensor([5]), torch.tensor([1e6]))
    second = next(batches)
    assert len(draws) == 2 and (second["x"][:, 0] == 5).all()
    assert len(list(batches)) == 1 and len(draws) == 3


def test_a_run_of_updates_is_read_at_once_and_a_non_finite_loss_names_its_update(tmp_path):
    """``Trainer._update``: the learner's losses (0-d tensors, unread per update: a GPU learner is not waited for)
    are read after the run, in update order; a NaN stops the training, naming the loss and the update it came
    from (here the actor loss, made every second update, of update 4 of the run)."""
    import math

    import pytest

    from kddrl_trl.training import Trainer

    calls = iter(range(1, 100))

    def update(batch):
        n = next(calls)
        out = {"loss_qvalue": torch.tensor(float(n))}
        if n % 2 == 0:
            out["loss_actor"] = torch.tensor(math.nan if n == 4 else -float(n))
        return out

    trainer = Trainer(None, (_filled(), _filled()), None, tmp_path, None, episodes=1, progress=False)
    losses = {}
    trainer._update(trainer.buffer_cf, 3, update, losses, "cf_updates")
    assert losses == {"loss_qvalue": [1.0, 2.0, 3.0], "loss_actor": [-2.0]} and trainer.counters["cf_updates"] == 3
    with pytest.raises(FloatingPointError, match=r"loss_actor = nan at cf_updates update 4 \(5 buffer-L"):
        trainer._update(trainer.buffer_cf, 2, update, losses, "cf_updates")


def test_a_seed_batchs_stacked_minibatches_are_each_seeds_own_step_by_step():
    """``seed_minibatches``: row ``i`` of step ``j`` is seed ``i`` 's ``j``-th minibatch alone while it takes the step
    (counts that end inside, at and past a storage read, and a seed that takes none), and its generator stream goes
    on as alone; a seed that sits a step out gets some other seed's rows."""
    from kddrl_trl.training.seed_batch_trainer import seed_minibatches

    counts = [MINIBATCHES_PER_DRAW + 6, 3, 0, 2 * MINIBATCHES_PER_DRAW, MINIBATCHES_PER_DRAW]
    ours = [_filled(seed=s) for s in range(len(counts))]
    alone = [list(minibatches(_filled(seed=s), n)) for s, n in enumerate(counts)]
    got = list(seed_minibatches(ours, counts))
    assert len(got) == max(counts)
    rows = {tuple(b["x"][:, 0].tolist()) for a in alone for b in a}
    for j, batch in enumerate(got):
        assert batch.batch_size == torch.Size([len(counts), 16])
        for i, n in enumerate(counts):
            if j < n:
                assert torch.equal(batch["x"][i], alone[i][j]["x"]), (i, j)
                assert torch.equal(batch["next", "done"][i], alone[i][j]["next", "done"]), (i, j)
            else:
                assert tuple(batch["x"][i, :, 0].tolist()) in rows  # a filler: another seed's minibatch
    for s, buf in enumerate(ours):
        reference = _filled(seed=s)
        list(minibatches(reference, counts[s]))
        assert torch.equal(buf.sample()["x"], reference.sample()["x"])
    assert list(seed_minibatches(ours, [0, 0])) == []
