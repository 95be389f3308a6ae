"""The learners of the comparison systems Peng et al. (D3QN + DDPG + MOBIL criteria), unified D3QN and PASAC:
their pieces (joint action, MOBIL criteria), which parameters each update moves, and their policies' masks."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import check_env_specs

from kddrl_trl import keys as K
from kddrl_trl.collectors import MultiTimescaleCollector
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.modules import lc_obs_dim, lc_state
from kddrl_trl.modules.joint_action import accel_levels, joint_action_mask, joint_action_split, joint_reward
from kddrl_trl.physics import mobil_utilities
from kddrl_trl.training import HierarchicalLearner, JointD3QNLearner, PASACLearner, make_buffer
from kddrl_trl.transforms import DecisionClock, MOBILCriteria

PENG = {
    "priors": False,
    "key_gaps": False,
    "mobil_criteria": True,
    "cf_agent": "ddpg",
    "d3qn": {"hidden": [32, 32]},
    "ddpg": {"hidden": [32, 32]},
}


def collect(learner, transforms, frames=30):
    """(buffer-L sample, buffer-H sample or None) of ``learner`` 's exploring policy on the fake env."""
    torch.manual_seed(0)
    env = TransformedEnv(FakeHighwayEnv(num_roads=4, seed=0), Compose(*transforms, DecisionClock(1)))
    rb_l, rb_h = make_buffer(5000, 32, 0), make_buffer(5000, 16, 0)
    mtc = MultiTimescaleCollector.from_env(
        env,
        learner.policy(),
        frames_per_env=frames,
        frame_buffer=rb_l,
        macro_buffer=rb_h,
        frame_keys=learner.buffer_keys(),
    )
    batch = next(iter(mtc)).frames
    mtc.shutdown()
    return batch, rb_l.sample(), rb_h.sample()


def snapshot(module):
    return {n: t.detach().clone() for n, t in module.state_dict().items() if t.is_floating_point() and t.dim() > 0}


def moved(before, module, prefix):
    return {n for n, t in snapshot(module).items() if n.startswith(prefix) and not torch.equal(before[n], t)}


# ------------------------------------------------------------------------------------------ pieces
def test_joint_action_split_mask_and_reward_by_hand():
    levels = accel_levels(7)
    torch.testing.assert_close(levels, torch.tensor([-5.0, -10 / 3, -5 / 3, 0.0, 5 / 3, 10 / 3, 5.0]))
    index = torch.tensor([0, 6, 7 + 3, 20])  # left -5, left +5, keep 0, right +5
    td = TensorDict(
        {
            K.JOINT_ACTION: torch.nn.functional.one_hot(index, 21).float(),
            K.LC_ACTION_MASK: torch.tensor([[True, True, False]] * 4),
        },
        [4],
    )
    joint_action_split(levels)(td)
    assert td[K.LC_ACTION].argmax(-1).tolist() == [K.LEFT, K.LEFT, K.KEEP, K.RIGHT]
    torch.testing.assert_close(td[K.CF_ACTION].squeeze(-1), torch.tensor([-5.0, 5.0, 0.0, 5.0]))
    mask = joint_action_mask(7)(td)[K.JOINT_ACTION_MASK]
    assert mask.shape == (4, 21) and mask[:, :14].all() and not mask[:, 14:].any()
    td["next"] = TensorDict({K.LC_REWARD: torch.ones(4, 1), K.CF_REWARD: torch.full((4, 1), 0.5)}, [4])
    assert joint_reward()(td)["next", *K.JOINT_REWARD].eq(1.5).all()
    with pytest.raises(ValueError, match="num_levels"):
        accel_levels(1)


def test_mobil_criteria_transform_specs_and_values():
    env = TransformedEnv(FakeHighwayEnv(num_roads=3, seed=1), MOBILCriteria())
    check_env_specs(env)
    td = env.rollout(4)["next"]
    u, safe = mobil_utilities(
        td[K.EGO_STATE][..., 0],
        td[K.EGO_STATE][..., 1],
        td[K.NEIGHBORS_KIN],
        td[K.NEIGHBORS_MASK],
        td[K.EGO_LANE][..., 0],
    )
    torch.testing.assert_close(td[K.MOBIL_INCENTIVE], u)
    assert torch.equal(td[K.MOBIL_SAFE], safe) and td[K.MOBIL_SAFE][..., K.KEEP].all()
    # the lane-change state of Peng et al. appends the criteria (scaled utilities, flags)
    obs = lc_state(embed=False, mobil=True)(td.clone())[K.LC_OBS]
    assert obs.shape[-1] == lc_obs_dim(0, mobil=True) == lc_obs_dim(0) + 6
    torch.testing.assert_close(obs[..., -3:], safe.float())


