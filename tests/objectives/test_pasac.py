"""PASACLoss (parameterised-action SAC), tested as TorchRL tests its losses: a batch built by hand with a "next"
subtree, which parameters each loss reaches, frozen targets, the temperatures, the value estimator."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torch.nn.functional import one_hot
from torchrl.envs.utils import ExplorationType, set_exploration_type

from kddrl_trl import keys as K
from kddrl_trl.objectives import make_pasac

B, D = 16, 6


def _state(gen: torch.Generator) -> dict:
    mask = torch.ones(B, 3, dtype=torch.bool)
    mask[::2, K.LEFT] = False  # half the rows cannot turn left
    return {K.JOINT_OBS: torch.randn(B, D, generator=gen), K.LC_ACTION_MASK: mask}


def batch(terminated: bool = False, seed: int = 0) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    flags = torch.full((B, 1), terminated)
    nxt = TensorDict(
        {
            **_state(gen),
            K.JOINT_REWARD: torch.randn(B, 1, generator=gen),
            "done": flags.clone(),
            "terminated": flags.clone(),
        },
        [B],
    )
    return TensorDict(
        {
            **_state(gen),
            K.LC_ACTION: one_hot(torch.randint(1, 3, (B,), generator=gen), 3).float(),
            K.CF_ACTION: torch.rand(B, 1, generator=gen) * 10 - 5,
            "next": nxt,
        },
        [B],
    )


@pytest.fixture
def parts():
    torch.manual_seed(0)
    return make_pasac(D, hidden=[32, 32], gamma=0.9, alpha_init=0.5)


def grads(loss_module, loss: torch.Tensor) -> set[str]:
    """Names of the loss module's parameters that ``loss`` sends a non-zero gradient to."""
    loss_module.zero_grad(set_to_none=True)
    loss.backward()
    return {n for n, p in loss_module.named_parameters() if p.grad is not None and p.grad.abs().sum() > 0}


def test_forward_returns_losses_and_detached_diagnostics(parts):
    out = parts.loss(batch())
    for key in ("loss_qvalue", "loss_actor", "loss_alpha_lane", "loss_alpha_param"):
        assert out[key].shape == () and torch.isfinite(out[key]) and out[key].requires_grad, key
    for key in ("alpha_lane", "alpha_param", "entropy_lane", "log_prob_param", "state_action_value", "target_value"):
        assert torch.isfinite(out[key]) and not out[key].requires_grad, key
    assert out["alpha_lane"] == pytest.approx(0.5) and out["alpha_param"] == pytest.approx(0.5)
    assert 0.0 <= float(out["entropy_lane"]) <= torch.log(torch.tensor(3.0))


def test_each_loss_reaches_only_its_own_parameters(parts):
    loss = parts.loss
    names = {n for n, _ in loss.named_parameters()}
    critic = {n for n in names if n.startswith("qvalue_network_params")}
    actor = {n for n in names if n.startswith("actor_network_params")}
    assert critic and actor and not any(n.startswith("target_") for n in names)  # targets are buffers
    assert grads(loss, loss(batch())["loss_qvalue"]) == critic
    assert grads(loss, loss(batch())["loss_actor"]) == actor  # both heads: categorical and tanh-Gaussian
    assert grads(loss, loss(batch())["loss_alpha_lane"]) == {"log_alpha_lane"}
    assert grads(loss, loss(batch())["loss_alpha_param"]) == {"log_alpha_param"}


def test_both_actor_heads_get_gradients(parts):
    loss = parts.loss
    loss.zero_grad(set_to_none=True)
    loss(batch())["loss_actor"].backward()
    last = [p for n, p in loss.named_parameters() if n.startswith("actor_network_params") and n.endswith("weight")][-1]
    rows = last.grad.abs().sum(-1)  # output rows: 3 logits, then loc and log_std of each of the 3 commands
    assert rows.shape == (9,) and (rows > 0).all()


