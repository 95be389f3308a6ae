"""Predictive-state transforms (paper §III.B-C, Eq. 11-13, 16, 20-22, 24; Algorithm 1 lines 15-20)."""

from __future__ import annotations

import math
from functools import partial

import pytest
import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import (
    Bounded,
    Categorical,
    Composite,
    LazyTensorStorage,
    ReplayBuffer,
    Unbounded,
)
from torchrl.data.replay_buffers import SamplerWithoutReplacement
from torchrl.envs import Compose, EnvBase, ParallelEnv, SerialEnv, TransformedEnv
from torchrl.envs.utils import check_env_specs

from kddrl_trl import keys as K
from kddrl_trl.envs import FakeHighwayEnv, SumoHighwayEnv
from kddrl_trl.physics import IDMParams, MOBILParams
from kddrl_trl.transforms import (
    IDMPrior,
    KeyGapsFromPrior,
    LCGANPrior,
    MOBILPrior,
    TrajGANPrediction,
    key_step_gaps,
    make_kddrl_transforms,
)

torch.set_num_threads(1)

PRED_KEYS = (K.PRED_PRIOR_TRAJ, K.PRED_TRAJ, K.PRED_KEY_GAPS)
PRIOR_KEYS = (K.PRIOR_P_MOBIL, K.PRIOR_P_LCGAN)
DERIVED = PRED_KEYS + PRIOR_KEYS
SHAPES = {
    K.PRED_PRIOR_TRAJ: (3, 20),
    K.PRED_TRAJ: (3, 20),
    K.PRED_KEY_GAPS: (3, 2),
    K.PRIOR_P_MOBIL: (3,),
    K.PRIOR_P_LCGAN: (3,),
}
L = IDMParams().length


def raw_obs(batch=(), history_len=10) -> TensorDict:
    """All-zero raw observation (every leader absent) of batch shape ``batch``."""
    b = tuple(batch)
    return TensorDict(
        {
            K.EGO_STATE: torch.zeros(*b, 3),
            K.EGO_LANE: torch.ones(*b, 1, dtype=torch.long),
            K.EGO_ACCEL: torch.zeros(*b, 1),
            K.NEIGHBORS_REL: torch.zeros(*b, 6, 4),
            K.NEIGHBORS_MASK: torch.zeros(*b, 6, dtype=torch.bool),
            K.NEIGHBORS_KIN: torch.zeros(*b, 6, 3),
            K.EGO_LANE_OFFSET: torch.zeros(*b, 1),
            K.NEIGHBORS_LANE_OFFSET: torch.zeros(*b, 6),
            K.LEADERS_AHEAD: torch.zeros(*b, 3, 3),
            K.LEADERS_HISTORY: torch.zeros(*b, 3, history_len, 2),
        },
        batch_size=b,
    )


def place(td: TensorDict, slot: str, y: float, v: float, ego_y: float = 0.0, ego_v: float = 25.0, dx=None):
    """Put neighbour ``slot`` at absolute position ``y`` with speed ``v`` (unbatched ``td``), consistently in
    kin, rel, mask and (for leaders) a constant-speed history."""
    i = K.SLOT[slot]
    td[K.NEIGHBORS_MASK][i] = True
    td[K.NEIGHBORS_KIN][i] = torch.tensor([y, v, 0.0])
    lat = {0: 3.2, 1: 0.0, 2: -3.2}[i % 3] if dx is None else dx
    td[K.NEIGHBORS_REL][i] = torch.tensor([lat, y - ego_y, 0.0, v - ego_v])
    if i < 3:
        h = td[K.LEADERS_HISTORY].shape[-2]
        back = torch.arange(h - 1, -1, -1, dtype=torch.float32) * 0.1
        td[K.LEADERS_HISTORY][i] = torch.stack([y - v * back, torch.full((h,), v)], -1)
    return td


def assert_derived(td: TensorDictBase, keys=DERIVED):
    """Every derived key present, of the documented shape, finite; probabilities on the simplex."""
    for key in keys:
        x = td.get(key)
        assert x.shape[-len(SHAPES[key]) :] == SHAPES[key], key
        assert x.dtype == torch.float32, key
        assert torch.isfinite(x).all(), key
    for key in PRIOR_KEYS:
        if key in keys:
            p = td.get(key)
            assert (p >= 0).all() and (p <= 1).all()
            torch.testing.assert_close(p.sum(-1), torch.ones_like(p[..., 0]), atol=1e-5, rtol=0)


def accelerate(td):
    """Policy: keep the lane, full throttle (rams leaders: collisions -> partial resets of a batched env)."""
    b = td.batch_size
    return td.update({K.LC_ACTION: F.one_hot(torch.full(b, K.KEEP), 3).float(), K.CF_ACTION: torch.full((*b, 1), 5.0)})


def strip(td: TensorDictBase) -> TensorDictBase:
    """``td`` without the derived ``pred`` / ``prior`` subtrees (root and next): the raw transition."""
    return td.exclude("pred", "prior", ("next", "pred"), ("next", "prior"))


# ------------------------------------------------------------------------------------------- specs
@pytest.mark.parametrize("num_roads", [1, 8])
def test_check_env_specs_fake(num_roads):
    env = TransformedEnv(FakeHighwayEnv(num_roads=num_roads, seed=2), make_kddrl_transforms())
    check_env_specs(env, seed=None)
    spec = env.observation_spec
    for key in DERIVED:
        assert spec[key].shape == (num_roads, *SHAPES[key])
        assert spec[key].dtype == torch.float32
    assert isinstance(spec[K.PRED_TRAJ], Unbounded) and isinstance(spec[K.PRED_KEY_GAPS], Unbounded)
    assert isinstance(spec[K.PRIOR_P_MOBIL], Bounded) and isinstance(spec[K.PRIOR_P_LCGAN], Bounded)
    assert float(spec[K.PRIOR_P_MOBIL].space.low.min()) == 0.0
    assert float(spec[K.PRIOR_P_MOBIL].space.high.max()) == 1.0
    # reset emits the same keys as a step
    assert_derived(env.reset())


def _fake(seed, num_roads=2):
    return FakeHighwayEnv(num_roads=num_roads, seed=seed)


def _fake_transformed(seed, num_roads=2):
    return TransformedEnv(FakeHighwayEnv(num_roads=num_roads, seed=seed), make_kddrl_transforms(seed=seed))


