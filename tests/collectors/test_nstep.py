"""Option ``train.n_steps`` (issue 14, "Learning signal"): n-step returns in buffer L for every frame learner
(:class:`kddrl_trl.collectors.nstep.NStepReturns`), by hand and wired through training on the fake env."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from testkit import SMALL_NETS, compose_job, fake_trainer

from kddrl_trl import keys as K
from kddrl_trl.collectors.nstep import NStepReturns


def frames(steps: int = 6, done_at: int = 3) -> TensorDict:
    """Two rows of ``steps`` frames; row 0 ends an episode (a collision) at ``done_at``."""
    done = torch.zeros(2, steps, 1, dtype=torch.bool)
    done[0, done_at] = True
    t = torch.arange(steps).float().expand(2, steps).unsqueeze(-1)
    return TensorDict(
        {
            "obs": t,
            "next": TensorDict(
                {
                    "obs": t + 1,
                    K.LC_REWARD: torch.ones(2, steps, 1),
                    K.CF_REWARD: t.clone(),
                    "done": done,
                    "terminated": done.clone(),
                    K.LC_HELD: torch.nn.functional.one_hot(t.long().squeeze(-1) % 3, 3).float(),
                },
                [2, steps],
            ),
        },
        [2, steps],
    )


def test_nstep_returns_by_hand():
    td = frames()
    before = td.clone()
    out = NStepReturns(3, 0.5)(td)
    assert out[K.STEPS_TO_NEXT_OBS].squeeze(-1).tolist() == [[3, 3, 2, 1, 2, 1], [3, 3, 3, 3, 2, 1]]
    # the next state is the window's last frame's; a window that reaches the collision does not bootstrap
    assert out["next", "obs"].squeeze(-1).tolist() == [[3, 4, 4, 4, 6, 6], [3, 4, 5, 6, 6, 6]]
    assert out["next", "terminated"].squeeze(-1).tolist()[0] == [False, True, True, True, False, False]
    # r_t + 0.5 r_t+1 + 0.25 r_t+2 (cf reward = t), cut at the collision and at the batch end
    cf = out["next", *K.CF_REWARD].squeeze(-1)
    torch.testing.assert_close(cf[0], torch.tensor([0 + 0.5 + 0.5, 1 + 1 + 0.75, 2 + 1.5, 3.0, 4 + 2.5, 5.0]))
    torch.testing.assert_close(out["next", *K.LC_REWARD][1].squeeze(-1), torch.tensor([1.75] * 4 + [1.5, 1.0]))
    # the held lane-change action of the window's last frame, the raw frames untouched
    assert torch.equal(out["next", *K.LC_HELD][1, 0], before["next", *K.LC_HELD][1, 2])
    assert (td == before).all()


def test_one_step_is_the_identity_and_bad_values_are_refused():
    td = frames()
    assert NStepReturns(1, 0.99)(td) is td
    with pytest.raises(ValueError, match="n_steps"):
        NStepReturns(0, 0.99)
    with pytest.raises(ValueError, match="gamma"):
        NStepReturns(3, 1.5)
    with pytest.raises(ValueError, match="frames \\[rows, time\\]"):
        NStepReturns(3, 0.99)(td.reshape(-1))


@pytest.mark.parametrize("algo", ["kddrl", "peng", "d3qn_unified", "pasac_unified"])
def test_every_frame_learner_trains_on_nstep_returns(algo, tmp_path):
    """``train.n_steps=3``: buffer L holds k and the held action of the window's end; each learner's TD target
    discounts its bootstrap by gamma ** k (its loss changes with k) and training runs."""
    nets = SMALL_NETS.get(algo, ["algo.learner.d3qn.hidden=[16]", "algo.learner.td3.hidden=[16]"])
    job = compose_job(f"algo={algo}", "env.num_roads=2", "compile=false", "train.n_steps=3", *nets)
    assert job.train.n_steps == 3
    env, learner, trainer, collector = fake_trainer(
        job, tmp_path, warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10
    )
    history = trainer.run(collector)
    env.close()
    assert len(history) == 3 and trainer.counters["cf_updates"] > 0
    sample = trainer.buffer_cf.sample()
    k = sample[K.STEPS_TO_NEXT_OBS]
    assert k.min() >= 1 and k.max() == 3 and ("next", *K.LC_HELD) in sample.keys(True)
    name = {"kddrl": "cf_value", "peng": "cf_value", "d3qn_unified": "joint", "pasac_unified": "pasac"}[algo]
    one = sample.clone()  # the same batch read as one-step transitions: another TD target
    one.set(K.STEPS_TO_NEXT_OBS, torch.ones_like(k))
    losses = []
    for batch in (sample, one):
        torch.manual_seed(0)  # the same target-smoothing noise / sampled actions in both
        with torch.no_grad():
            losses.append(learner.loss(name, batch)[0].sum())
    # the bootstrap term differs (gamma ** k against gamma; small while the critics are young): exact inequality
    assert torch.isfinite(losses[0]) and not torch.equal(losses[0], losses[1])