def test_targets_stay_frozen_and_follow_the_soft_update(parts):
    loss = parts.loss
    target = {n: t.clone() for n, t in loss.target_qvalue_network_params.flatten_keys().items()}
    assert not any(t.requires_grad for t in loss.target_qvalue_network_params.flatten_keys().values())
    opt = torch.optim.SGD(loss.parameters(), lr=0.1)
    out = loss(batch())
    (out["loss_qvalue"] + out["loss_actor"] + out["loss_alpha_lane"] + out["loss_alpha_param"]).backward()
    opt.step()
    for n, t in loss.target_qvalue_network_params.flatten_keys().items():
        assert torch.equal(t, target[n]), n  # a gradient step leaves the targets alone
    parts.target_updater.step()
    online = loss.qvalue_network_params.flatten_keys()
    for n, t in loss.target_qvalue_network_params.flatten_keys().items():
        torch.testing.assert_close(t, target[n] + 0.005 * (online[n].detach() - target[n]))


@pytest.mark.parametrize("part", ["lane", "param"])
def test_each_temperature_moves_toward_its_target_entropy(parts, part):
    """Entropy below the target: α rises; above it: α falls; the other temperature stays."""
    loss = parts.loss
    other = "param" if part == "lane" else "lane"
    for target, direction in ((50.0, 1), (-50.0, -1)):  # unreachable targets: the sign of the step is known
        getattr(loss, f"target_entropy_{part}").fill_(target)
        before = {p: float(getattr(loss, f"log_alpha_{p}")) for p in ("lane", "param")}
        opt = torch.optim.SGD([getattr(loss, f"log_alpha_{part}")], lr=0.01)
        opt.zero_grad()
        loss(batch())[f"loss_alpha_{part}"].backward()
        opt.step()
        moved = float(getattr(loss, f"log_alpha_{part}")) - before[part]
        assert moved * direction > 0, (part, target, moved)
        assert float(getattr(loss, f"log_alpha_{other}")) == before[other]


def test_the_lane_temperature_ignores_states_with_one_valid_command(parts):
    """During a manoeuvre the mask leaves one lane command: entropy 0 whatever α_d. Such states do not tune α_d
    (counting them drove α_d from 0.2 to 3e14 in a 1000-episode run): the lane temperature loss of a batch equals
    that of its choosable rows alone, and a batch with no choice leaves α_d where it is."""
    loss = parts.loss
    td = batch()
    forced = td[:8].clone()
    forced[K.LC_ACTION_MASK] = torch.zeros(8, 3, dtype=torch.bool)
    forced[K.LC_ACTION_MASK][:, K.KEEP] = True
    mixed = torch.cat([td[8:], forced])
    assert loss.choosable(mixed).tolist() == [1.0] * 8 + [0.0] * 8
    torch.manual_seed(5)
    both = loss(mixed)
    torch.manual_seed(5)
    alone = loss(td[8:])
    assert float(both["loss_alpha_lane"]) == pytest.approx(float(alone["loss_alpha_lane"]), rel=1e-5)
    assert float(both["entropy_lane"]) == pytest.approx(float(alone["entropy_lane"]), rel=1e-5)
    none = loss(forced)
    assert float(none["loss_alpha_lane"]) == 0.0 and float(none["entropy_lane"]) == 0.0
    loss.zero_grad(set_to_none=True)
    none["loss_alpha_lane"].backward()
    assert loss.log_alpha_lane.grad is None or float(loss.log_alpha_lane.grad) == 0.0


def test_target_of_a_terminal_transition_is_the_reward(parts):
    td = batch(terminated=True)
    out = parts.loss(td)
    assert out["target_value"] == pytest.approx(float(td["next", *K.JOINT_REWARD].mean()), abs=1e-6)


