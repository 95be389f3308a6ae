"""N learners in one (``seeds=N``, :mod:`kddrl_trl.modules.seed_batch`): each seed of the batch is the single
learner it was loaded from, update for update, and no seed reads another's weights, data or gradients."""

from __future__ import annotations

import pytest
import torch
from testkit import SMALL, fake_samples

from kddrl_trl.modules.seed_batch import SeedLinear, load_seeds, seed_slice, stack_seeds, stacked_names
from kddrl_trl.training import HierarchicalLearner

N = 3
#: TD3's target-policy smoothing draws noise of the minibatch's shape; without it the batched and the single
#: updates see the same arithmetic (the noise's own stream is per call, not per seed)
NO_SMOOTHING = {**SMALL, "td3": {**SMALL["td3"], "policy_noise": 0.0}}


@pytest.fixture(scope="module")
def samples():
    frames, macros = fake_samples(12, 6)
    return [f.exclude("priority") for f in frames], [m.exclude("priority") for m in macros]


def singles(cfg=NO_SMOOTHING, n=N):
    out = []
    for i in range(n):
        torch.manual_seed(i)
        out.append(HierarchicalLearner(**cfg))
    return out


def batched(learners, cfg=NO_SMOOTHING):
    b = HierarchicalLearner(**cfg, seeds=len(learners))
    load_seeds(b, learners)
    return b


def per_seed(samples_, step):
    """Seed i's minibatch at ``step``: a different sample for every seed and step."""
    frames, macros = samples_
    return [frames[(step * N + i) % len(frames)] for i in range(N)], [
        macros[(step + i) % len(macros)] for i in range(N)
    ]


def run_batched(b, samples_, steps=4, change=None):
    out = []
    for step in range(steps):
        f, m = per_seed(samples_, step)
        if change is not None:
            f, m = change(f, m)
        out.append((b.update_cf(torch.stack([x.clone() for x in f])), b.update_lc(torch.stack([x.clone() for x in m]))))
    return out


def test_each_seed_of_a_batch_is_its_single_learner_update_for_update(samples):
    """4 TD3 and 4 D3QN updates (the actor and the soft targets twice), each seed on its own minibatches: every
    loss and, after them, every tensor of seed i equals the single learner i's to float tolerance (the batched
    matrix products round differently); the updates moved them."""
    ones = singles()
    b = batched(ones)
    for i, one in enumerate(ones):
        assert all(torch.equal(seed_slice(b, i)[k], v) for k, v in one.state_dict().items())
    start = seed_slice(b, 0)
    losses = run_batched(b, samples)
    for step, (cf, lc) in enumerate(losses):
        f, m = per_seed(samples, step)
        for i, one in enumerate(ones):
            o_cf, o_lc = one.update_cf(f[i].clone()), one.update_lc(m[i].clone())
            for k in o_cf:
                torch.testing.assert_close(cf[k][i], o_cf[k], rtol=1e-5, atol=1e-6)
            torch.testing.assert_close(lc["loss_lc"][i], o_lc["loss_lc"], rtol=1e-5, atol=1e-6)
    for i, one in enumerate(ones):
        mine = seed_slice(b, i)
        for k, v in one.state_dict().items():
            torch.testing.assert_close(mine[k], v, rtol=1e-5, atol=1e-6, msg=k)
    moved = [k for k in stacked_names(b) if not torch.equal(seed_slice(b, 0)[k], start[k])]
    assert len(moved) > len(stacked_names(b)) // 2


