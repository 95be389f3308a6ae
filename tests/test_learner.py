"""The two agents' updates: which parameters each loss moves, targets, shared embedding, checkpoints."""
from __future__ import annotations

import io

import pytest
import torch
from torchrl.envs import Compose, TransformedEnv

from kddrl_trl import keys as K
from kddrl_trl.collectors import DecisionClock, MultiTimescaleCollector
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.training import HierarchicalLearner, make_buffer
from kddrl_trl.transforms import make_kddrl_transforms

SMALL = {"embed_dim": 8, "embed_hidden": 16, "d3qn": {"hidden": [32, 32], "eps_decisions": 50},
         "td3": {"hidden": [32, 32]}}


@pytest.fixture(scope="module")
def batches():
    """A buffer-L sample and a buffer-H sample collected from the fake env with the full transform stack."""
    torch.manual_seed(0)
    env = TransformedEnv(FakeHighwayEnv(num_roads=4, seed=0), Compose(make_kddrl_transforms(), DecisionClock(5)))
    learner = HierarchicalLearner(**SMALL)
    rb_l, rb_h = make_buffer(5000, 32, 0), make_buffer(5000, 16, 0)
    mtc = MultiTimescaleCollector.from_env(env, learner.policy(), frames_per_env=40, frame_buffer=rb_l,
                                           macro_buffer=rb_h, frame_keys=learner.buffer_keys())
    next(iter(mtc))
    mtc.shutdown()
    return rb_l.sample(), rb_h.sample()


def tensors(module):
    """Every floating tensor of the state dict (parameters, and the targets TorchRL keeps as buffers)."""
    return {n: t for n, t in module.state_dict().items() if t.is_floating_point() and t.dim() > 0}


def snapshot(module):
    return {n: t.detach().clone() for n, t in tensors(module).items()}


def changed(before, module):
    return {n for n, t in tensors(module).items() if not torch.equal(before[n], t.detach())}


def groups(learner):
    """State-dict names of the learner's tensors by role."""
    names = list(tensors(learner))
    return {
        "embedding": {n for n in names if n.startswith("embedding.")},
        "target_embedding": {n for n in names if n.startswith("target_embedding.")},
        "q": {n for n in names if n.startswith("lc_loss.value_network_params")},
        "q_target": {n for n in names if n.startswith("lc_loss.target_value_network_params")},
        "critic": {n for n in names if n.startswith("cf_loss.qvalue_network_params")},
        "actor": {n for n in names if n.startswith("cf_loss.actor_network_params")},
        "cf_targets": {n for n in names if n.startswith("cf_loss.target_")},
    }


def test_td3_update_moves_critic_and_embedding_then_actor_and_targets_on_the_delay(batches):
    frames, _ = batches
    torch.manual_seed(1)
    learner = HierarchicalLearner(**SMALL)
    g = groups(learner)
    assert all(g.values()), g
    before = snapshot(learner)
    learner.update_cf(frames)  # update 1 of policy_delay=2: critic (+ embedding) only
    moved = changed(before, learner)
    assert g["critic"] <= moved and g["embedding"] <= moved
    assert not moved & (g["actor"] | g["cf_targets"] | g["q"] | g["q_target"] | g["target_embedding"])
    before = snapshot(learner)
    learner.update_cf(frames)  # update 2: critic, actor, soft target updates
    moved = changed(before, learner)
    assert g["actor"] <= moved and g["critic"] <= moved
    assert g["target_embedding"] <= moved and (moved & g["cf_targets"])
    assert not moved & (g["q"] | g["q_target"])


def test_targets_follow_polyak_updates(batches):
    frames, _ = batches
    learner = HierarchicalLearner(**SMALL)
    tau = learner.embed_tau
    t0 = {n: p.detach().clone() for n, p in learner.target_embedding.named_parameters()}
    learner.update_cf(frames)
    learner.update_cf(frames)
    for n, p in learner.target_embedding.named_parameters():
        online = dict(learner.embedding.named_parameters())[n].detach()
        torch.testing.assert_close(p.detach(), t0[n] + tau * (online - t0[n]))  # Eq. 9-10 form, once