def test_soft_value_by_hand(parts):
    """V(s') of the module docstring, recomputed from the networks, with the value estimator's γ."""
    loss = parts.loss
    td = batch()
    torch.manual_seed(3)
    out = loss(td)
    torch.manual_seed(3)
    with torch.no_grad():
        nxt = td["next"]
        p, log_p, param, log_prob = loss._policy(nxt)
        q = loss._q_every_choice(nxt, param, loss.target_qvalue_network_params)
        v = (p * (q - loss.alpha_lane * log_p - loss.alpha_param * log_prob)).sum(-1, keepdim=True)
    expected = (nxt[K.JOINT_REWARD] + 0.9 * v).mean()
    assert float(out["target_value"]) == pytest.approx(float(expected), rel=1e-5)
    assert torch.isfinite(log_p).all() and (p[::2, K.LEFT] == 0).all()  # masked commands: probability 0, no NaN


def test_set_keys_and_unknown_keys(parts):
    loss = parts.loss
    with pytest.raises(ValueError):
        loss.set_keys(not_a_key="x")
    loss.set_keys(reward=K.LC_REWARD)
    assert loss.tensor_keys.reward == K.LC_REWARD and loss.value_estimator.tensor_keys.reward == K.LC_REWARD
    assert ("next", *K.LC_REWARD) in loss.in_keys


def test_sampler_respects_the_mask_and_is_greedy_without_exploration(parts):
    td = batch().exclude(K.LC_ACTION, K.CF_ACTION, "next")
    td[K.LC_ACTION_MASK][:, K.RIGHT] = False
    for explore in (True, False):
        out = parts.sampler(explore)(parts.actor(td.clone()))
        assert out[K.LC_ACTION].sum(-1).eq(1).all()
        assert td[K.LC_ACTION_MASK].gather(1, out[K.LC_ACTION].argmax(-1, keepdim=True)).all()
        assert ((out[K.CF_ACTION] >= -5) & (out[K.CF_ACTION] <= 5)).all()
    greedy = [parts.sampler(True)(parts.actor(td.clone())) for _ in range(2)]
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        greedy = [parts.sampler(True)(parts.actor(td.clone())) for _ in range(2)]
    assert torch.equal(greedy[0][K.CF_ACTION], greedy[1][K.CF_ACTION])


# ------------------------------------------------------------------------ a hybrid-action task with a known optimum
OPT_PARAM = torch.tensor([-3.0, 0.0, 3.0])  # the best acceleration of each command (left, keep, right), m/s²


def bandit_batch(n: int, gen: torch.Generator) -> TensorDict:
    """A one-step hybrid-action task (every transition terminal): the state's first three features name the best
    command ``k* = argmax s[:3]``, each command k has its own best parameter ``OPT_PARAM[k]``; the reward is
    ``1[k = k*] - 4 ((x - OPT_PARAM[k]) / 5)²``, at most 1, reached only by ``(k*, OPT_PARAM[k*])``. Actions are
    drawn uniformly (off-policy data, as from a replay buffer)."""
    obs = torch.randn(n, 4, generator=gen)
    choice = torch.randint(0, 3, (n,), generator=gen)
    x = torch.rand(n, 1, generator=gen) * 10 - 5
    reward = (choice == obs[:, :3].argmax(-1)).float() - 4 * ((x.squeeze(-1) - OPT_PARAM[choice]) / 5) ** 2
    mask = torch.ones(n, 3, dtype=torch.bool)
    done = torch.ones(n, 1, dtype=torch.bool)
    nxt = TensorDict(
        {
            K.JOINT_OBS: torch.randn(n, 4, generator=gen),
            K.LC_ACTION_MASK: mask.clone(),
            K.JOINT_REWARD: reward.unsqueeze(-1),
            "done": done,
            "terminated": done.clone(),
        },
        [n],
    )
    return TensorDict(
        {
            K.JOINT_OBS: obs,
            K.LC_ACTION_MASK: mask,
            K.LC_ACTION: one_hot(choice, 3).float(),
            K.CF_ACTION: x,
            "next": nxt,
        },
        [n],
    )