def test_no_seed_reads_another_seeds_weights_data_or_gradients(samples):
    """Seed 1's minibatches replaced by others and its weights perturbed: seeds 0 and 2 end bit for bit where they
    ended before; and the gradient of seed 0's loss is exactly zero in every other seed's slice."""
    ref = batched(singles())
    run_batched(ref, samples)

    other = batched(singles())
    with torch.no_grad():
        for name in stacked_names(other):
            t = dict(other.named_parameters(remove_duplicate=False)).get(name)
            if t is not None:
                from kddrl_trl.modules.seed_batch import seed_dim

                t.select(seed_dim(name, t), 1).add_(0.1)
    frames, macros = samples
    swap = lambda f, m: ([f[0], frames[-1], f[2]], [m[0], macros[-1], m[2]])  # noqa: E731
    run_batched(other, samples, change=swap)
    for i in (0, 2):
        a, c = seed_slice(ref, i), seed_slice(other, i)
        for k in stacked_names(ref):
            assert torch.equal(a[k], c[k]), k
    assert not torch.equal(seed_slice(ref, 1)[stacked_names(ref)[0]], seed_slice(other, 1)[stacked_names(ref)[0]])

    b = batched(singles())
    f, _ = per_seed(samples, 0)
    losses, _ = b.loss("cf_value", torch.stack(f))
    from kddrl_trl.modules.seed_batch import seed_dim, seed_means

    params = [p for p in b.parameters() if p.requires_grad]
    grads = torch.autograd.grad(seed_means(losses, torch.stack(f))[0], params, allow_unused=True)
    reached = 0
    names = {id(p): n for n, p in b.named_parameters()}
    for p, g in zip(params, grads):
        if g is None:
            continue
        d = seed_dim(names[id(p)], p)
        assert torch.count_nonzero(g.narrow(d, 1, N - 1)) == 0, names[id(p)]
        reached += bool(torch.count_nonzero(g.select(d, 0)))
    assert reached > 0


def test_seed_linear_refuses_an_input_without_the_seed_dimension():
    layer = stack_seeds(torch.nn.Sequential(torch.nn.Linear(4, 2)), 3)[0]
    assert isinstance(layer, SeedLinear) and layer.weight.shape == (3, 2, 4)
    assert layer(torch.randn(3, 5, 7, 4)).shape == (3, 5, 7, 2)
    with pytest.raises(ValueError, match="seed dimension"):
        layer(torch.randn(5, 4))


def test_load_seeds_refuses_learners_that_differ_where_nothing_is_stacked():
    ones = singles(n=2)
    ones[1].counters[1] = 5  # the update counters are one for the batch (the seeds update together)
    with pytest.raises(ValueError, match="counters"):
        batched(ones)


def test_a_batch_acts_on_n_times_k_rows_as_each_seed_on_its_own_k(samples):
    """Greedy actions of a batch of 3 seeds on 3 x 2 env rows, seed-major, with decision and held rows mixed: seed
    i's rows get single learner i's lane-change and car-following actions; the batch refuses rows that do not split
    into its seeds."""
    from tensordict.nn import set_interaction_type
    from torchrl.envs import Compose, ExplorationType, TransformedEnv

    from kddrl_trl import keys as K
    from kddrl_trl.envs import FakeHighwayEnv
    from kddrl_trl.transforms import DecisionClock, make_kddrl_transforms

    ones = singles()
    b = batched(ones)
    env = TransformedEnv(FakeHighwayEnv(num_roads=6, seed=3), Compose(make_kddrl_transforms(), DecisionClock(5)))
    td = env.reset()
    td.set(K.LC_DECIDE, torch.tensor([True, False, False, True, True, False]).reshape(td.get(K.LC_DECIDE).shape))
    with set_interaction_type(ExplorationType.DETERMINISTIC):
        acted = b.policy(explore=False)(td.clone())
        for i, one in enumerate(ones):
            own = one.policy(explore=False)(td[2 * i : 2 * i + 2].clone())
            assert torch.equal(acted.get(K.LC_ACTION)[2 * i : 2 * i + 2], own.get(K.LC_ACTION))
            torch.testing.assert_close(acted.get(K.CF_ACTION)[2 * i : 2 * i + 2], own.get(K.CF_ACTION))
        with pytest.raises(ValueError, match="N x K rows"):
            b.policy(explore=False)(td[:5].clone())