# ------------------------------------------------------------------------------------------- peng
def test_peng_ddpg_and_d3qn_updates_move_their_own_networks():
    learner = HierarchicalLearner(**PENG)
    frames, sample_l, sample_h = collect(learner, [MOBILCriteria()])
    assert frames[K.LC_DECIDE].all()  # lc_period 1: a decision on every frame
    assert K.MOBIL_INCENTIVE in learner.buffer_keys() and ("next", *K.MOBIL_SAFE) in learner.buffer_keys()
    assert type(learner.cf_loss).__name__ == "DDPGLoss" and learner.td3.policy_delay == 1
    before = snapshot(learner)
    out = learner.update_frame(sample_l)  # DDPG: critic, actor and both targets in one step
    assert set(out) == {"loss_qvalue", "loss_actor"}
    assert moved(before, learner, "cf_loss.value_network_params")
    assert moved(before, learner, "cf_loss.actor_network_params")
    assert moved(before, learner, "cf_loss.target_actor_network_params")
    assert moved(before, learner, "cf_loss.target_value_network_params")
    assert not moved(before, learner, "lc_loss.")
    before = snapshot(learner)
    learner.update_decision(sample_h)
    assert moved(before, learner, "lc_loss.value_network_params") and not moved(before, learner, "cf_loss.")


# ----------------------------------------------------------------------------------- unified D3QN
def test_unified_d3qn_acts_on_valid_joint_actions_and_learns():
    learner = JointD3QNLearner(num_levels=5, d3qn={"hidden": [32], "eps_decisions": 10})
    frames, sample_l, _ = collect(learner, [])
    assert frames[K.JOINT_ACTION].shape[-1] == 15 and not learner.learns_from_decisions
    lane = frames[K.JOINT_ACTION].argmax(-1) // 5
    torch.testing.assert_close(frames[K.LC_ACTION].argmax(-1), lane)
    assert frames[K.LC_ACTION_MASK].gather(-1, lane.unsqueeze(-1)).all()  # never an invalid command
    assert set(frames[K.CF_ACTION].unique().tolist()) <= set(accel_levels(5).tolist())
    before = snapshot(learner)
    assert torch.isfinite(learner.update_frame(sample_l)["loss_joint"])
    assert moved(before, learner, "q_loss.value_network_params") and moved(before, learner, "q_loss.target_")
    with pytest.raises(NotImplementedError):
        learner.update_decision(sample_l)


# ------------------------------------------------------------------------------------------- PASAC
def test_pasac_learner_acts_on_valid_commands_and_one_step_moves_every_part():
    learner = PASACLearner(pasac={"hidden": [32]})
    frames, sample_l, _ = collect(learner, [])
    assert frames[K.LC_ACTION_MASK].gather(-1, frames[K.LC_ACTION].argmax(-1, keepdim=True)).all()
    assert ((frames[K.CF_ACTION] >= -5) & (frames[K.CF_ACTION] <= 5)).all()
    alphas = learner.exploration()
    before = snapshot(learner)
    out = learner.update_frame(sample_l)
    assert set(out) == {"loss_qvalue", "loss_actor", "loss_alpha_lane", "loss_alpha_param"}
    for part in ("sac_loss.qvalue_network_params", "sac_loss.actor_network_params", "sac_loss.target_qvalue"):
        assert moved(before, learner, part), part
    assert learner.exploration() != alphas


# ------------------------------------------------------------------- state extras (issue 14, every learner)
EXTRAS = ("thw", "ttc")


