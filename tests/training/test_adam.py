"""``FusedAdam`` (the learners' CPU optimiser) against ``torch.optim.Adam(fused=True)``: the same bits, the same
state, checkpoints either way, the full step wherever the lean one does not apply, hooks once per step; ``step_all``:
several optimisers' lean steps in shared kernel calls, with the bits of one ``step()`` each."""

from __future__ import annotations

import torch
from testkit import SMALL

from kddrl_trl.training import HierarchicalLearner
from kddrl_trl.training.adam import FusedAdam, step_all
from kddrl_trl.training.learner import adam

SHAPES = [(16, 7), (16,), (16, 16), (16,), (1, 16), (1,)]


def params(seed: int = 0) -> list[torch.nn.Parameter]:
    g = torch.Generator().manual_seed(seed)
    return [torch.nn.Parameter(torch.randn(*s, generator=g)) for s in SHAPES]


def steps(opt: torch.optim.Optimizer, ps, n: int, seed: int = 1, skip=()) -> None:
    """``n`` steps with seeded gradients (the parameters at the indices ``skip`` get none)."""
    g = torch.Generator().manual_seed(seed)
    for _ in range(n):
        opt.zero_grad()
        grads = [torch.randn(p.shape, generator=g) for p in ps]
        for i, (p, gr) in enumerate(zip(ps, grads)):
            if i not in skip:
                p.grad = gr
        opt.step()


def assert_same(pa, oa, pb, ob) -> None:
    for a, b in zip(pa, pb):
        assert torch.equal(a, b)
    for a, b in zip(pa, pb):
        for key in ("step", "exp_avg", "exp_avg_sq"):
            assert torch.equal(oa.state[a][key], ob.state[b][key]), key


def test_fused_adam_is_torch_adam_bit_for_bit_and_takes_the_lean_step():
    pa, pb = params(), params()
    ref, ours = torch.optim.Adam(pa, lr=1e-2, fused=True), FusedAdam(pb, lr=1e-2)
    start = [p.detach().clone() for p in pb]
    steps(ref, pa, 25)
    steps(ours, pb, 25)
    assert_same(pa, ref, pb, ours)
    assert ours._tensors is not None  # the lean step ran after the first
    assert all(not torch.equal(p, s) for p, s in zip(pb, start))
    ours.zero_grad()
    assert all(p.grad is None for p in pb)


def test_fused_adam_checkpoints_load_either_way_and_go_on_identically():
    pa, pb = params(), params()
    ref, ours = torch.optim.Adam(pa, lr=1e-2, fused=True), FusedAdam(pb, lr=1e-2)
    steps(ref, pa, 5)
    steps(ours, pb, 5)
    # swap the optimiser states: a FusedAdam checkpoint in torch's Adam and the other way round
    ref_state, our_state = ref.state_dict(), ours.state_dict()
    ref.load_state_dict(our_state)
    ours.load_state_dict(ref_state)
    assert ours._tensors is None  # the state tensors are new: taken again after the next step
    steps(ref, pa, 5, seed=2)
    steps(ours, pb, 5, seed=2)
    assert_same(pa, ref, pb, ours)
    assert ours._tensors is not None


def test_fused_adam_takes_torchs_step_for_a_parameter_without_a_gradient_and_for_a_closure():
    pa, pb = params(), params()
    ref, ours = torch.optim.Adam(pa, lr=1e-2, fused=True), FusedAdam(pb, lr=1e-2)
    steps(ref, pa, 3)
    steps(ours, pb, 3)
    steps(ref, pa, 3, seed=3, skip={2})  # Adam skips a parameter without a gradient
    steps(ours, pb, 3, seed=3, skip={2})
    assert_same(pa, ref, pb, ours)
    assert int(ours.state[pb[2]]["step"]) == 3 and int(ours.state[pb[0]]["step"]) == 6
    calls = []

    def closure():
        calls.append(1)
        return torch.tensor(0.0)

    assert float(ours.step(closure)) == 0.0 and calls == [1]


def test_fused_adam_runs_step_hooks_once_per_step_in_either_path():
    ps = params()
    opt = FusedAdam(ps, lr=1e-2)
    torch.optim.Adam(params(1), lr=1e-2)  # torch wraps Adam.step itself once an Adam exists
    pre, post = [], []
    opt.register_step_pre_hook(lambda *a: pre.append(1))
    opt.register_step_post_hook(lambda *a: post.append(1))
    steps(opt, ps, 4)  # the first step is torch's, the others lean
    assert len(pre) == len(post) == 4


def test_the_learners_cpu_optimisers_are_lean_and_the_plain_ones_are_torchs():
    learner = HierarchicalLearner(**SMALL)
    assert all(type(o) is FusedAdam for o in learner.optimizers().values())
    assert type(adam(params(), 1e-3, lean=False)) is torch.optim.Adam


def _step_all_run(lrs, n: int, hook=None, patch=False):
    """``n`` gradient steps of optimisers with learning rates ``lrs`` over their own copies of :func:`params`, by
    :func:`step_all` (FusedAdam) and by ``torch.optim.Adam(fused=True)`` stepped one by one; the two runs' tensors."""
    g = torch.Generator().manual_seed(4)
    sets = [(params(i), params(i)) for i in range(len(lrs))]
    ours = [FusedAdam(a, lr=lr) for (a, _), lr in zip(sets, lrs)]
    ref = [torch.optim.Adam(b, lr=lr, fused=True) for (_, b), lr in zip(sets, lrs)]
    if hook is not None:
        ours[-1].register_step_post_hook(hook)
    if patch:  # as an LR scheduler patches an optimiser's step on the instance
        plain_step = ours[0].step
        ours[0].step = lambda *a, **k: (calls.append(1), plain_step(*a, **k))[1]
    calls = []
    for _ in range(n):
        for a, b in sets:
            for pa, pb in zip(a, b):
                pa.grad = pb.grad = torch.randn(pa.shape, generator=g)
        step_all(ours)
        for o in ref:
            o.step()
    return sets, ours, ref, calls


def test_step_all_gives_each_optimisers_own_steps_bits_in_shared_kernel_calls():
    sets, ours, ref, _ = _step_all_run([1e-2, 1e-2, 3e-3], 12)
    for (a, b), oa, ob in zip(sets, ours, ref):
        assert_same(a, oa, b, ob)  # the parameters and every state tensor, bit for bit
    assert all(o._tensors is not None for o in ours)  # all three took the lean step
    # the step counters are views of one tensor of each optimiser's, still each parameter's own state["step"]
    for o, (a, _) in zip(ours, sets):
        flat = o._tensors[4]
        assert all(o.state[p]["step"]._base is flat for p in a) and torch.equal(flat, torch.full((len(a),), 12.0))
        saved = o.state_dict()["state"][0]["step"]
        assert saved.dim() == 0 and float(saved) == 12.0


def test_step_all_leaves_a_watched_optimiser_to_its_own_step():
    post = []
    sets, ours, ref, _ = _step_all_run([1e-2, 1e-2], 5, hook=lambda *a: post.append(1))
    assert len(post) == 5  # the hook ran on every step: step_all called step() of each
    for (a, b), oa, ob in zip(sets, ours, ref):
        assert_same(a, oa, b, ob)
    sets, ours, ref, calls = _step_all_run([1e-2, 1e-2], 5, patch=True)
    assert len(calls) == 5  # the step patched on the instance ran every time
    for (a, b), oa, ob in zip(sets, ours, ref):
        assert_same(a, oa, b, ob)