def test_each_seed_anneals_its_own_epsilon_by_its_own_decisions():
    """ε of seed i after its decisions equals TorchRL's ``EGreedyModule.step`` on the single learner i."""
    ones = singles()
    b = batched(ones)
    b.explore_step([3, 0, 7], 10)
    for one, n in zip(ones, (3, 0, 7)):
        one.explore_step(n, 10)
    assert b.exploration()["epsilon"] == [float(one.lc_explore.eps) for one in ones]
    assert len(set(b.exploration()["epsilon"])) == 3


def test_a_seed_that_sits_steps_out_is_untouched_and_later_steps_as_its_own_count(samples):
    """D3QN steps that some seeds sit out (a seed learns once per decision of its own): a seed's networks, targets
    and optimiser states are bit for bit as before a step it sat out, and after 3 steps each seed equals its single
    learner that took only the steps it took (its own Adam step count: SeedAdam)."""
    ones = singles()
    b = batched(ones)
    masks = [[True, False, True], [True, True, False], [True, True, True]]
    for step, mask in enumerate(masks):
        f, m = per_seed(samples, step)
        b.update_cf(torch.stack([x.clone() for x in f]))
        before = seed_slice(b, mask.index(False)) if not all(mask) else None
        moments = [t.select(d, mask.index(False)).clone() for t, d in b.opt_lc.seed_tensors()] if before else None
        b.update_lc(torch.stack([x.clone() for x in m]), active=torch.tensor(mask))
        if before is not None:  # the idle seed: the D3QN step moved none of its tensors (the embedding's included)
            after = seed_slice(b, mask.index(False))
            assert all(torch.equal(before[k], after[k]) for k in stacked_names(b))
            now = [t.select(d, mask.index(False)) for t, d in b.opt_lc.seed_tensors()]
            assert moments and all(torch.equal(x, y) for x, y in zip(moments, now))  # its Adam moments and step count
        for i, one in enumerate(ones):
            one.update_cf(f[i].clone())
            if mask[i]:
                one.update_lc(m[i].clone())
    steps = b.opt_lc.state[b.opt_lc.param_groups[0]["params"][0]]["step"]
    assert steps.tolist() == [3.0, 2.0, 2.0]
    for i, one in enumerate(ones):
        mine = seed_slice(b, i)
        for k, v in one.state_dict().items():
            if k != "counters":  # the batch's update counters are shared (the trainer counts each seed's own)
                torch.testing.assert_close(mine[k], v, rtol=1e-5, atol=1e-6, msg=k)


def test_the_collector_fills_each_seeds_buffers_with_its_own_rows_only():
    """A seed batch of 2 on 2 x 2 fake-env rows, 2 iterations: seed i's buffer L holds exactly its rows' frames and
    its buffer H exactly what a writer of its own makes of its rows (its macro-transitions carried across the
    iterations); the rows are acted on by the batch's policy."""
    from torchrl.envs import Compose, TransformedEnv

    from kddrl_trl import keys as K
    from kddrl_trl.collectors import MacroTransitionWriter, MultiTimescaleCollector
    from kddrl_trl.envs import FakeHighwayEnv
    from kddrl_trl.training import make_buffer
    from kddrl_trl.transforms import DecisionClock, make_kddrl_transforms

    b = batched(singles(n=2))
    env = TransformedEnv(FakeHighwayEnv(num_roads=4, seed=0), Compose(make_kddrl_transforms(), DecisionClock(5)))
    frames_l, macros_h = [make_buffer(5000, 8, i) for i in range(2)], [make_buffer(5000, 8, i) for i in range(2)]
    mtc = MultiTimescaleCollector.from_env(
        env, b.policy(), frames_per_env=30, frame_buffer=frames_l, macro_buffer=macros_h, seeds=2
    )
    batches = []
    for batch in mtc:
        batches.append(batch)
        if len(batches) == 2:
            break
    mtc.shutdown()
    for i in range(2):
        own = torch.cat([bt.frames[2 * i : 2 * i + 2].reshape(-1) for bt in batches])
        assert len(frames_l[i]) == own.numel() == 2 * 2 * 30
        stored = frames_l[i][:]
        assert torch.equal(stored.get(K.EGO_STATE), own.get(K.EGO_STATE))
        writer = MacroTransitionWriter()
        expect = [m for m in (writer(bt.frames[2 * i : 2 * i + 2]) for bt in batches) if m is not None]
        expect = torch.cat(expect) if expect else None
        assert expect is not None and len(macros_h[i]) == expect.numel()
        assert torch.equal(macros_h[i][:].get(("next", K.LC_REWARD)), expect.get(("next", K.LC_REWARD)))
        assert [bt.seed_macros[i] is None for bt in batches] != [True, True]


