"""The two agents' updates: which parameters each loss moves, targets, shared embedding, checkpoints."""

from __future__ import annotations

import io

import pytest
import torch
from testkit import SMALL, fake_samples
from torchrl.envs import TransformedEnv

from kddrl_trl import keys as K
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.training import HierarchicalLearner
from kddrl_trl.transforms import DecisionClock


@pytest.fixture(scope="module")
def batches():
    """A buffer-L sample and a buffer-H sample collected from the fake env with the full transform stack."""
    (frames,), (macros,) = fake_samples(1, 1)
    return frames, macros


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
    assert torch.isfinite(out["loss_lc"])
    moved = changed(before, learner)
    assert g["q"] <= moved and g["embedding"] <= moved
    assert moved & g["q_target"]  # soft update (Eq. 5)
    assert not moved & (g["critic"] | g["actor"] | g["cf_targets"])


def test_actor_loss_never_reaches_the_embedding(batches):
    frames, _ = batches
    learner = HierarchicalLearner(**SMALL)
    learner.loss("cf_actor", frames)[0].backward()
    assert all(p.grad is None for p in learner.embedding.parameters())
    assert any(p.grad is not None for p in learner.cf_loss.actor_network_params.values(True, True))
    learner.zero_grad()
    learner.loss("cf_value", frames)[0].backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in learner.embedding.parameters())
    assert all(p.grad is None for p in learner.target_embedding.parameters())


def test_plain_states_without_embedding(batches):
    frames, macros = batches
    learner = HierarchicalLearner(
        priors=False, key_gaps=False, d3qn={"hidden": [16], "dueling": False}, td3={"hidden": [16]}
    )
    assert learner.embedding is None and learner.opt_embed is None
    assert K.PRIOR_P_MOBIL not in learner.buffer_keys()
    learner.update_cf(frames)
    learner.update_lc(macros)


def test_kddrl_and_its_ablations_learn_with_the_headway_and_ttc_extras(batches):
    """``algo.state_extras=[thw,ttc]`` on KDDRL (embedding) and the plain D3QN+TD3 ablation: both agents' states
    end with the two features, the networks take them, the policy acts and both updates run."""
    from kddrl_trl.modules import cf_obs_dim, headway_features, lc_obs_dim

    frames, macros = batches
    for kw, d in ((SMALL, SMALL["embed_dim"]), ({**SMALL, "priors": False, "key_gaps": False}, 0)):
        learner = HierarchicalLearner(**kw, state_extras=("thw", "ttc"))
        lc = learner.lc_state(learner.embedding(frames.clone()) if d else frames.clone())[K.LC_OBS]
        cf = learner.cf_state(learner.embedding(frames.clone()) if d else frames.clone())[K.CF_OBS]
        assert lc.shape[-1] == lc_obs_dim(d) + 2 and cf.shape[-1] == cf_obs_dim(d) + 2
        expected = headway_features(frames[K.EGO_STATE], frames[K.NEIGHBORS_REL], frames[K.NEIGHBORS_MASK])
        torch.testing.assert_close(lc[..., -2:], expected)
        torch.testing.assert_close(cf[..., -2:], expected)
        obs = frames.exclude(K.CF_ACTION).clone().set(K.LC_HELD, frames[K.LC_ACTION])  # the decision clock's key
        acted = learner.policy(explore=False)(obs)
        assert acted[K.CF_ACTION].shape == frames[K.CF_ACTION].shape and acted[K.CF_ACTION].abs().le(5).all()
        before = snapshot(learner)
        learner.update_cf(frames)
        learner.update_lc(macros)
        assert changed(before, learner)


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


# ------------------------------------------------------------------------------------------------ issue 14
def test_td3_target_reads_the_new_lane_change_decision_on_the_frame_before_a_decision():
    """F6: s_TD3^{t+1} holds a_D3QN^{t+1} (Eq. 30). Where the next frame is a decision frame that is the D3QN's new
    choice (here forced to keep by the next state's mask), not the action held during the ending interval; elsewhere
    it is the held one. The old code copied the root action on every row."""
    torch.manual_seed(0)
    learner = HierarchicalLearner(priors=False, key_gaps=False, **{k: v for k, v in SMALL.items() if k != "embed_dim"})
    env = TransformedEnv(FakeHighwayEnv(num_roads=4, seed=0), DecisionClock(5))
    roll = env.rollout(3, learner.policy(explore=False), break_when_any_done=False).reshape(-1)
    left = torch.zeros(roll.batch_size[0], 3)
    left[:, K.LEFT] = 1.0
    roll.set(K.LC_ACTION, left)  # held: a left change
    keep_only = torch.zeros(roll.batch_size[0], 3, dtype=torch.bool)
    keep_only[:, K.KEEP] = True
    roll.set(("next", *K.LC_ACTION_MASK), keep_only)  # at t+1 only keep is allowed
    decide = torch.arange(roll.batch_size[0]) % 2 == 0
    roll.set(("next", *K.LC_DECIDE), decide[:, None])
    seen = {}

    def capture(states):
        seen["states"] = states
        return states.get(K.CF_OBS).sum() * 0.0, {"td_error": torch.zeros(states.shape)}

    learner.cf_loss.value_loss = capture
    learner.loss("cf_value", roll.select(*learner.buffer_keys(), strict=False))
    next_action = seen["states"].get(("next", *K.CF_OBS))[:, -4:-1]  # the one-hot a_D3QN block of Eq. 30
    assert (next_action[decide].argmax(-1) == K.KEEP).all()
    assert (next_action[~decide].argmax(-1) == K.LEFT).all()
    assert (seen["states"].get(K.CF_OBS)[:, -4:-1].argmax(-1) == K.LEFT).all()