@pytest.mark.parametrize("batched", ["serial", "parallel"])
def test_check_env_specs_batched_fake(batched):
    """The stack outside a batched env (one generator call for all envs), and inside its workers."""
    make = (
        (lambda fns: SerialEnv(2, fns))
        if batched == "serial"
        else (lambda fns: ParallelEnv(2, fns, mp_start_method="fork"))
    )
    outer = TransformedEnv(make([partial(_fake, 0), partial(_fake, 1)]), make_kddrl_transforms())
    inner = make([partial(_fake_transformed, 0), partial(_fake_transformed, 1)])
    try:
        for env in (outer, inner):
            check_env_specs(env, seed=None)
            td = env.rollout(15, accelerate, break_when_any_done=False)
            assert td.batch_size == (2, 2, 15)
            assert_derived(td)
            assert_derived(td["next"])
    finally:
        outer.close()
        inner.close()


@pytest.mark.usefixtures("no_sumo_open")
@pytest.mark.parametrize("num_roads", [1, 8])
def test_check_env_specs_sumo(num_roads):
    env = TransformedEnv(SumoHighwayEnv("baseline", num_roads=num_roads, seed=1), make_kddrl_transforms())
    try:
        check_env_specs(env, seed=None)
        td = env.rollout(10, accelerate, break_when_any_done=False)
        assert_derived(td["next"])
    finally:
        env.close()


@pytest.mark.usefixtures("no_sumo_open")
def test_check_env_specs_sumo_parallel():
    fns = [partial(SumoHighwayEnv, "baseline", num_roads=2, seed=s) for s in (1, 2)]
    env = TransformedEnv(ParallelEnv(2, fns, mp_start_method="fork"), make_kddrl_transforms())
    try:
        check_env_specs(env, seed=None)
    finally:
        env.close()


# ------------------------------------------------------------------------------- rollout with resets
def test_full_stack_rollout_with_resets_finite():
    env = TransformedEnv(FakeHighwayEnv(num_roads=6, seed=4), make_kddrl_transforms())
    td = env.rollout(120, accelerate, break_when_any_done=False)
    done = td["next", "done"].squeeze(-1)
    assert done.any(), "the rollout must cross resets"
    assert (done.any(0) & ~done.all(0)).any(), "some frame must reset some roads but not all (partial reset)"
    assert_derived(td)
    assert_derived(td["next"])
    # at least some leaders are present and predicted (nonzero), and absent ones are exactly zero
    present = td[K.NEIGHBORS_MASK][..., :3]
    assert present.any() and (~present).any()
    assert (td[K.PRED_TRAJ][~present] == 0).all() and (td[K.PRED_KEY_GAPS][~present] == 0).all()
    assert (td[K.PRED_TRAJ][present] != 0).all()


def test_partial_reset_recomputes_reset_rows_only():
    """Stateless per frame: after a partial reset the reset rows carry keys computed on their new
    observation, and the next step is, for every row, a fresh computation on that row's observation."""
    env = TransformedEnv(FakeHighwayEnv(num_roads=4, seed=5), make_kddrl_transforms())
    physics = Compose(IDMPrior(), KeyGapsFromPrior(), MOBILPrior())
    td = env.reset()
    for _ in range(5):
        td = env.step(accelerate(td))["next"].clone()
    rows = torch.tensor([True, False, True, False])
    out = env.reset(TensorDict({"_reset": rows[:, None]}, batch_size=[4]))
    ref = physics(strip(out).clone())
    for key in (K.PRED_PRIOR_TRAJ, K.PRIOR_P_MOBIL):
        torch.testing.assert_close(out[key][rows], ref[key][rows], rtol=0, atol=0)
    assert not torch.equal(out[K.EGO_STATE][rows], td[K.EGO_STATE][rows])  # reset rows: new episode
    assert_derived(out[rows])
    td[rows] = out[rows]  # what step_and_maybe_reset does with a partial reset
    nxt = env.step(accelerate(td))["next"]
    ref = physics(strip(nxt).clone())
    for key in (K.PRED_PRIOR_TRAJ, K.PRIOR_P_MOBIL):
        torch.testing.assert_close(nxt[key], ref[key], rtol=0, atol=0)
    assert_derived(nxt)


# --------------------------------------------------------------------------------------- IDM prior
def hand_idm(y, v, y_a, v_a, has, p=None, steps=20, dt=0.1):
    """Plain-python IDM integration (Eq. 11-12, semi-implicit Euler) of one leader."""
    p = p or IDMParams()
    out = []
    for _ in range(steps):
        acc = 1.0 - (max(v, 0.0) / p.v0) ** p.delta
        if has:
            s_star = p.s0 + max(0.0, v * p.T + v * (v - v_a) / (2.0 * math.sqrt(p.a_max * p.b)))
            acc -= (s_star / max(y_a - y - p.length, 0.1)) ** 2
        v = max(v + p.a_max * acc * dt, 0.0)
        y = y + v * dt
        y_a = y_a + v_a * dt
        out.append(y)
    return torch.tensor(out)