def test_a_seed_leaves_the_batch_as_a_single_learner_and_comes_back(samples):
    """After 3 batched steps (the D3QN's partly sat out), seed i's state (``seed_full_state``, what its own
    checkpoint holds) loaded into a single learner trains on as the batch's seed i does; and written back into a
    fresh batch seed by seed (``load_seed_state``, a resumed batch) it gives the same batch, optimiser states
    included."""
    from kddrl_trl.training.seed_split import load_seed_state, seed_full_state

    b = batched(singles())
    for step, mask in enumerate([[True, False, True], [True, True, True], [False, True, True]]):
        f, m = per_seed(samples, step)
        b.update_cf(torch.stack([x.clone() for x in f]))
        b.update_lc(torch.stack([x.clone() for x in m]), active=torch.tensor(mask))
    states = [seed_full_state(b, i) for i in range(N)]
    again = HierarchicalLearner(**NO_SMOOTHING, seeds=N)
    for i, state in enumerate(states):
        load_seed_state(again, i, state)
    for k, v in b.state_dict().items():
        assert torch.equal(again.state_dict()[k], v), k
    for name, opt in b.optimizers().items():
        mine = again.optimizers()[name].state_dict()["state"]
        for idx, s in opt.state_dict()["state"].items():
            assert all(torch.equal(mine[idx][key], s[key]) for key in s), (name, idx)
    alone = []
    for i, state in enumerate(states):
        one = HierarchicalLearner(**NO_SMOOTHING)
        one.load_full_state_dict(state)
        alone.append(one)
    f, m = per_seed(samples, 3)
    b.update_cf(torch.stack([x.clone() for x in f]))
    b.update_lc(torch.stack([x.clone() for x in m]))
    for i, one in enumerate(alone):
        one.update_cf(f[i].clone())
        one.update_lc(m[i].clone())
        mine = seed_slice(b, i)
        for k, v in one.state_dict().items():
            if k != "counters":
                torch.testing.assert_close(mine[k], v, rtol=1e-5, atol=1e-6, msg=k)


def test_seed_adam_s_step_sets_no_attribute():
    """SeedAdam takes its per-seed views when it is built, so a step only writes tensors: TorchDynamo (torch 2.11
    on a GPU) refuses to compile a step that sets an optimiser attribute."""
    from kddrl_trl.training.seed_adam import SeedAdam

    w = torch.nn.Parameter(torch.randn(3, 4, 2))
    opt = SeedAdam([w], seed_dims=[0], lr=1e-3)
    before = dict(vars(opt))
    w.grad = torch.randn_like(w)
    opt.step()
    assert set(vars(opt)) == set(before) and all(vars(opt)[k] is v for k, v in before.items())
    assert opt.state[w]["step"].tolist() == [1.0, 1.0, 1.0]
    opt.load_state_dict(opt.state_dict())  # a resumed batch: a loaded state keeps the views, and steps the same
    loaded = dict(vars(opt))
    assert loaded["_views"] is before["_views"]
    opt.step()
    assert set(vars(opt)) == set(loaded) and all(vars(opt)[k] is v for k, v in loaded.items())
    assert opt.state[w]["step"].tolist() == [2.0, 2.0, 2.0]