def test_double_dqn_target_argmax_respects_the_next_action_mask():
    """F1: TorchRL's DQNLoss takes the double-DQN argmax (Eq. 4) with the masked Q actor on the next state, so an
    action the next mask forbids (e.g. an unsafe lane change) never enters the target."""
    from tensordict import TensorDict

    from kddrl_trl.objectives import make_d3qn

    torch.manual_seed(0)
    parts = make_d3qn(4, hidden=[8], gamma=0.5)
    obs, nobs = torch.randn(1, 4), torch.randn(1, 4)
    with torch.no_grad():
        q_s = parts.actor.module[0](TensorDict({K.LC_OBS: obs}, [1]))[K.LC_ACTION_VALUE][0]
        q_next = parts.actor.module[0](TensorDict({K.LC_OBS: nobs}, [1]))[K.LC_ACTION_VALUE][0]
    best = int(q_next.argmax())
    mask = torch.ones(1, 3, dtype=torch.bool)
    mask[0, best] = False  # the next state's best action is forbidden
    td = TensorDict(
        {
            K.LC_OBS: obs,
            K.LC_ACTION: torch.tensor([[0.0, 1.0, 0.0]]),
            K.LC_ACTION_MASK: torch.ones(1, 3, dtype=torch.bool),
            "next": {
                K.LC_OBS: nobs,
                K.LC_ACTION_MASK: mask,
                K.LC_REWARD: torch.zeros(1, 1),
                "done": torch.zeros(1, 1, dtype=torch.bool),
                "terminated": torch.zeros(1, 1, dtype=torch.bool),
            },
        },
        [1],
    )
    loss = float(parts.loss(td)["loss"])
    allowed = q_next.masked_fill(~mask[0], -torch.inf).max()  # the target network is still the online copy
    assert loss == pytest.approx(float((q_s[K.KEEP] - 0.5 * allowed) ** 2), rel=1e-5)
    assert loss != pytest.approx(float((q_s[K.KEEP] - 0.5 * q_next.max()) ** 2), rel=1e-5)


def test_acting_noise_is_clipped_as_in_algorithm_1():
    """F2: a = mu(s) + clip(eps, -c, c) (Algorithm 1 line 32), then the bounds; TorchRL's module alone does not clip."""
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from kddrl_trl.objectives import make_td3
    from kddrl_trl.objectives.td3 import ClippedGaussianModule

    parts = make_td3(4, hidden=[8], exploration_sigma=50.0, exploration_clip=0.5)
    assert isinstance(parts.explore, ClippedGaussianModule)
    td = TensorDict({K.CF_ACTION: torch.zeros(10_000, 1)}, [10_000])
    with set_exploration_type(ExplorationType.RANDOM):
        noisy = parts.explore(td.clone())[K.CF_ACTION]
    assert noisy.abs().max() <= 0.5 + 1e-6 and noisy.std() > 0.3
    with set_exploration_type(ExplorationType.RANDOM):
        unclipped = make_td3(4, hidden=[8], exploration_sigma=50.0, exploration_clip=None).explore(td.clone())
    assert unclipped[K.CF_ACTION].abs().max() > 4.0  # only the action bounds [-5, 5]


def test_semi_mdp_option_discounts_the_bootstrap_by_gamma_to_the_frames_spanned():
    """algo.learner.d3qn.semi_mdp: R + gamma^k max Q(s', .) with k = ("next", "lc", "macro_frames"); default: gamma."""
    from tensordict import TensorDict

    from kddrl_trl.objectives import make_d3qn

    def loss_of(semi_mdp: bool) -> tuple[float, torch.Tensor, torch.Tensor]:
        torch.manual_seed(0)
        parts = make_d3qn(4, hidden=[8], gamma=0.9, double=False, semi_mdp=semi_mdp)
        obs, nobs = torch.randn(1, 4), torch.randn(1, 4)
        with torch.no_grad():
            q_s = parts.actor.module[0](TensorDict({K.LC_OBS: obs}, [1]))[K.LC_ACTION_VALUE][0]
            q_n = parts.actor.module[0](TensorDict({K.LC_OBS: nobs}, [1]))[K.LC_ACTION_VALUE][0]
        ones = torch.ones(1, 3, dtype=torch.bool)
        td = TensorDict(
            {
                K.LC_OBS: obs,
                K.LC_ACTION: torch.tensor([[0.0, 1.0, 0.0]]),
                K.LC_ACTION_MASK: ones,
                "next": {
                    K.LC_OBS: nobs,
                    K.LC_ACTION_MASK: ones,
                    K.LC_REWARD: torch.ones(1, 1),
                    K.LC_MACRO_FRAMES: torch.tensor([[20]]),
                    "done": torch.zeros(1, 1, dtype=torch.bool),
                    "terminated": torch.zeros(1, 1, dtype=torch.bool),
                },
            },
            [1],
        )
        return float(parts.loss(td)["loss"]), q_s[K.KEEP], q_n.max()

    loss, q, q_next = loss_of(False)
    assert loss == pytest.approx(float((q - (1.0 + 0.9 * q_next)) ** 2), rel=1e-5)
    loss, q, q_next = loss_of(True)
    assert loss == pytest.approx(float((q - (1.0 + 0.9**20 * q_next)) ** 2), rel=1e-5)