@pytest.mark.parametrize("system", ["peng", "d3qn_unified", "pasac_unified"])
def test_every_comparison_learner_acts_and_learns_with_the_headway_and_ttc_extras(system):
    """``algo.state_extras=[thw,ttc]``: the states grow by two features (the last two, :func:`headway_features` of the
    raw keys), the networks take them, the policy acts and one update moves the networks."""
    from kddrl_trl.modules import cf_obs_dim, headway_features

    if system == "peng":
        learner, transforms = HierarchicalLearner(**PENG, state_extras=EXTRAS), [MOBILCriteria()]
        states = {
            K.LC_OBS: (learner.lc_state, lc_obs_dim(0, mobil=True) + 2),
            K.CF_OBS: (learner.cf_state, cf_obs_dim(0) + 2),
        }
    elif system == "d3qn_unified":
        learner, transforms = JointD3QNLearner(num_levels=5, d3qn={"hidden": [32]}, state_extras=EXTRAS), []
        states = {K.JOINT_OBS: (learner.state, cf_obs_dim(0) + 2)}
    else:
        learner, transforms = PASACLearner(pasac={"hidden": [32]}, state_extras=EXTRAS), []
        states = {K.JOINT_OBS: (learner.state, cf_obs_dim(0) + 2)}
    frames, sample_l, sample_h = collect(learner, transforms)  # the policy acted on the grown states
    expected = headway_features(frames[K.EGO_STATE], frames[K.NEIGHBORS_REL], frames[K.NEIGHBORS_MASK])
    assert ((expected >= 0) & (expected <= 5)).all() and expected.std() > 0
    for key, (builder, dim) in states.items():
        obs = builder(frames.clone())[key]
        assert obs.shape[-1] == dim
        torch.testing.assert_close(obs[..., -2:], expected)
    before = snapshot(learner)
    learner.update_frame(sample_l)
    if system == "peng":
        learner.update_decision(sample_h)
        assert moved(before, learner, "lc_loss.value_network_params")
    assert moved(
        before, learner, "cf_loss." if system == "peng" else ("q_loss." if system == "d3qn_unified" else "sac_loss.")
    )


# ------------------------------------------------------------------ every learner on a GPU (issue 15)
def _cpu_state(learner) -> dict:
    return {k: v.detach().cpu() for k, v in learner.state_dict().items() if k != "counters"}


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
@pytest.mark.parametrize("system", ["peng", "d3qn_unified", "pasac_unified"])
@pytest.mark.parametrize("compile", [False, True])
def test_every_comparison_learner_updates_on_cuda_with_cudagraphs(system, compile):
    """On a GPU, each comparison learner with CUDA-graphed update functions (eager- or compile-captured): updates
    without a random draw (Peng's DDPG and D3QN, the unified D3QN) give the CPU learner's parameters; PASAC's
    (sampled actions) give finite losses and move its networks. Its policy acts on CPU TensorDicts."""

    def build(**kw):
        if system == "peng":
            return HierarchicalLearner(**PENG, **kw)
        if system == "d3qn_unified":
            return JointD3QNLearner(num_levels=5, d3qn={"hidden": [32]}, **kw)
        return PASACLearner(pasac={"hidden": [32]}, **kw)

    torch.manual_seed(0)
    cpu = build()
    frames, sample_l, sample_h = collect(cpu, [MOBILCriteria()] if system == "peng" else [])
    gpu = build(device="cuda", cudagraphs=True, compile=compile)
    assert gpu.cudagraphs and next(gpu.parameters()).is_cuda
    gpu.load_full_state_dict(cpu.full_state_dict())
    before = snapshot(gpu)
    for _ in range(6):  # past CudaGraphModule's warm-up calls: captured and replayed
        out = gpu.update_frame(sample_l)
        assert all(torch.isfinite(v) for v in out.values()), out
        if system == "peng":
            gpu.update_decision(sample_h)
        if system != "pasac_unified":
            cpu.update_frame(sample_l)
            if system == "peng":
                cpu.update_decision(sample_h)
    if system == "pasac_unified":
        assert moved(before, gpu, "sac_loss.qvalue_network_params") and moved(before, gpu, "sac_loss.actor_network")
    else:
        ref, got = _cpu_state(cpu), _cpu_state(gpu)
        for name in ref:
            torch.testing.assert_close(got[name], ref[name], rtol=1e-3, atol=1e-4, msg=name)
    td = gpu.policy(explore=True)(frames[:, 0].exclude("next").clone())
    assert td.get(K.CF_ACTION).device.type == "cpu"