def test_idm_prior_by_hand():
    td = raw_obs()
    place(td, "b", 40.0, 30.0)  # current leader, slower vehicle 25 m ahead of it
    td[K.LEADERS_AHEAD][1] = torch.tensor([70.0, 20.0, 1.0])
    place(td, "c", 60.0, 28.0)  # right leader, free road
    td[K.NEIGHBORS_KIN][0] = float("nan")  # a absent, garbage in its slot
    td[K.LEADERS_AHEAD][0] = float("nan")
    out = IDMPrior()(td)[K.PRED_PRIOR_TRAJ]
    assert out.shape == (3, 20)
    torch.testing.assert_close(out[1], hand_idm(40.0, 30.0, 70.0, 20.0, True), rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(out[2], hand_idm(60.0, 28.0, 0.0, 0.0, False), rtol=1e-5, atol=1e-4)
    assert (out[0] == 0).all()
    assert (torch.diff(out[1]) > 0).all() and out[1, -1] < 70.0 + 20.0 * 2.0 - L  # brakes, no overlap
    # configurable parameters: a shorter headway and other horizon
    p = IDMParams(T=1.0, a_max=3.0)
    out2 = IDMPrior(p, steps=30)(td.clone())[K.PRED_PRIOR_TRAJ]
    assert out2.shape == (3, 30)
    torch.testing.assert_close(out2[1], hand_idm(40.0, 30.0, 70.0, 20.0, True, p, steps=30), rtol=1e-5, atol=1e-4)


def test_idm_prior_batched_any_shape():
    one = raw_obs()
    place(one, "b", 40.0, 30.0)
    td = one.expand(2, 3).clone()
    out = IDMPrior()(td)[K.PRED_PRIOR_TRAJ]
    assert out.shape == (2, 3, 3, 20)
    torch.testing.assert_close(out, IDMPrior()(one)[K.PRED_PRIOR_TRAJ].expand(2, 3, 3, 20))


# ------------------------------------------------------------------------------------------- MOBIL
def scene(lane=1, ego_v=25.0, **slots):
    """Ego at y = 0 in ``lane``; each slot given as (bumper-to-bumper gap to ego, speed)."""
    td = raw_obs()
    td[K.EGO_STATE] = torch.tensor([0.0, ego_v, 0.0])
    td[K.EGO_LANE] = torch.tensor([lane])
    for name, (gap, v) in slots.items():
        y = gap + L if name in "abc" else -(gap + L)
        place(td, name, y, v, ego_v=ego_v)
    return td


def p_mobil(td, **kw):
    return MOBILPrior(**kw)(td)[K.PRIOR_P_MOBIL]


def test_mobil_prior_safety_violation_zeroes_direction():
    # slow leader ahead; left lane free ahead but a follower only 3 m behind (< y_safe = 5 m)
    p = p_mobil(scene(b=(50.0, 22.0), d=(3.0, 25.0)))
    assert p[K.LEFT] == 0.0 and p[K.RIGHT] > 0.9
    # the same follower at 40 m: left becomes possible
    assert p_mobil(scene(b=(50.0, 22.0), d=(40.0, 25.0)))[K.LEFT] > 0.0


def test_mobil_prior_below_threshold_keeps():
    p = p_mobil(scene(ego_v=30.0, b=(250.0, 29.8)))
    torch.testing.assert_close(p, torch.tensor([0.0, 1.0, 0.0]))


def test_mobil_prior_politeness_changes_decision():
    td = scene(b=(50.0, 22.0), d=(40.0, 25.0), lane=0)  # lane 0: no right lane, left vs keep only
    rude = p_mobil(td.clone(), mobil=MOBILParams(politeness=0.1))
    polite = p_mobil(td.clone(), mobil=MOBILParams(politeness=1.0))
    assert rude.argmax() == K.LEFT
    torch.testing.assert_close(polite, torch.tensor([0.0, 1.0, 0.0]))
    # a plain mapping (Hydra config) works too
    torch.testing.assert_close(p_mobil(td.clone(), mobil={"politeness": 1.0}), polite)


def test_mobil_prior_num_lanes():
    td = scene(lane=2, b=(30.0, 15.0))
    assert p_mobil(td.clone())[K.LEFT] == 0.0  # lane 2 of 3 is the leftmost
    assert p_mobil(td.clone(), num_lanes=4)[K.LEFT] > 0.0  # not on a 4-lane road


def test_absent_neighbours_never_nan():
    td = raw_obs(batch=(4,))
    for key in (K.NEIGHBORS_KIN, K.NEIGHBORS_REL, K.LEADERS_AHEAD, K.LEADERS_HISTORY):
        td.set(key, torch.full_like(td.get(key), float("nan")))  # garbage everywhere, every slot absent
    out = make_kddrl_transforms()(td)
    assert_derived(out)
    for key in PRED_KEYS:
        assert (out[key] == 0).all()
    torch.testing.assert_close(out[K.PRIOR_P_MOBIL], torch.tensor([0.0, 1.0, 0.0]).expand(4, 3))


# --------------------------------------------------------------------------------------------- GANs
def traffic_obs(seed=0, num_roads=8):
    env = FakeHighwayEnv(num_roads=num_roads, seed=seed)
    return IDMPrior()(env.reset())


def test_trajgan_prediction_seeded():
    td = traffic_obs()
    present = td[K.NEIGHBORS_MASK][..., :3]
    a = TrajGANPrediction(seed=0)(td.clone())
    b = TrajGANPrediction(seed=0)(td.clone())
    c = TrajGANPrediction(seed=1)(td.clone())
    torch.testing.assert_close(a[K.PRED_TRAJ], b[K.PRED_TRAJ], rtol=0, atol=0)
    assert not torch.equal(a[K.PRED_TRAJ][present], c[K.PRED_TRAJ][present])  # raw samples differ
    # the refinement is near the prior (residual of a few metres at most over 2 s)
    assert (a[K.PRED_TRAJ] - a[K.PRED_PRIOR_TRAJ]).abs().max() < 20.0
    # key gaps: TG at steps 10 and 20 minus the ego position, zero where absent (Eq. 24)
    ego_y = td[K.EGO_STATE][:, 0]
    expected = a[K.PRED_TRAJ][..., [9, 19]] - ego_y[:, None, None]
    torch.testing.assert_close(a[K.PRED_KEY_GAPS][present], expected[present])
    assert (a[K.PRED_KEY_GAPS][~present] == 0).all()
    # a stream, restartable
    t = TrajGANPrediction(seed=0)
    first = t(td.clone())[K.PRED_TRAJ]
    second = t(td.clone())[K.PRED_TRAJ]
    assert not torch.equal(first[present], second[present])
    t.reseed()
    torch.testing.assert_close(t(td.clone())[K.PRED_TRAJ], first, rtol=0, atol=0)


def test_trajgan_prediction_mean_reduction():
    td = traffic_obs()
    m0 = TrajGANPrediction(num_samples=64, reduce="mean", seed=0)(td.clone())[K.PRED_TRAJ]
    m1 = TrajGANPrediction(num_samples=64, reduce="mean", seed=1)(td.clone())[K.PRED_TRAJ]
    s0 = TrajGANPrediction(seed=0)(td.clone())[K.PRED_TRAJ]
    s1 = TrajGANPrediction(seed=1)(td.clone())[K.PRED_TRAJ]
    # averaging K draws shrinks the seed-to-seed spread
    assert (m0 - m1).abs().mean() < (s0 - s1).abs().mean()


def test_lcgan_prior_seeded():
    td = TrajGANPrediction()(traffic_obs())
    a = LCGANPrior(seed=0)(td.clone())[K.PRIOR_P_LCGAN]
    b = LCGANPrior(seed=0)(td.clone())[K.PRIOR_P_LCGAN]
    c = LCGANPrior(seed=1)(td.clone())[K.PRIOR_P_LCGAN]
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert not torch.equal(a, c)
    assert_derived(TensorDict({K.PRIOR_P_LCGAN: a}, batch_size=[8]), keys=(K.PRIOR_P_LCGAN,))
    # impossible directions are exactly zero
    lane = td[K.EGO_LANE][:, 0]
    assert (a[lane == 0, K.RIGHT] == 0).all() and (a[lane == 2, K.LEFT] == 0).all()


def test_frozen_generators_no_gradients():
    stack = make_kddrl_transforms()
    params = list(stack.parameters())
    assert params and not any(p.requires_grad for p in params)
    td = traffic_obs()
    td.set(K.NEIGHBORS_KIN, td[K.NEIGHBORS_KIN].requires_grad_(True))
    td.set(K.NEIGHBORS_REL, td[K.NEIGHBORS_REL].requires_grad_(True))
    td.set(K.EGO_STATE, td[K.EGO_STATE].requires_grad_(True))
    out = stack(td)
    for key in DERIVED:
        assert not out[key].requires_grad, key


# ------------------------------------------------------------------------------------ replay buffer
class AffineTraj(TensorDictModuleBase):
    """Deterministic stand-in for trajGAN (any module with the predictor's keys): TG = TC + 1 m."""

    in_keys = [K.PRED_PRIOR_TRAJ, K.NEIGHBORS_MASK]  # noqa: RUF012
    out_keys = [K.PRED_TRAJ]  # noqa: RUF012

    def forward(self, td):
        return td.set(K.PRED_TRAJ, td[K.PRED_PRIOR_TRAJ] + td[K.NEIGHBORS_MASK][..., :3, None].float())


class SoftmaxGaps(TensorDictModuleBase):
    """Deterministic stand-in for lcGAN: softmax of the current-lane key gaps (a function of its inputs)."""

    in_keys = [K.EGO_STATE, K.PRED_KEY_GAPS]  # noqa: RUF012
    out_keys = [K.PRIOR_P_LCGAN]  # noqa: RUF012

    def forward(self, td):
        return td.set(K.PRIOR_P_LCGAN, torch.softmax(td[K.PRED_KEY_GAPS][..., 1] / 50.0, -1))


def _rollout_and_replay(stack_fn, steps=40):
    env = TransformedEnv(FakeHighwayEnv(num_roads=3, seed=7), stack_fn())
    td = env.rollout(steps, accelerate, break_when_any_done=False)  # [K, T], crosses resets
    assert td["next", "done"].any()
    replayed = stack_fn()(strip(td).clone())  # forward on the raw [K, T] transition
    return td, replayed


def test_replay_buffer_forward_matches_rollout_exact():
    """Physics transforms, and GAN transforms with deterministic predictors: exactly the rollout values,
    for the root and the "next" observations of a [K, T] batch and through a ReplayBuffer sample."""

    def stack_fn():
        return Compose(IDMPrior(), TrajGANPrediction(AffineTraj()), MOBILPrior(), LCGANPrior(SoftmaxGaps()))

    td, replayed = _rollout_and_replay(stack_fn)
    for key in DERIVED:
        torch.testing.assert_close(replayed[key], td[key], rtol=0, atol=0)
        torch.testing.assert_close(replayed["next", key], td["next", key], rtol=0, atol=0)
    # through a replay buffer holding raw transitions, the stack as its transform
    flat = strip(td).reshape(-1)
    rb = ReplayBuffer(
        storage=LazyTensorStorage(flat.numel()),
        sampler=SamplerWithoutReplacement(),
        batch_size=16,
        transform=stack_fn(),
    )
    rb.extend(flat)
    sample, info = rb.sample(return_info=True)
    idx = torch.as_tensor(info["index"])
    expected = td.reshape(-1)[idx]
    for key in DERIVED:
        torch.testing.assert_close(sample[key], expected[key], rtol=0, atol=0)
        torch.testing.assert_close(sample["next", key], expected["next", key], rtol=0, atol=0)


def test_replay_buffer_forward_matches_rollout_gan_mean():
    """The shipped GANs through ``forward`` on [K, T]: physics keys exact; with mean reduction the GAN keys
    agree up to the Monte-Carlo error of the mean (the draws differ: rollout and replay batch differently)."""

    def stack_fn():
        return make_kddrl_transforms(num_samples=256, reduce="mean", seed=3)

    td, replayed = _rollout_and_replay(stack_fn, steps=30)
    for key in (K.PRED_PRIOR_TRAJ, K.PRIOR_P_MOBIL):
        torch.testing.assert_close(replayed[key], td[key], rtol=0, atol=0)
    torch.testing.assert_close(replayed[K.PRED_TRAJ], td[K.PRED_TRAJ], rtol=0, atol=0.05)
    torch.testing.assert_close(replayed[K.PRED_KEY_GAPS], td[K.PRED_KEY_GAPS], rtol=0, atol=0.05)
    torch.testing.assert_close(replayed[K.PRIOR_P_LCGAN], td[K.PRIOR_P_LCGAN], rtol=0, atol=0.05)


# -------------------------------------------------------------------------------------- ablations
def test_without_trajgan_key_gaps_are_the_priors():
    env = TransformedEnv(FakeHighwayEnv(num_roads=4, seed=1), make_kddrl_transforms(trajgan=False))
    check_env_specs(env, seed=None)
    td = env.rollout(20, accelerate, break_when_any_done=False)
    assert K.PRED_TRAJ not in td.keys(True) and K.PRED_TRAJ not in env.observation_spec.keys(True)
    present = td[K.NEIGHBORS_MASK][..., :3]
    expected = key_step_gaps(td[K.PRED_PRIOR_TRAJ], td[K.EGO_STATE][..., 0], present)
    torch.testing.assert_close(td[K.PRED_KEY_GAPS], expected, rtol=0, atol=0)
    torch.testing.assert_close(
        td[K.PRED_KEY_GAPS][present], (td[K.PRED_PRIOR_TRAJ][..., [9, 19]] - td[K.EGO_STATE][..., :1, None])[present]
    )
    assert_derived(td, keys=(K.PRED_PRIOR_TRAJ, K.PRED_KEY_GAPS, *PRIOR_KEYS))
    assert [type(t).__name__ for t in env.transform] == ["IDMPrior", "KeyGapsFromPrior", "MOBILPrior", "LCGANPrior"]


def test_without_priors_has_no_prior_keys():
    env = TransformedEnv(FakeHighwayEnv(num_roads=2, seed=1), make_kddrl_transforms(priors=False))
    check_env_specs(env, seed=None)
    td = env.rollout(5, accelerate, break_when_any_done=False)
    assert "prior" not in td and "prior" not in td["next"]
    assert "prior" not in env.observation_spec
    assert_derived(td, keys=PRED_KEYS)
    assert [type(t).__name__ for t in env.transform] == ["IDMPrior", "TrajGANPrediction"]


def test_factory_order_and_dict_config():
    stack = make_kddrl_transforms()
    assert [type(t).__name__ for t in stack] == ["IDMPrior", "TrajGANPrediction", "MOBILPrior", "LCGANPrior"]
    cfg = {
        "trajgan": True,
        "priors": True,
        "trajgan_checkpoint": None,
        "lcgan_checkpoint": None,
        "num_samples": 4,
        "reduce": "mean",
        "seed": 2,
        "idm": {"T": 1.2, "v0": 30.0},
        "mobil": {"politeness": 0.5},
        "num_lanes": 3,
        "device": "cpu",
    }
    stack = make_kddrl_transforms(**cfg)
    assert stack[0].idm.T == 1.2 and stack[2].mobil.politeness == 0.5 and stack[2].idm.v0 == 30.0
    assert stack[1].predictor.num_samples == 4 and stack[1].predictor.reduce == "mean"
    assert stack[3].predictor.draws == 4
    omegaconf = pytest.importorskip("omegaconf")
    stack = make_kddrl_transforms(**omegaconf.OmegaConf.create(cfg))
    assert stack[0].idm.T == pytest.approx(1.2)
    assert_derived(stack(traffic_obs()))
    with pytest.raises(ValueError):
        make_kddrl_transforms(reduce="median")
    with pytest.raises(TypeError):
        make_kddrl_transforms(**{**cfg, "unknown": 1})


# ------------------------------------------------------------------ reuse on somebody else's env
class ToyRoadEnv(EnvBase):
    """A toy 3-lane road, written without kddrl_trl's env code: a few cars at constant speed, the ego at
    constant speed in the middle lane, episodes of 30 frames. It writes the raw keys of ``kddrl_trl.keys``
    the stack reads, with its own specs, and nothing else of kddrl_trl."""

    batch_locked = True

    def __init__(self, num_envs=2, history_len=10):
        super().__init__(batch_size=torch.Size([num_envs]))
        b, self.h = (num_envs,), history_len
        self.observation_spec = Composite(
            ego=Composite(
                state=Unbounded((*b, 3)),
                lane=Bounded(0, 2, (*b, 1), dtype=torch.int64),
                lane_offset=Unbounded((*b, 1)),
                shape=b,
            ),
            neighbors=Composite(
                rel=Unbounded((*b, 6, 4)),
                mask=Categorical(2, (*b, 6), dtype=torch.bool),
                kin=Unbounded((*b, 6, 3)),
                lane_offset=Unbounded((*b, 6)),
                shape=b,
            ),
            leaders=Composite(ahead=Unbounded((*b, 3, 3)), history=Unbounded((*b, 3, history_len, 2)), shape=b),
            shape=b,
        )
        self.action_spec = Bounded(-3.0, 3.0, (*b, 1))
        self.reward_spec = Unbounded((*b, 1))
        self.t = torch.zeros(num_envs, dtype=torch.long)
        # per lane (0, 1, 2): cars at these offsets ahead of / behind the ego start, with these speeds
        self.car_y0 = torch.tensor([[30.0, 90.0, -25.0], [45.0, 110.0, -40.0], [20.0, 70.0, -15.0]])
        self.car_v = torch.tensor([[27.0, 26.0, 28.0], [24.0, 23.0, 26.0], [22.0, 21.0, 23.0]])

    def _obs(self):
        n, dt = self.batch_size[0], 0.1
        t = self.t.float()[:, None, None]
        ego_y, ego_v = 25.0 * self.t.float() * dt, torch.full((n,), 25.0)
        car_y = self.car_y0 + self.car_v * t * dt  # [n, lane, car]
        rel_y = car_y - ego_y[:, None, None]
        lanes = (2, 1, 0)  # left, current, right of lane 1
        kin, mask, rel, ahead, hist = [], [], [], [], []
        for leader in (True, False):
            for lane in lanes:
                ry = rel_y[:, lane]
                cand = torch.where(ry > 0 if leader else ry <= 0, ry.abs(), torch.full_like(ry, float("inf")))
                j = cand.argmin(-1)
                ok = torch.isfinite(cand.gather(-1, j[:, None]))[:, 0]
                y, v = car_y[:, lane].gather(-1, j[:, None])[:, 0], self.car_v[lane][j]
                kin.append(torch.stack([y, v, torch.zeros(n)], -1))
                mask.append(ok)
                rel.append(torch.stack([torch.full((n,), 3.5 * (lane - 1)), y - ego_y, torch.zeros(n), v - ego_v], -1))
                if leader:
                    gap = torch.where(
                        car_y[:, lane] > y[:, None],
                        car_y[:, lane] - y[:, None],
                        torch.full_like(car_y[:, lane], float("inf")),
                    )
                    k = gap.argmin(-1)
                    has = torch.isfinite(gap.gather(-1, k[:, None]))[:, 0]
                    ahead.append(
                        torch.stack(
                            [car_y[:, lane].gather(-1, k[:, None])[:, 0] * has, self.car_v[lane][k] * has, has.float()],
                            -1,
                        )
                    )
                    back = torch.arange(self.h - 1, -1, -1).float() * dt
                    hist.append(torch.stack([y[:, None] - v[:, None] * back, v[:, None].expand(n, self.h)], -1))
        return TensorDict(
            {
                K.EGO_STATE: torch.stack([ego_y, ego_v, torch.zeros(n)], -1),
                K.EGO_LANE: torch.ones(n, 1, dtype=torch.long),
                K.NEIGHBORS_KIN: torch.stack(kin, 1),
                K.NEIGHBORS_MASK: torch.stack(mask, 1),
                K.NEIGHBORS_REL: torch.stack(rel, 1),
                K.LEADERS_AHEAD: torch.stack(ahead, 1),
                K.LEADERS_HISTORY: torch.stack(hist, 1),
                K.EGO_LANE_OFFSET: torch.zeros(n, 1),
                K.NEIGHBORS_LANE_OFFSET: torch.zeros(n, 6),
            },
            batch_size=self.batch_size,
        )

    def _reset(self, tensordict=None, **kwargs):
        rows = (
            tensordict.get("_reset").reshape(-1)
            if tensordict is not None and "_reset" in tensordict
            else torch.ones_like(self.t, dtype=torch.bool)
        )
        self.t[rows] = 0
        out = self._obs()
        out.set("done", torch.zeros(*self.batch_size, 1, dtype=torch.bool))
        out.set("terminated", torch.zeros(*self.batch_size, 1, dtype=torch.bool))
        return out

    def _step(self, tensordict):
        self.t += 1
        out = self._obs()
        done = (self.t >= 30)[:, None]
        out.set("reward", torch.zeros(*self.batch_size, 1))
        out.set("done", done)
        out.set("terminated", done.clone())
        return out

    def _set_seed(self, seed):
        pass


def test_stack_reusable_on_a_foreign_env():
    base = ToyRoadEnv(num_envs=3)
    check_env_specs(base, seed=None)
    env = TransformedEnv(base, make_kddrl_transforms())
    check_env_specs(env, seed=None)
    td = env.rollout(40, break_when_any_done=False)  # crosses the 30-frame episode end
    assert td["next", "done"].any()
    assert_derived(td)
    assert_derived(td["next"])
    present = td[K.NEIGHBORS_MASK][..., :3]
    assert present.all()  # every lane has a leader on the toy road
    assert (td[K.PRED_KEY_GAPS][..., 1] > td[K.PRED_KEY_GAPS][..., 0]).all()  # leaders move forward


def test_compiled_stack_matches_eager_stack():
    """``compile=True`` (physics priors and GAN inference through torch.compile) changes speed, not values."""
    import shutil

    from kddrl_trl import keys as K
    from kddrl_trl.envs import FakeHighwayEnv
    from kddrl_trl.transforms import make_kddrl_transforms

    if not any(shutil.which(c) for c in ("c++", "g++", "clang++")):
        pytest.skip("torch.compile needs a C++ compiler on a CPU machine")
    from torch._dynamo.utils import clear_compilation_metrics, get_compilation_metrics

    env = FakeHighwayEnv(num_roads=5, seed=3)
    td = env.rollout(12, break_when_any_done=False)["next"].reshape(-1)
    eager = make_kddrl_transforms(seed=4)(td.clone())
    torch._dynamo.reset()  # the stack's graph is traced here, whatever ran before in this process
    clear_compilation_metrics()
    compiled = make_kddrl_transforms(seed=4, compile=True)(td.clone())
    traced = [m for m in get_compilation_metrics() if m.co_name == "run_frames"]
    assert len(traced) == 1 and not traced[0].restart_reasons, [(m.restart_reasons, m.fail_reason) for m in traced]
    for key in (K.PRED_PRIOR_TRAJ, K.PRED_TRAJ, K.PRED_KEY_GAPS, K.PRIOR_P_MOBIL, K.PRIOR_P_LCGAN):
        torch.testing.assert_close(compiled[key], eager[key], rtol=1e-4, atol=1e-3, msg=str(key))
    # a member used on its own, outside the stack (eager: only the stack compiles), gives the same values too
    member = make_kddrl_transforms(seed=4, compile=True)[1]
    one = member(IDMPrior()(td.clone()))
    torch.testing.assert_close(one[K.PRED_TRAJ], eager[K.PRED_TRAJ], rtol=1e-4, atol=1e-3)


def test_compiled_stack_calls_its_warm_graph_directly_with_the_same_bits():
    """Once warm, a compiled stack runs its graph without TorchDynamo (``warm_frames``), and gives what the same
    graph gives under TorchDynamo's guards, bit for bit, call after call; what it keeps goes with the stack."""
    import gc
    import shutil

    from kddrl_trl.envs import FakeHighwayEnv
    from kddrl_trl.transforms import make_kddrl_transforms
    from kddrl_trl.transforms.stack import _WARM, warm_frames

    if not any(shutil.which(c) for c in ("c++", "g++", "clang++")):
        pytest.skip("torch.compile needs a C++ compiler on a CPU machine")
    frames = FakeHighwayEnv(num_roads=3, seed=7).rollout(6, break_when_any_done=False)["next"]
    direct, guarded = make_kddrl_transforms(seed=5, compile=True), make_kddrl_transforms(seed=5, compile=True)
    warm_frames(guarded).guard_every_call()  # never warm: every call under TorchDynamo's guards
    for t in range(frames.shape[1]):  # the noise streams advance alike in both
        a, b = direct(frames[:, t].clone()), guarded(frames[:, t].clone())
        for key in DERIVED:
            assert torch.equal(a[key], b[key]), (t, key)
    warm = warm_frames(direct)
    graphs = [f for f in warm.direct.values() if f is not None]
    assert len(graphs) == 1 and sum(warm.calls.values()) == 2  # two guarded calls, then the direct graph
    assert not any(f is not None for f in warm_frames(guarded).direct.values())
    n = len(_WARM)
    del direct, warm, graphs
    gc.collect()
    assert len(_WARM) == n - 1  # the dropped stack's calls are dropped with it


# ------------------------------------------------------------------------------ the fused stack
@pytest.mark.parametrize("trajgan,priors", [(True, True), (False, True), (True, False), (False, False)])
def test_fused_stack_equals_members_one_by_one(trajgan, priors):
    """``PredictiveStack`` (one function per frame) gives exactly what its members give when chained by a
    plain ``Compose``: same values, same noise streams over successive calls, reset and step alike."""
    from kddrl_trl.transforms import PredictiveStack

    env = FakeHighwayEnv(num_roads=4, seed=5)
    frames = env.rollout(6, accelerate, break_when_any_done=False)["next"]
    fused = make_kddrl_transforms(trajgan, priors, seed=9)
    chained = Compose(*make_kddrl_transforms(trajgan, priors, seed=9).transforms)
    assert isinstance(fused, PredictiveStack) and not isinstance(chained, PredictiveStack)
    for t in range(frames.shape[1]):  # successive calls: the generators' streams advance alike
        a, b = fused(frames[:, t].clone()), chained(frames[:, t].clone())
        for key in fused.transforms[-1].out_keys + fused.transforms[0].out_keys:
            assert torch.equal(a[key], b[key]), (t, key)
        assert set(a.keys(include_nested=True)) == set(b.keys(include_nested=True))
    # in an env, with partial resets
    run_f = TransformedEnv(FakeHighwayEnv(num_roads=3, seed=2), make_kddrl_transforms(trajgan, priors, seed=1))
    run_c = TransformedEnv(
        FakeHighwayEnv(num_roads=3, seed=2), Compose(*make_kddrl_transforms(trajgan, priors, seed=1).transforms)
    )
    ra = run_f.rollout(40, accelerate, break_when_any_done=False)
    rb = run_c.rollout(40, accelerate, break_when_any_done=False)
    assert ra["next", "done"].any() and not ra["next", "done"].all()
    assert (ra == rb).all()


def test_fused_stack_falls_back_to_members():
    """A stack holding a user's transform runs the members one by one; a user's predictor module is run
    eagerly inside the fused function; a missing raw key is named."""
    from torchrl.envs.transforms import RenameTransform

    from kddrl_trl.transforms import PredictiveStack

    obs = FakeHighwayEnv(num_roads=3, seed=1).reset()
    stack = make_kddrl_transforms(seed=0)
    stack.append(RenameTransform([K.PRIOR_P_MOBIL], [("prior", "mobil_copy")], create_copy=True))
    out = stack(obs.clone())
    torch.testing.assert_close(out["prior", "mobil_copy"], out[K.PRIOR_P_MOBIL])
    assert_derived(out)

    user = PredictiveStack(
        IDMPrior(), TrajGANPrediction(AffineTraj()), MOBILPrior(), LCGANPrior(SoftmaxGaps()), compile=False
    )
    assert not user[1].pure and user[0].pure
    ref = Compose(IDMPrior(), TrajGANPrediction(AffineTraj()), MOBILPrior(), LCGANPrior(SoftmaxGaps()))(obs.clone())
    got = user(obs.clone())
    for key in DERIVED:
        assert torch.equal(got[key], ref[key]), key

    with pytest.raises(KeyError, match="leaders"):
        make_kddrl_transforms()(obs.exclude(K.LEADERS_AHEAD))
    # the leaders' history is optional (issue 17): a lone frame without it gets fresh windows (LeaderHistory)
    assert_derived(make_kddrl_transforms()(obs.exclude(K.LEADERS_HISTORY)))


def test_compiled_stack_pickles():
    """A compiled stack (e.g. handed to spawned workers) pickles (it stores nothing compiled: the compiled
    function lives in the process) and runs (the noise streams travel with it)."""
    import pickle

    obs = FakeHighwayEnv(num_roads=2, seed=6).reset()
    stack = make_kddrl_transforms(seed=2, compile=True)
    copy = pickle.loads(pickle.dumps(stack))
    assert isinstance(copy, type(stack)) and [type(t) for t in copy] == [type(t) for t in stack]
    eager = pickle.loads(pickle.dumps(make_kddrl_transforms(seed=2)))
    out, ref = copy(obs.clone()), eager(obs.clone())
    for key in DERIVED:
        torch.testing.assert_close(out[key], ref[key], rtol=1e-4, atol=1e-3, msg=str(key))


# ------------------------------------------------------------------------------------------------ issue 14
def _one_ego(lane=1, kin=None, mask=None, env_mask=(True, True, True)) -> TensorDict:
    """Raw keys of one ego at y = 100 m, 30 m/s (neighbours a-f given as {slot: (y, v, a)})."""
    k, m = torch.zeros(1, 6, 3), torch.zeros(1, 6, dtype=torch.bool)
    for slot, values in (kin or {}).items():
        k[0, K.SLOT[slot]] = torch.tensor(values)
        m[0, K.SLOT[slot]] = True
    return TensorDict(
        {
            K.EGO_STATE: torch.tensor([[100.0, 30.0, 0.0]]),
            K.EGO_LANE: torch.tensor([[lane]]),
            K.NEIGHBORS_KIN: k,
            K.NEIGHBORS_MASK: m,
            K.LC_ACTIVE: torch.zeros(1, 1, dtype=torch.bool),
            K.LC_ACTION_MASK: torch.tensor([env_mask]),
            K.CF_ACTION: torch.full((1, 1), 5.0),
        },
        [1],
    )


def test_mobil_safety_mask_ands_eq_20_21_into_the_command_mask():
    """F1: a left change with the left follower 2 m behind (Eq. 20) is refused; a right change with room is kept; the
    env's own mask (no lane, manoeuvre under way) still applies; keep is always allowed."""
    from kddrl_trl.transforms import MOBILSafetyMask

    mask = MOBILSafetyMask()
    td = _one_ego(kin={"d": (98.0, 30.0, 0.0), "c": (200.0, 30.0, 0.0), "f": (50.0, 30.0, 0.0)})
    assert mask(td.clone())[K.LC_ACTION_MASK].tolist() == [[False, True, True]]
    td = _one_ego(kin={"c": (200.0, 30.0, 0.0), "f": (50.0, 30.0, 0.0)}, env_mask=(True, True, False))
    assert mask(td.clone())[K.LC_ACTION_MASK].tolist() == [[True, True, False]]
    td = _one_ego(kin={"f": (92.0, 30.0, 0.0)})  # the right follower would brake below -b_safe
    assert mask(td.clone())[K.LC_ACTION_MASK].tolist() == [[True, True, False]]
    # on an env: specs hold, and the mask only ever removes commands
    check_env_specs(TransformedEnv(FakeHighwayEnv(num_roads=4, seed=0), MOBILSafetyMask()))
    env = TransformedEnv(FakeHighwayEnv(num_roads=4, seed=0), MOBILSafetyMask())
    raw = FakeHighwayEnv(num_roads=4, seed=0)

    def keep(td):
        return td.update({K.LC_ACTION: F.one_hot(torch.full((4,), K.KEEP), 3).float(), K.CF_ACTION: torch.zeros(4, 1)})

    roll, bare = env.rollout(30, keep, break_when_any_done=False), raw.rollout(30, keep, break_when_any_done=False)
    assert not (roll[K.LC_ACTION_MASK] & ~bare[K.LC_ACTION_MASK]).any() and roll[K.LC_ACTION_MASK][..., K.KEEP].all()
    assert (roll[K.LC_ACTION_MASK] != bare[K.LC_ACTION_MASK]).any()  # and it does remove some


def test_mobil_safety_mask_is_switched_by_the_algo_option():
    from testkit import compose_job

    from kddrl_trl.conf.schema import HierarchicalAlgo
    from kddrl_trl.factories import make_transforms
    from kddrl_trl.transforms import DecisionClock, MOBILSafetyMask, SafetyShield

    job = compose_job("algo=d3qn_td3")
    assert not any(isinstance(t, MOBILSafetyMask) for t in make_transforms(job.algo, 0, job.env.highway()).transforms)
    job = compose_job("algo=d3qn_td3", "algo.mobil_safety_mask=true", "algo.shield=idm")
    kinds = [type(t) for t in make_transforms(job.algo, 0, job.env.highway()).transforms]
    assert isinstance(job.algo, HierarchicalAlgo) and kinds == [MOBILSafetyMask, DecisionClock, SafetyShield]
    rule = compose_job("algo=idm_mobil", "algo.shield=ttc")
    assert [type(t) for t in make_transforms(rule.algo, 0, rule.env.highway()).transforms] == [SafetyShield]


def test_safety_bounds():
    """a_safe: no leader -> the action bound; idm = Eq. 11-12's interaction term only (v0 = inf); ttc = the
    deceleration cancelling the closing speed before min_gap, only below the TTC threshold."""
    from kddrl_trl.physics import idm_acceleration
    from kddrl_trl.transforms.shield import safe_acceleration

    kw = dict(idm=IDMParams(v0=math.inf), ttc=3.0, min_gap=2.0, high=5.0)
    assert safe_acceleration(_one_ego(), "idm", **kw).item() == 5.0
    assert safe_acceleration(_one_ego(), "ttc", **kw).item() == 5.0
    close = _one_ego(kin={"b": (135.0, 20.0, -1.0)})  # gap 30 m, closing at 10 m/s: TTC 3 s
    expected = idm_acceleration(torch.tensor(30.0), torch.tensor(20.0), torch.tensor(30.0), IDMParams(v0=math.inf))
    assert safe_acceleration(close, "idm", **kw).item() == pytest.approx(expected.item())
    assert safe_acceleration(close, "ttc", **kw).item() == 5.0  # TTC = 3 s: not below the threshold
    closer = _one_ego(kin={"b": (125.0, 20.0, -1.0)})  # gap 20 m: TTC 2 s
    assert safe_acceleration(closer, "ttc", **kw).item() == pytest.approx(-1.0 - 10.0**2 / (2 * 18.0))
    # the left leader counts only during a left lane change
    left = _one_ego(kin={"a": (110.0, 10.0, 0.0)})
    assert safe_acceleration(left, "ttc", **kw).item() == 5.0
    left.set(K.LC_ACTIVE, torch.ones(1, 1, dtype=torch.bool))
    left.set(K.EGO_STATE, torch.tensor([[100.0, 30.0, 1.0]]))
    assert safe_acceleration(left, "ttc", **kw).item() < -5.0


@pytest.mark.parametrize("kind", ["idm", "ttc", "rss"])
def test_shield_executes_and_records_the_bounded_action_and_counts_interventions(kind):
    """The env executes min(a_agent, a_safe); the collected frame holds the executed action (buffer L learns the
    transition that happened); ("next", "cf", "shield") flags the frames; the tracker counts them per episode."""
    from tensordict.nn import TensorDictModule

    from kddrl_trl.eval import evaluate_policy
    from kddrl_trl.eval.metrics import summarize
    from kddrl_trl.transforms import SafetyShield

    def env_():
        return TransformedEnv(FakeHighwayEnv(num_roads=4, seed=0, ego_start="window"), SafetyShield(kind))

    env = env_()
    check_env_specs(env)
    floor_it = TensorDictModule(
        lambda s: (F.one_hot(torch.full(s.shape[:-1], K.KEEP), 3).float(), torch.full_like(s[..., :1], 5.0)),
        in_keys=[K.EGO_STATE],
        out_keys=[K.LC_ACTION, K.CF_ACTION],
    )
    roll = env.rollout(61, floor_it, break_when_any_done=False)[:, :-1]  # TorchRL runs no hook on the last step
    flag = roll["next", *K.CF_SHIELD][..., 0]
    action = roll[K.CF_ACTION][..., 0]
    assert flag.any() and (action[flag] < 5.0).all() and (action[~flag] == 5.0).all()
    moving = roll["next", *K.EGO_STATE][..., 1] > 0.5  # v' = max(v + a dt, 0): executed = command
    assert torch.allclose(roll["next", *K.EGO_ACCEL][..., 0][moving], action[moving], atol=1e-3)
    from torchrl.collectors import Collector

    collector = Collector(
        env_(), floor_it, frames_per_batch=80, total_frames=80, trust_policy=True, auto_register_policy_transforms=False
    )
    batch = next(iter(collector))  # what buffer L receives
    collector.shutdown()
    flag, action = batch["next", *K.CF_SHIELD][..., 0], batch[K.CF_ACTION][..., 0]
    assert flag.any() and (action[flag] < 5.0).all() and (action[~flag] == 5.0).all()
    episodes = evaluate_policy(env_(), floor_it, episodes=4, seed=0, progress=False)
    assert sum(e["shield_interventions"] for e in episodes) > 0
    assert all(e["shield_rate"] == pytest.approx(e["shield_interventions"] / e["frames"]) for e in episodes)
    assert 0 < summarize(episodes)["shield_rate"] <= 1
    bare = evaluate_policy(FakeHighwayEnv(num_roads=4, seed=0), floor_it, episodes=2, seed=0, progress=False)
    assert all(e["shield_interventions"] == 0 for e in bare)  # no shield: the key is absent, counted as 0
    # in a ParallelEnv worker (the periodic evaluation's), whose TensorDicts are locked: the shield still acts
    from functools import partial

    from torchrl.envs import ParallelEnv

    worker = ParallelEnv(1, partial(shielded_fake_env, kind), mp_start_method="spawn")
    try:
        episodes = evaluate_policy(worker, floor_it, episodes=4, seed=0, progress=False)
    finally:
        worker.close()
    assert sum(e["shield_interventions"] for e in episodes) > 0


def shielded_fake_env(kind: str):
    """The fake env of 4 roads behind a :class:`~kddrl_trl.transforms.SafetyShield` (picklable for a worker)."""
    from kddrl_trl.transforms import SafetyShield

    return TransformedEnv(FakeHighwayEnv(num_roads=4, seed=0, ego_start="window"), SafetyShield(kind))


def _generator_state(stack, kind: str) -> dict:
    from kddrl_trl.transforms import LCGANPrior, TrajGANPrediction

    cls = TrajGANPrediction if kind == "trajgan" else LCGANPrior
    (t,) = [t for t in stack.transforms if isinstance(t, cls)]
    return {k: v.clone() for k, v in t.predictor.state_dict().items()}


@pytest.mark.parametrize("kind", ["trajgan", "lcgan"])
def test_gan_weights_follow_the_env_simulator_unless_named(kind):
    """``algo.transforms.weights=auto`` loads the GAN weights trained on the traffic of the env's simulator;
    ``sumo`` / ``highwayenv`` name them; a checkpoint path wins; an unknown name is refused by the schema."""
    from testkit import compose_job

    from kddrl_trl.factories import make_transforms
    from kddrl_trl.generative import default_checkpoint, load_predictor

    def loaded(*overrides):
        job = compose_job("env=highwayenv", *overrides)
        (stack,) = [
            t
            for t in make_transforms(job.algo, 0, job.env.highway(), simulator="highwayenv").transforms
            if hasattr(t, "transforms")
        ]
        return _generator_state(stack, kind)

    def shipped(traffic):
        return {k: v.clone() for k, v in load_predictor(kind, traffic=traffic).state_dict().items()}

    def same(a, b):
        return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)

    assert not same(shipped("sumo"), shipped("highwayenv"))
    assert same(loaded(), shipped("highwayenv"))
    assert same(loaded("algo.transforms.weights=sumo"), shipped("sumo"))
    path = default_checkpoint(kind, "sumo")
    assert same(loaded(f"algo.transforms.{kind}_checkpoint={path}"), shipped("sumo"))
    job = compose_job("algo.transforms.weights=auto")  # SUMO: the SUMO weights
    (stack,) = [t for t in make_transforms(job.algo, 0, job.env.highway()).transforms if hasattr(t, "transforms")]
    assert same(_generator_state(stack, kind), shipped("sumo"))
    with pytest.raises(Exception, match="weights"):
        compose_job("algo.transforms.weights=carla")