def test_d3qn_update_moves_q_and_embedding_not_td3(batches):
    _, macros = batches
    learner = HierarchicalLearner(**SMALL)
    g = groups(learner)
    before = snapshot(learner)
    out = learner.update_lc(macros)
    assert torch.isfinite(torch.tensor(out["loss_lc"]))
    moved = changed(before, learner)
    assert g["q"] <= moved and g["embedding"] <= moved
    assert moved & g["q_target"]  # soft update (Eq. 5)
    assert not moved & (g["critic"] | g["actor"] | g["cf_targets"])


def test_actor_loss_never_reaches_the_embedding(batches):
    frames, _ = batches
    learner = HierarchicalLearner(**SMALL)
    learner.loss("cf_actor", frames).backward()
    assert all(p.grad is None for p in learner.embedding.parameters())
    assert any(p.grad is not None for p in learner.cf_loss.actor_network_params.values(True, True))
    learner.zero_grad()
    learner.loss("cf_value", frames).backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in learner.embedding.parameters())
    assert all(p.grad is None for p in learner.target_embedding.parameters())


def test_plain_states_without_embedding(batches):
    frames, macros = batches
    learner = HierarchicalLearner(priors=False, key_gaps=False, d3qn={"hidden": [16], "dueling": False},
                                  td3={"hidden": [16]})
    assert learner.embedding is None and learner.opt_embed is None
    assert K.PRIOR_P_MOBIL not in learner.buffer_keys()
    learner.update_cf(frames)
    learner.update_lc(macros)


def test_greedy_policy_masks_invalid_commands_and_exploring_policy_respects_mask(batches):
    frames, _ = batches
    learner = HierarchicalLearner(**SMALL)
    td = frames.select(*[k for k in learner.buffer_keys() if k[0] != "next"]).exclude(K.LC_ACTION, K.CF_ACTION)
    mask = torch.zeros(td.shape[0], 3, dtype=torch.bool)
    mask[:, K.KEEP] = True
    mask[::2, K.RIGHT] = True
    td.set(K.LC_ACTION_MASK, mask)
    td.set(K.LC_DECIDE, torch.ones(td.shape[0], 1, dtype=torch.bool))
    td.set(K.LC_HELD, torch.nn.functional.one_hot(torch.full((td.shape[0],), K.KEEP), 3).float())
    for explore in (False, True):
        out = learner.policy(explore=explore)(td.clone())
        chosen = out[K.LC_ACTION].argmax(-1)
        assert mask.gather(1, chosen[:, None]).all()
        assert ((out[K.CF_ACTION] >= -5) & (out[K.CF_ACTION] <= 5)).all()


def test_full_state_dict_round_trip(batches):
    frames, macros = batches
    a = HierarchicalLearner(**SMALL)
    for _ in range(3):
        a.update_cf(frames)
    a.update_lc(macros)
    a.explore_step(7, 0)
    buf = io.BytesIO()
    torch.save(a.full_state_dict(), buf)  # as a checkpoint file holds it (no tensor shared with ``a``)
    buf.seek(0)
    state = torch.load(buf, weights_only=False)
    torch.manual_seed(123)
    b = HierarchicalLearner(**SMALL)
    b.load_full_state_dict(state)
    for (n, p), (_, q) in zip(a.state_dict().items(), b.state_dict().items()):
        torch.testing.assert_close(p, q, msg=n)
    assert b.lc_explore.eps == a.lc_explore.eps < 1.0
    assert int(b.counters[1]) == 3
    # optimiser state restored too: the next update is identical
    torch.manual_seed(5)
    a.update_cf(frames)
    torch.manual_seed(5)
    b.update_cf(frames)
    for (n, p), (_, q) in zip(a.state_dict().items(), b.state_dict().items()):
        torch.testing.assert_close(p, q, msg=n)
