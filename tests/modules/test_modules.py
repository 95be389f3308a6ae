"""Fusion (Eq. 23), shared embedding (Eq. 24), agent states (Eq. 24, 30) and the gradient routing of the
shared embedding through real TorchRL losses (DQNLoss double+dueling, TD3Loss) — kddrl_trl.modules."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.data import Bounded, OneHot
from torchrl.modules import MLP, Actor, QValueActor, ValueOperator
from torchrl.modules.models import DuelingMlpDQNet
from torchrl.objectives import DQNLoss, SoftUpdate, TD3Loss, ValueEstimators

from kddrl_trl import keys as K
from kddrl_trl.modules import (
    BASE_DIM,
    PriorFusion,
    SharedEmbedding,
    StateScale,
    build_agent_states,
    cf_obs_dim,
    cf_state,
    detach_embedding,
    embedding_parameters,
    lc_obs_dim,
    lc_state,
    make_shared_embedding,
    make_target_embedding,
    soft_update_embedding_,
)

torch.set_num_threads(1)

BATCHES = [(), (4,), (4, 7)]
D = 16


def _obs(batch, g):
    b = tuple(batch)
    rel = torch.randn(*b, 6, 4, generator=g) * torch.tensor([3.0, 60.0, 1.0, 5.0])
    return {
        K.EGO_STATE: torch.stack(
            [torch.rand(b, generator=g) * 420, 20 + 15 * torch.rand(b, generator=g), torch.randn(b, generator=g) * 0.5],
            -1,
        ),
        K.EGO_ACCEL: (torch.rand(*b, 1, generator=g) - 0.5) * 10,
        K.NEIGHBORS_REL: rel,
        K.NEIGHBORS_MASK: torch.rand(*b, 6, generator=g) > 0.3,
        K.PRED_KEY_GAPS: torch.randn(*b, 3, 2, generator=g) * 60,
        K.PRIOR_P_MOBIL: torch.softmax(torch.randn(*b, 3, generator=g) * 2, -1),
        K.PRIOR_P_LCGAN: torch.softmax(torch.randn(*b, 3, generator=g), -1),
    }


def make_batch(batch=(8,), seed=0, next_=True) -> TensorDict:
    """Hand-made batch with the transform keys written directly (the transforms are another issue's)."""
    g = torch.Generator().manual_seed(seed)
    b = tuple(batch)
    td = TensorDict(_obs(b, g), batch_size=b)
    td[K.LC_ACTION] = nn.functional.one_hot(torch.randint(3, b, generator=g), 3).float()
    td[K.CF_ACTION] = (torch.rand(*b, 1, generator=g) - 0.5) * 10
    if next_:
        nxt = TensorDict(_obs(b, g), batch_size=b)
        nxt[K.LC_REWARD] = torch.randn(*b, 1, generator=g)
        nxt[K.CF_REWARD] = torch.randn(*b, 1, generator=g)
        nxt["done"] = torch.zeros(*b, 1, dtype=torch.bool)
        nxt["terminated"] = torch.zeros(*b, 1, dtype=torch.bool)
        td["next"] = nxt
    return td


def _nonzero(p: torch.Tensor) -> bool:
    return p.grad is not None and bool(p.grad.abs().sum() > 0)


def _no_grad(params) -> bool:
    return all(p.grad is None or not bool(p.grad.abs().sum() > 0) for p in params)


# --------------------------------------------------------------------------------------------- shapes
@pytest.mark.parametrize("batch", BATCHES)
def test_prior_fusion_shapes(batch):
    td = make_batch(batch, next_=False)
    out = PriorFusion(out_features=8, hidden=16)(td)
    p_lc = out[K.PRIOR_P_LC]
    assert p_lc.shape == (*batch, 8)
    assert torch.isfinite(p_lc).all() and p_lc.abs().max() <= 1


@pytest.mark.parametrize("batch", BATCHES)
def test_shared_embedding_shapes(batch):
    emb = make_shared_embedding(d=D, hidden=32)
    assert isinstance(emb, TensorDictSequential)
    out = emb(make_batch(batch, next_=False))
    assert out[K.PRIOR_P_LC].shape == (*batch, D)
    assert out[K.EMBED_S_E].shape == (*batch, D)
    assert torch.isfinite(out[K.EMBED_S_E]).all()


@pytest.mark.parametrize("batch", BATCHES)
@pytest.mark.parametrize("embed", [True, False])
def test_state_builder_shapes(batch, embed):
    td = make_batch(batch, next_=False)
    if embed:
        make_shared_embedding(d=D)(td)
    d = D if embed else 0
    lc = lc_state(embed=embed)(td)[K.LC_OBS]
    cf = cf_state(embed=embed)(td)[K.CF_OBS]
    assert lc.shape == (*batch, lc_obs_dim(d)) == (*batch, 33 + d)
    assert cf.shape == (*batch, cf_obs_dim(d)) == (*batch, 37 + d)
    assert torch.isfinite(lc).all() and torch.isfinite(cf).all()
    assert lc.abs().max() <= StateScale().clip and cf.abs().max() <= StateScale().clip


def test_ablation_variants():
    td = make_batch((5,), next_=False)
    gaps_only = make_shared_embedding(d=D, priors=False)  # "without LG"
    assert list(gaps_only.in_keys) == [K.PRED_KEY_GAPS]
    out = gaps_only(td.exclude(K.PRIOR_P_MOBIL, K.PRIOR_P_LCGAN))
    assert out[K.EMBED_S_E].shape == (5, D) and K.PRIOR_P_LC not in out.keys(True)
    prior_only = make_shared_embedding(d=D, key_gaps=False, prior_dim=4)  # d3qn_td3_lg
    assert set(prior_only.in_keys) == {K.PRIOR_P_LCGAN, K.PRIOR_P_MOBIL}
    out = prior_only(td.exclude(K.PRED_KEY_GAPS))
    assert out[K.PRIOR_P_LC].shape == (5, 4) and out[K.EMBED_S_E].shape == (5, D)
    assert make_shared_embedding(priors=False, key_gaps=False) is None  # d3qn_td3
    assert embedding_parameters(None) == []
    with pytest.raises(ValueError):
        SharedEmbedding(prior_dim=None, key_gaps=False)


def test_embedding_reads_its_inputs_and_clips_gaps():
    torch.manual_seed(0)
    emb = make_shared_embedding(d=D)
    td = make_batch((3,), next_=False)
    base = emb(td.clone())[K.EMBED_S_E]
    for key in (K.PRIOR_P_MOBIL, K.PRIOR_P_LCGAN, K.PRED_KEY_GAPS):
        t = td.clone()
        t[key] = t[key].flip(-1) + 0.5
        assert not torch.allclose(emb(t)[K.EMBED_S_E], base), key
    # gaps are scaled by 100 m and clipped at ±5: 500 m and a 1e6 m sentinel give the same s_e
    a, b = td.clone(), td.clone()
    a[K.PRED_KEY_GAPS] = torch.full((3, 3, 2), 500.0)
    b[K.PRED_KEY_GAPS] = torch.full((3, 3, 2), 1e6)
    assert torch.allclose(emb(a)[K.EMBED_S_E], emb(b)[K.EMBED_S_E])


def test_state_scaling_and_absent_slots():
    rel = torch.arange(24.0).reshape(6, 4) + 1
    mask = torch.tensor([True, False, True, False, False, True])
    td = TensorDict(
        {
            K.EGO_STATE: torch.tensor([200.0, 30.0, 1.0]),
            K.NEIGHBORS_REL: rel,
            K.NEIGHBORS_MASK: mask,
            K.LC_ACTION: torch.tensor([0.0, 1.0, 0.0]),
            K.EGO_ACCEL: torch.tensor([-2.5]),
            K.EMBED_S_E: torch.full((D,), 0.25),
        },
        [],
    )
    lc = lc_state(embed=False)(td.clone())[K.LC_OBS]
    torch.testing.assert_close(lc[:3], torch.tensor([2.0, 0.6, 0.2]))
    expected_rel = torch.where(mask[:, None], rel / torch.tensor([10.0, 100.0, 5.0, 50.0]), 0.0).clamp(-5, 5)
    torch.testing.assert_close(lc[3:27], expected_rel.flatten())
    torch.testing.assert_close(lc[27:33], mask.float())
    cf = cf_state()(td.clone())[K.CF_OBS]
    assert cf.shape == (BASE_DIM + D + 4,)
    torch.testing.assert_close(cf[:BASE_DIM], lc)
    torch.testing.assert_close(cf[BASE_DIM : BASE_DIM + D], torch.full((D,), 0.25))
    torch.testing.assert_close(cf[-4:], torch.tensor([0.0, 1.0, 0.0, -0.5]))


def test_headway_and_ttc_extras_by_hand():
    """``algo.state_extras`` (issue 14): known gaps and speeds give known THW / TTC, scaled by 2 s, capped at 10 s."""
    from kddrl_trl.modules import headway_features

    # rows: closing in; leader faster; no leader; ego standing behind a standing leader; overlap; far and slow
    ego_v = torch.tensor([20.0, 25.0, 30.0, 0.0, 10.0, 5.0])
    dy = torch.tensor([35.0, 55.0, 40.0, 15.0, 3.0, 205.0])  # front to front: gap = dy - 5 m
    dvy = torch.tensor([-5.0, 2.0, 0.0, 0.0, -1.0, -1.0])  # leader minus ego
    present = torch.tensor([True, True, False, True, True, True])
    ego = torch.stack([torch.zeros(6), ego_v, torch.zeros(6)], -1)
    rel = torch.zeros(6, 6, 4)
    rel[:, 1, 1], rel[:, 1, 3] = dy, dvy
    mask = torch.zeros(6, 6, dtype=torch.bool)
    mask[:, 1] = present
    mask[:, 0] = True  # other slots do not matter
    rel[:, 0, 1], rel[:, 0, 3] = 6.0, -30.0
    thw, ttc = headway_features(ego, rel, mask).unbind(-1)
    #                                  30/20   50/25  none    standing  0 gap  200/5 = 40 -> cap
    torch.testing.assert_close(thw * 2, torch.tensor([1.5, 2.0, 10.0, 10.0, 0.0, 10.0]))
    #                                  30/5  opening  none  not closing  0 gap  200/1 -> cap
    torch.testing.assert_close(ttc * 2, torch.tensor([6.0, 10.0, 10.0, 10.0, 0.0, 10.0]))
    td = TensorDict(
        {
            K.EGO_STATE: ego,
            K.NEIGHBORS_REL: rel,
            K.NEIGHBORS_MASK: mask,
            K.LC_ACTION: torch.zeros(6, 3),
            K.EGO_ACCEL: torch.zeros(6, 1),
        },
        [6],
    )
    for extras in (("thw", "ttc"), ("ttc", "thw")):  # always in STATE_EXTRAS order, appended last
        lc = lc_state(embed=False, extras=extras)(td.clone())[K.LC_OBS]
        cf = cf_state(embed=False, extras=extras)(td.clone())[K.CF_OBS]
        assert lc.shape[-1] == lc_obs_dim(0, extras=extras) == BASE_DIM + 2
        assert cf.shape[-1] == cf_obs_dim(0, extras=extras) == cf_obs_dim(0) + 2
        torch.testing.assert_close(lc[:, :BASE_DIM], lc_state(embed=False)(td.clone())[K.LC_OBS])
        torch.testing.assert_close(lc[:, -2:], torch.stack([thw, ttc], -1))
        torch.testing.assert_close(cf[:, -2:], torch.stack([thw, ttc], -1))
    only = lc_state(embed=False, extras=["ttc"])(td.clone())[K.LC_OBS]
    assert only.shape[-1] == BASE_DIM + 1 and torch.equal(only[:, -1], ttc)
    for bad in (["tth"], ["thw", "thw"]):
        with pytest.raises(ValueError, match="algo.state_extras"):
            lc_state(embed=False, extras=bad)


def test_detach_flag_and_detach_embedding():
    emb = make_shared_embedding(d=D)
    td = emb(make_batch((4,), next_=False))
    assert td[K.EMBED_S_E].requires_grad
    assert not lc_state(detach_s_e=True)(td)[K.LC_OBS].requires_grad  # nothing to backprop into
    assert not cf_state(detach_s_e=True)(td)[K.CF_OBS].requires_grad
    td = emb(make_batch((4,), next_=False))
    cf_state()(td)
    det = detach_embedding(td)
    assert not det[K.CF_OBS].requires_grad and not det[K.EMBED_S_E].requires_grad
    assert td[K.CF_OBS].requires_grad  # the input is not modified
    td[K.CF_OBS].sum().backward()
    assert all(_nonzero(p) for p in embedding_parameters(emb))


def test_build_agent_states_next_and_target():
    torch.manual_seed(0)
    emb = make_shared_embedding(d=D)
    target = make_target_embedding(emb)
    assert all(not p.requires_grad for p in target.parameters())
    with torch.no_grad():  # make online and target differ
        for p in emb.parameters():
            p.add_(0.1)
    batch = make_batch((6,))
    keys_before = set(batch.keys(True, True))
    out = build_agent_states(batch, emb, lc_state(), cf_state(), target_embedding=target)
    assert set(batch.keys(True, True)) == keys_before  # the sample is untouched
    assert out[K.LC_OBS].requires_grad and out[K.CF_OBS].requires_grad
    assert not out["next", K.LC_OBS].requires_grad and not out["next", K.CF_OBS].requires_grad
    torch.testing.assert_close(out["next", K.LC_ACTION], batch[K.LC_ACTION])  # held action copied
    torch.testing.assert_close(out["next", K.EMBED_S_E], target(batch["next"].clone())[K.EMBED_S_E])
    assert not torch.allclose(out["next", K.EMBED_S_E], emb(batch["next"].clone())[K.EMBED_S_E])
    # a collector-written next lane-change action is kept
    b2 = batch.clone()
    b2["next", K.LC_ACTION] = torch.zeros(6, 3)
    assert (build_agent_states(b2, emb, cf_state())["next", K.LC_ACTION] == 0).all()
    # no embedding: the pure D3QN+TD3 state
    plain = build_agent_states(batch, None, lc_state(embed=False), cf_state(embed=False))
    assert plain[K.LC_OBS].shape == (6, 33) and plain["next", K.CF_OBS].shape == (6, 37)
    # soft update
    soft_update_embedding_(target, emb, 1.0)
    for t, s in zip(target.parameters(), emb.parameters()):
        torch.testing.assert_close(t, s.detach())
        assert not t.requires_grad


# -------------------------------------------------------------------------------- gradient routing
class _Scale(nn.Module):
    def __init__(self, k: float):
        super().__init__()
        self.k = k

    def forward(self, x):
        return self.k * x


class _QNet(nn.Module):
    def __init__(self, obs_dim: int):
        super().__init__()
        self.mlp = MLP(in_features=obs_dim + 1, out_features=1, num_cells=[32])

    def forward(self, obs, act):
        return self.mlp(torch.cat([obs, act / 5.0], -1))


def make_agents(d: int = D):
    lc_dim, cf_dim = lc_obs_dim(d), cf_obs_dim(d)
    qnet = DuelingMlpDQNet(
        3,
        mlp_kwargs_feature={"in_features": lc_dim, "num_cells": [32], "out_features": 32},
        mlp_kwargs_output={"num_cells": 32},
    )
    q_actor = QValueActor(
        qnet,
        in_keys=[K.LC_OBS],
        spec=OneHot(3),
        action_key=K.LC_ACTION,
        action_value_key=("lc", "action_value"),
        chosen_action_value_key=("lc", "chosen_action_value"),
    )
    dqn = DQNLoss(q_actor, double_dqn=True, delay_value=True, action_space="one-hot")
    dqn.set_keys(
        action=K.LC_ACTION,
        action_value=("lc", "action_value"),
        value=("lc", "chosen_action_value"),
        reward=K.LC_REWARD,
        done="done",
        terminated="terminated",
        priority=("lc", "td_error"),
    )
    dqn.make_value_estimator(ValueEstimators.TD0, gamma=0.99)

    actor = Actor(
        nn.Sequential(MLP(in_features=cf_dim, out_features=1, num_cells=[32]), nn.Tanh(), _Scale(5.0)),
        in_keys=[K.CF_OBS],
        out_keys=[K.CF_ACTION],
        spec=Bounded(-5.0, 5.0, (1,)),
    )
    critic = ValueOperator(_QNet(cf_dim), in_keys=[K.CF_OBS, K.CF_ACTION], out_keys=[("cf", "state_action_value")])
    td3 = TD3Loss(actor, critic, bounds=(-5.0, 5.0), num_qvalue_nets=2)
    td3.set_keys(
        action=K.CF_ACTION,
        state_action_value=("cf", "state_action_value"),
        reward=K.CF_REWARD,
        done="done",
        terminated="terminated",
        priority=("cf", "td_error"),
    )
    td3.make_value_estimator(ValueEstimators.TD0, gamma=0.99)
    dqn.updater, td3.updater = SoftUpdate(dqn, tau=0.005), SoftUpdate(td3, tau=0.005)
    return q_actor, dqn, actor, td3


def _targets(loss):
    out = [p for name, p in loss.named_parameters() if "target_" in name] + [
        t for name, t in loss.named_buffers() if "target_" in name
    ]
    assert out, "the loss keeps target parameters"
    return out


@pytest.fixture
def setup():
    torch.manual_seed(0)
    emb = make_shared_embedding(d=D, hidden=32)
    target_emb = make_target_embedding(emb)
    q_actor, dqn, actor, td3 = make_agents()
    return emb, target_emb, q_actor, dqn, actor, td3


def _zero(*modules):
    for m in modules:
        for p in m.parameters():
            p.grad = None


def test_losses_do_not_own_the_embedding(setup):
    emb, _, _, dqn, _, td3 = setup
    ids = {id(p) for p in embedding_parameters(emb)}
    assert ids and ids.isdisjoint(id(p) for p in dqn.parameters())
    assert ids.isdisjoint(id(p) for p in td3.parameters())


def test_dqn_td_loss_trains_the_embedding(setup):
    emb, target_emb, q_actor, dqn, _, _ = setup
    states = build_agent_states(make_batch((8,)), emb, lc_state(), target_embedding=target_emb)
    loss = dqn(states)["loss"]
    assert loss.ndim == 0 and torch.isfinite(loss)
    loss.backward()
    assert all(_nonzero(p) for p in embedding_parameters(emb))  # fusion + shared, every tensor
    assert any(_nonzero(p) for p in q_actor.parameters())
    assert all(p.grad is None for p in _targets(dqn))
    assert all(p.grad is None for p in target_emb.parameters())
    # semi-gradient: with the root path detached nothing reaches the embedding (the next path is no-grad)
    _zero(emb)
    dqn(detach_embedding(build_agent_states(make_batch((8,)), emb, lc_state())))["loss"].backward()
    assert _no_grad(embedding_parameters(emb))


def test_td3_value_loss_trains_the_embedding(setup):
    emb, target_emb, _, _, _, td3 = setup
    states = build_agent_states(make_batch((8,)), emb, cf_state(), target_embedding=target_emb)
    loss_q, _ = td3.value_loss(states)
    assert torch.isfinite(loss_q)
    loss_q.backward()
    assert all(_nonzero(p) for p in embedding_parameters(emb))
    assert any(_nonzero(p) for p in td3.qvalue_network_params.values(True, True))
    assert _no_grad(td3.actor_network_params.values(True, True))
    assert all(p.grad is None for p in _targets(td3))
    assert all(p.grad is None for p in target_emb.parameters())


def test_td3_actor_loss_does_not_train_the_embedding(setup):
    emb, target_emb, _, _, _, td3 = setup
    states = build_agent_states(make_batch((8,)), emb, cf_state(), target_embedding=target_emb)
    loss_a, _ = td3.actor_loss(detach_embedding(states))
    assert torch.isfinite(loss_a)
    loss_a.backward()
    assert _no_grad(embedding_parameters(emb))
    assert any(_nonzero(p) for p in td3.actor_network_params.values(True, True))
    assert _no_grad(td3.qvalue_network_params.values(True, True))
    assert all(p.grad is None for p in _targets(td3))
    # control: without detach_embedding the actor loss *would* reach the embedding
    _zero(emb, td3)
    states = build_agent_states(make_batch((8,)), emb, cf_state(), target_embedding=target_emb)
    td3.actor_loss(states)[0].backward()
    assert any(_nonzero(p) for p in embedding_parameters(emb))


def test_one_shared_update_step(setup):
    """One instance, both value losses, one embedding optimiser: both updates move the same tensors."""
    emb, target_emb, _, dqn, _, td3 = setup
    opt = torch.optim.Adam(embedding_parameters(emb), lr=1e-2)
    before = [p.detach().clone() for p in embedding_parameters(emb)]
    target_before = [p.detach().clone() for p in target_emb.parameters()]
    for loss_fn in (lambda s: dqn(s)["loss"], lambda s: td3.value_loss(s)[0]):
        opt.zero_grad()
        states = build_agent_states(make_batch((8,)), emb, lc_state(), cf_state(), target_embedding=target_emb)
        loss_fn(states).backward()
        opt.step()
    assert all(not torch.equal(a, p) for a, p in zip(before, embedding_parameters(emb)))
    assert all(torch.equal(a, p) for a, p in zip(target_before, target_emb.parameters()))
    dqn.updater.step()
    td3.updater.step()
    soft_update_embedding_(target_emb, emb, 0.005)  # alongside the losses' SoftUpdate
    assert all(not torch.equal(a, p) for a, p in zip(target_before, target_emb.parameters()))


def test_acting_policies_compose(setup):
    emb, _, q_actor, _, actor, _ = setup
    lc_policy = TensorDictSequential(emb, lc_state(), q_actor)
    cf_policy = TensorDictSequential(emb, cf_state(), actor)
    with torch.no_grad():
        td = make_batch((), next_=False)
        td = lc_policy(td)
        assert td[K.LC_ACTION].shape == (3,) and td[K.LC_ACTION].sum() == 1
        td = cf_policy(td)
        assert td[K.CF_ACTION].shape == (1,) and td[K.CF_ACTION].abs() <= 5