def train_on_bandit(updates: int, actor_lr: float = 3e-3) -> tuple[float, float, torch.Tensor]:
    """PASAC trained as :class:`~kddrl_trl.training.PASACLearner` trains it (one optimiser per part, the summed
    losses, the soft target update); returns the greedy policy's share of best commands, its mean reward, and the
    greedy parameter of every command ``[states, 3]`` on fresh states."""
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(1)
    parts = make_pasac(4, hidden=[64, 64], gamma=0.9, alpha_init=0.05, target_entropy_lane=0.169)
    loss = parts.loss
    opts = [
        torch.optim.Adam(loss.qvalue_network_params.flatten_keys().values(), lr=3e-3),
        torch.optim.Adam(loss.actor_network_params.flatten_keys().values(), lr=actor_lr),
        torch.optim.Adam([loss.log_alpha_lane, loss.log_alpha_param], lr=3e-3),
    ]
    for _ in range(updates):
        out = loss(bandit_batch(256, gen))
        for opt in opts:
            opt.zero_grad()
        (out["loss_qvalue"] + out["loss_actor"] + out["loss_alpha_lane"] + out["loss_alpha_param"]).backward()
        for opt in opts:
            opt.step()
        parts.target_updater.step()
    test = bandit_batch(2048, gen).exclude(K.LC_ACTION, K.CF_ACTION, "next")
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        acted = parts.sampler(explore=False)(parts.actor(test.clone()))
    choice, x = acted[K.LC_ACTION].argmax(-1), acted[K.CF_ACTION].squeeze(-1)
    reward = (choice == test[K.JOINT_OBS][:, :3].argmax(-1)).float() - 4 * ((x - OPT_PARAM[choice]) / 5) ** 2
    per_command = (loss.param_loc + loss.param_half * torch.tanh(acted[K.PASAC_LOC])).squeeze(-1)
    return float((choice == test[K.JOINT_OBS][:, :3].argmax(-1)).float().mean()), float(reward.mean()), per_command


def test_pasac_solves_a_hybrid_action_task_with_a_known_optimum():
    """The optimum is the best command with its own best acceleration (reward 1); a uniform policy scores about
    1/3 - 4/3 ≈ -1.0. The trained greedy policy must pick the best command almost always, and every command's
    acceleration must sit at that command's optimum (the acceleration is conditioned on the command)."""
    best, reward, per_command = train_on_bandit(1000)
    assert best >= 0.9, best
    assert reward >= 0.85, reward
    assert (per_command - OPT_PARAM).abs().median(0).values.max() < 0.5, per_command[:4]


def test_the_hybrid_action_task_is_not_solved_without_policy_learning():
    """The same budget with the actor frozen (learning rate 0) fails the bars above: they measure learning."""
    best, reward, per_command = train_on_bandit(1000, actor_lr=0.0)
    assert best < 0.9 or reward < 0.85 or (per_command - OPT_PARAM).abs().median(0).values.max() >= 0.5


def test_temperatures_stay_inside_their_bounds():
    """An unreachable lane target pushes α_d up; it stops at alpha_max, and alpha_min holds it from below."""
    parts = make_pasac(D, hidden=[16], alpha_init=0.5, alpha_min=0.1, alpha_max=1.0)
    loss = parts.loss
    opt = torch.optim.SGD([loss.log_alpha_lane, loss.log_alpha_param], lr=1.0)
    loss.target_entropy_lane.fill_(50.0)  # below target: α_d rises
    loss.target_entropy_param.fill_(-50.0)  # log π_c + H̄_c < 0: α_c falls
    for _ in range(20):
        out = loss(batch())
        opt.zero_grad()
        (out["loss_alpha_lane"] + out["loss_alpha_param"]).backward()
        opt.step()
    out = loss(batch())
    assert float(out["alpha_lane"]) == pytest.approx(1.0) and float(out["alpha_param"]) == pytest.approx(0.1)
    with pytest.raises(ValueError, match="alpha_min"):
        make_pasac(D, alpha_init=2.0, alpha_max=1.0)
