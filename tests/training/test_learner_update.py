"""The learners' update functions (one per gradient step, compiled at the one compile site, CUDA-graphed
on a GPU) against the TorchRL reference loop they replace, and the ``device`` / ``cudagraphs`` options."""

from __future__ import annotations

import io

import pytest
import torch
from testkit import SMALL, fake_samples

from kddrl_trl import keys as K
from kddrl_trl.devtools.plain_kddrl import PlainKDDRL, tensors
from kddrl_trl.training import HierarchicalLearner


@pytest.fixture(scope="module")
def samples():
    """Buffer-L and buffer-H samples collected from the fake env with the full transform stack."""
    return fake_samples(6, 3)


def reference_steps(learner: HierarchicalLearner, frames, macros) -> None:
    """The update loop the update functions replace, step by step: the learner's losses, ``backward``, its optimisers,
    TorchRL's ``SoftUpdate.step()`` (tensor by tensor) and the target embedding lerped parameter by parameter."""

    def soft_embedding():
        with torch.no_grad():
            for t, s in zip(learner.target_embedding.parameters(), learner.embedding.parameters()):
                t.lerp_(s, learner.embed_tau)

    def descend(loss, *optimizers):
        for o in optimizers:
            o.zero_grad()
        loss.backward()
        for o in optimizers:
            o.step()

    for i, (f, m) in enumerate(zip(frames, macros * 2)):
        torch.manual_seed(100 + i)
        descend(learner.loss("cf_value", f)[0], learner.opt_critic, learner.opt_embed)
        if (i + 1) % learner.td3.policy_delay == 0:
            descend(learner.loss("cf_actor", f)[0], learner.opt_actor)
            learner.td3.target_updater.step()
            soft_embedding()
        if i % 2 == 0:
            descend(learner.loss("lc", m)[0], learner.opt_lc, learner.opt_embed)
            learner.d3qn.target_updater.step()
            soft_embedding()


def learner_steps(learner: HierarchicalLearner, frames, macros) -> None:
    for i, (f, m) in enumerate(zip(frames, macros * 2)):
        torch.manual_seed(100 + i)
        learner.update_cf(f)
        if i % 2 == 0:
            learner.update_lc(m)


def assert_same_tensors(a: torch.nn.Module, b: torch.nn.Module, **tol) -> None:
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys()
    for name in sa.keys() - {"counters"}:
        torch.testing.assert_close(sa[name], sb[name], msg=name, **tol)


def test_update_functions_give_the_parameters_of_the_torchrl_reference_loop(samples):
    """Eager update functions (gradients by ``torch.autograd.grad``, one ``_foreach_lerp_`` per target group) vs
    ``backward`` and TorchRL's ``SoftUpdate`` loop: the same networks, targets and target embedding, bit for bit,
    after 6 TD3 and 3 D3QN updates (and the updates moved them)."""
    frames, macros = samples
    torch.manual_seed(1)
    ours = HierarchicalLearner(**SMALL)
    torch.manual_seed(1)
    ref = HierarchicalLearner(**SMALL)
    assert_same_tensors(ours, ref)
    start = {k: v.clone() for k, v in ours.state_dict().items()}
    learner_steps(ours, frames, macros)
    reference_steps(ref, frames, macros)
    assert_same_tensors(ours, ref, rtol=0, atol=0)  # autograd.grad's gradients are backward's, bit for bit
    moved = [n for n, t in ours.state_dict().items() if t.is_floating_point() and not torch.equal(t, start[n])]
    assert any("target_embedding" in n for n in moved) and any("cf_loss.target_" in n for n in moved)
    assert any("lc_loss.target_" in n for n in moved)
    assert ours.counters.tolist() == [3, 6, 3]


@pytest.mark.slow
def test_compiled_update_functions_match_the_eager_ones(samples):
    """``compile=True`` (the one compile site: the learner's loss through ``torch.compile``, its guards skipped once
    warm: ``WarmCompiled``) gives the eager
    parameters after the same updates, within float tolerance (Inductor's own RNG would draw other TD3 target
    noise than eager PyTorch: ``fallback_random`` makes it draw the same)."""
    import torch._inductor.config as inductor_config

    frames, macros = samples
    torch.manual_seed(1)
    eager = HierarchicalLearner(**SMALL)
    torch.manual_seed(1)
    compiled = HierarchicalLearner(**SMALL, compile=True)
    assert_same_tensors(eager, compiled)
    learner_steps(eager, frames, macros)
    with inductor_config.patch(fallback_random=True):  # (monkeypatch's undo deleted the config key for later tests)
        learner_steps(compiled, frames, macros)
    assert_same_tensors(eager, compiled, rtol=1e-4, atol=1e-5)


@pytest.mark.slow
def test_the_inductor_options_of_the_compiled_loss_change_no_bit(samples, monkeypatch):
    """On the CPU the learner's loss is compiled with TorchInductor's C++ wrapper and without its size asserts
    (:func:`~kddrl_trl.compiling.inductor_options`): the same kernels, called from C++ instead of Python, with fewer
    checks around them, so the same parameters, bit for bit, as with TorchInductor's defaults and as with the C++
    wrapper alone, after the same D3QN and TD3 updates (the TD3 target noise drawn by eager PyTorch in every arm:
    ``fallback_random``)."""
    import torch._inductor.config as inductor_config

    from kddrl_trl.compiling import fresh_compiler, inductor_options
    from kddrl_trl.training import base

    assert inductor_options("cpu") == {"cpp_wrapper": True, "size_asserts": False} and inductor_options("cuda") == {}
    frames, macros = samples
    arms = {}
    for name, options in (("defaults", {}), ("cpp_wrapper", {"cpp_wrapper": True}), ("ours", None)):
        fresh_compiler()  # the arms must not share a cached graph
        monkeypatch.undo()
        if options is not None:
            monkeypatch.setattr(base, "inductor_options", lambda device, options=options: options)
        torch.manual_seed(1)
        arms[name] = learner = HierarchicalLearner(**SMALL, compile=True)
        with inductor_config.patch(fallback_random=True):
            learner_steps(learner, frames[:4], macros)
    monkeypatch.undo()
    fresh_compiler()
    states = {name: learner.state_dict() for name, learner in arms.items()}
    torch.manual_seed(1)
    start = HierarchicalLearner(**SMALL).state_dict()
    assert any(not torch.equal(states["ours"][k], start[k]) for k in start if "target" not in k)  # the updates moved it
    for other in ("defaults", "cpp_wrapper"):
        for name in start:
            assert torch.equal(states[other][name], states["ours"][name]), (other, name)


@pytest.mark.parametrize("compile", [False, True])
def test_graphed_update_copies_each_batch_into_the_inputs_it_captured(samples, compile):
    """:class:`~kddrl_trl.compiling.GraphedUpdate` (the CUDA-graph path of an update function; here on the CPU,
    where tensordict's ``CudaGraphModule`` calls through without a graph): each batch is copied into the static
    TensorDict the update reads, so the updates give the parameters of direct calls, eager or compiled; a batch of
    another size, or without a key the first had, is refused by name."""
    import warnings

    from kddrl_trl.compiling import GraphedUpdate

    frames, macros = samples
    torch.manual_seed(1)
    direct = HierarchicalLearner(**SMALL)
    torch.manual_seed(1)
    graphed = HierarchicalLearner(**SMALL)
    fn = torch.compile(graphed._step_lc, dynamic=False) if compile else graphed._step_lc
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "This module is instantiated on a machine without CUDA", UserWarning)
        step = GraphedUpdate(fn, "cpu", warmup=2, written=(K.PRIORITY,))
    for m in macros * 2:
        ref_loss, ref_priority = direct._step_lc(m.clone())
        loss, priority = step(m.clone())
        torch.testing.assert_close(loss, ref_loss, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(priority, ref_priority, rtol=1e-5, atol=1e-6)
    assert_same_tensors(direct, graphed, rtol=1e-5, atol=1e-6)
    assert K.PRIORITY not in step.keys and len(step.leaves) == len(step.keys)
    with pytest.raises(ValueError, match=r"captured for minibatches of \(16,\) rows and got \(8,\)"):
        step(macros[0][:8])
    with pytest.raises(KeyError, match="this batch lacks"):
        step(macros[0].exclude(K.EGO_STATE))


def test_device_auto_is_the_cpu_without_a_gpu_and_cuda_fails_at_once(monkeypatch):
    from kddrl_trl.factories import make_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert make_device("auto") == torch.device("cpu") and make_device("cpu") == torch.device("cpu")
    with pytest.raises(SystemExit, match="device=cuda but no CUDA device is available"):
        make_device("cuda")


def test_cudagraphs_are_refused_on_the_cpu_and_auto_is_off_there():
    from kddrl_trl.compiling import resolve_cudagraphs

    assert resolve_cudagraphs("auto", torch.device("cpu")) is False
    assert resolve_cudagraphs("auto", torch.device("cuda")) is True
    learner = HierarchicalLearner(**SMALL, cudagraphs=False)
    assert learner.device == torch.device("cpu") and learner.cudagraphs is False
    assert learner.policy().__class__.__name__ == "MultiRatePolicy"  # nothing wrapped on a CPU learner
    with pytest.raises(ValueError, match="cudagraphs=true needs device=cuda"):
        HierarchicalLearner(**SMALL, cudagraphs=True)
    with pytest.raises(ValueError, match="cudagraphs=true needs device=cuda"):
        resolve_cudagraphs("true", torch.device("cpu"))
    with pytest.raises(ValueError, match="cudagraphs must be a bool here, got 'auto'"):
        HierarchicalLearner(**SMALL, cudagraphs="auto")  # the parts get resolved knobs (make_job resolves them)


def cpu_state(learner: HierarchicalLearner) -> dict:
    return {k: v.detach().cpu() for k, v in learner.state_dict().items() if k != "counters"}


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_cuda_learner_with_cudagraphs_matches_the_cpu_one_and_checkpoints_cross_devices(samples):
    """On a GPU: the CUDA-graphed (eager-captured) learner gives the CPU learner's parameters after the same D3QN
    updates (no random draw in them), its TD3 updates run, its policy acts on CPU TensorDicts, and its checkpoint
    loads into a CPU learner."""
    frames, macros = samples
    torch.manual_seed(1)
    cpu = HierarchicalLearner(**SMALL)
    gpu = HierarchicalLearner(**SMALL, device="cuda", cudagraphs=True)
    assert gpu.cudagraphs and next(gpu.parameters()).is_cuda
    gpu.load_full_state_dict(cpu.full_state_dict())
    for m in macros * 4:
        cpu.update_lc(m)
        gpu.update_lc(m)
    ref, got = cpu_state(cpu), cpu_state(gpu)
    for name in ref:
        torch.testing.assert_close(got[name], ref[name], rtol=1e-3, atol=1e-4, msg=name)
    for f in frames * 2:
        assert all(torch.isfinite(v) for v in gpu.update_cf(f).values())
    obs = frames[0].exclude("next").clone()
    obs.set(K.LC_HELD, torch.nn.functional.one_hot(torch.ones(obs.shape[0], dtype=torch.long), 3).float())
    acting = gpu.policy(explore=False)  # a CPU copy of the GPU policy
    td = acting(obs.clone())  # a buffer sample plus the held action an env's TensorDict has
    assert td.get(("cf", "action")).device.type == "cpu"
    on_gpu = gpu._policy(explore=False)(obs.clone().to("cuda"))
    torch.testing.assert_close(td.get(("cf", "action")), on_gpu.get(("cf", "action")).cpu(), rtol=1e-4, atol=1e-5)
    buf = io.BytesIO()
    torch.save(gpu.full_state_dict(), buf)
    buf.seek(0)
    back = HierarchicalLearner(**SMALL)
    back.load_full_state_dict(torch.load(buf, map_location="cpu", weights_only=False))
    got, ref = cpu_state(gpu), cpu_state(back)
    for name in ref:
        torch.testing.assert_close(ref[name], got[name], msg=name)


def plain_tensors(ref) -> dict:
    """The plain reference's networks as named tensors, under the names of the learner's losses."""
    out = {
        "embedding": [*ref.fusion.parameters(), *ref.embed.parameters()],
        "target_embedding": [*ref.t_fusion.parameters(), *ref.t_embed.parameters()],
        "q": list(ref.q.parameters()),
        "q_target": list(ref.q_t.parameters()),
        "actor": list(ref.actor.net.parameters()),
        "actor_target": list(ref.actor_t.net.parameters()),
    }
    for k in range(2):
        out[f"critic{k}"] = list(ref.critics[k].parameters())
        out[f"critic{k}_target"] = list(ref.critics_t[k].parameters())
    return out


def learner_tensors(learner: HierarchicalLearner) -> dict:
    td3, d3 = learner.cf_loss, learner.lc_loss

    def leaves(params, skip=("loc", "scale")):
        return [v for k, v in params.flatten_keys(".").items() if k.split(".")[-1] not in skip]

    out = {
        "embedding": list(learner.embedding.parameters()),
        "target_embedding": list(learner.target_embedding.parameters()),
        "q": leaves(d3.value_network_params),
        "q_target": leaves(d3.target_value_network_params),
        "actor": leaves(td3.actor_network_params),
        "actor_target": leaves(td3.target_actor_network_params),
    }
    for k in range(2):
        out[f"critic{k}"] = leaves(td3.qvalue_network_params[k])
        out[f"critic{k}_target"] = leaves(td3.target_qvalue_network_params[k])
    return out


def test_benchmark_plain_reference_makes_the_learners_update(samples):
    """``PlainKDDRL`` (the plain-PyTorch reference, ``kddrl_trl.devtools.plain_kddrl``, the benchmark's plain arm)
    computes the learner's update: from the same weights, on the same batches, with the same TD3 target noise (same
    seeds), both reach the
    same networks and targets after 6 TD3 and 3 D3QN updates, the D3QN's greedy next lane-change action in the TD3
    target (F6) included: the batches hold decision frames where it differs from the held action."""
    frames, macros = samples
    torch.manual_seed(1)
    learner = HierarchicalLearner(**SMALL)
    ref = PlainKDDRL(learner)
    ours, plain = learner_tensors(learner), plain_tensors(ref)
    for name in ours:
        assert len(ours[name]) == len(plain[name]), name
        for a, b in zip(ours[name], plain[name]):
            torch.testing.assert_close(a.detach(), b.detach(), rtol=0, atol=0, msg=name)
    start = {n: [t.detach().clone() for t in ts] for n, ts in ours.items()}
    f6 = 0
    for i, (f, m) in enumerate(zip(frames, macros * 2)):
        x, nx = tensors(f)
        with torch.no_grad():
            obs2 = ref.lc_state(nx["ego"], nx["rel"], nx["mask"], ref._s_e(nx, True))
            differs = (ref._greedy_lc(obs2, nx["action_mask"]) != x["lc_action"]).any(-1, keepdim=True)
        f6 += int((differs & nx["decide"]).sum())
        torch.manual_seed(100 + i)
        learner.update_cf(f)
        torch.manual_seed(100 + i)
        ref.update_cf(x, nx)
        if i % 2 == 0:
            learner.update_lc(m)
            ref.update_lc(*tensors(m))
    assert f6 > 0, "no decision frame where the D3QN's next choice differs from the held action: F6 untested"
    ours, plain = learner_tensors(learner), plain_tensors(ref)
    for name in ours:
        for a, b, s in zip(ours[name], plain[name], start[name]):
            torch.testing.assert_close(a.detach(), b.detach(), rtol=1e-4, atol=1e-5, msg=name)
        assert any(not torch.equal(a.detach(), s) for a, s in zip(ours[name], start[name])), f"{name} never moved"


def test_warm_compiled_loss_calls_each_names_graph_directly_once_warm_and_compiles_a_new_shape():
    """``WarmCompiled`` (the compiled loss of a CPU learner): every name first compiles with its guards; then each
    name runs its own graph directly, and an input of a new shape (a graph that does not exist) is compiled and run
    with every guard instead of failing or reusing a wrong graph, then called directly in turn."""
    from kddrl_trl.compiling import WarmCompiled

    def loss(name, x):
        return x * 2.0 if name == "double" else x + 1.0

    fn = WarmCompiled(torch.compile(loss, dynamic=False, backend="eager"), warmup=1)
    x = torch.arange(4.0)
    assert torch.equal(fn("double", x), x * 2.0) and torch.equal(fn("inc", x), x + 1.0)
    assert sorted(k[0] for k in fn.calls) == ["double", "inc"] and not fn.direct
    for _ in range(2):  # warm: each name runs its own graph directly
        assert torch.equal(fn("inc", x), x + 1.0) and torch.equal(fn("double", x), x * 2.0)
    assert sorted(k[0] for k, f in fn.direct.items() if f is not None) == ["double", "inc"]
    y = torch.arange(6.0).reshape(2, 3)
    for _ in range(2):
        assert torch.equal(fn("double", y), y * 2.0)
    assert len([f for f in fn.direct.values() if f is not None]) == 3


def test_warm_compiled_traces_autograd_grad_and_leaves_the_setting_as_it_was():
    """Every graph ``WarmCompiled`` compiles (warm-up and recompilation) is traced with
    ``torch._dynamo.config.trace_autograd_ops`` on (``compiling.tracing_gradients``: a step's loss and gradients in
    one graph); outside its calls the setting is the user's own."""
    from torch._dynamo import config as dynamo_config

    from kddrl_trl.compiling import WarmCompiled

    seen = []

    def backend(gm, example_inputs):  # called exactly when a graph is compiled
        seen.append(dynamo_config.trace_autograd_ops)
        return gm.forward

    fn = WarmCompiled(torch.compile(lambda name, x: x * 3.0, dynamic=False, backend=backend), warmup=1)
    before = dynamo_config.trace_autograd_ops
    fn("a", torch.ones(3))
    fn("a", torch.ones(3))  # warm: no compile
    fn("a", torch.ones(2, 2))  # a new shape: recompiled with every guard
    assert seen == [True, True]
    assert dynamo_config.trace_autograd_ops == before


def test_a_compiled_step_traces_its_gradients_into_one_graph_and_matches_backward():
    """Under ``compiling.tracing_gradients`` a function returning a loss and ``torch.autograd.grad`` of it compiles
    to one graph with no graph break (without it, ``autograd.grad`` breaks the graph: the test can fail), and the
    gradients are ``backward`` 's, in the parameters' layout once through ``base._param_layout`` (a weight's
    gradient from ``mm`` comes back transposed)."""
    from kddrl_trl.compiling import tracing_gradients
    from kddrl_trl.training.learner import _param_layout

    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(6, 16), torch.nn.ReLU(), torch.nn.Linear(16, 1))
    params = tuple(net.parameters())
    x = torch.randn(32, 6)

    def step(x):
        loss = net(x).pow(2).mean()
        grads = torch.autograd.grad(loss, params)
        return loss.detach(), tuple(map(_param_layout, grads, params))

    torch._dynamo.reset()
    assert torch._dynamo.explain(step)(x).graph_break_count == 1  # the default: autograd.grad is a graph break
    torch._dynamo.reset()
    with tracing_gradients():
        explained = torch._dynamo.explain(step)(x)
        assert explained.graph_count == 1 and explained.graph_break_count == 0
        torch._dynamo.reset()
        loss, grads = torch.compile(step, dynamic=False, backend="aot_eager")(x)
    net(x).pow(2).mean().backward()
    for p, g in zip(params, grads, strict=True):
        assert g.stride() == p.stride() == p.grad.stride()
        torch.testing.assert_close(g, p.grad, rtol=0, atol=0)
    torch._dynamo.reset()


def test_each_step_of_the_learner_traces_into_one_graph(samples):
    """The KDDRL learner's three steps (TD3 critic, TD3 actor, D3QN) each trace, loss and gradients, into one graph
    without a graph break under ``compiling.tracing_gradients`` (what ``compile=True`` compiles): a break would
    split a step and bring back the autograd wrappers the one graph avoids."""
    from kddrl_trl.compiling import tracing_gradients

    frames, macros = samples
    learner = HierarchicalLearner(**SMALL)
    learner.update_cf(frames[0])  # the steps' parameter lists (_descend) and the optimiser states exist
    learner.update_cf(frames[1])
    learner.update_lc(macros[0])
    for name, batch in (("cf_value", frames[2]), ("cf_actor", frames[2]), ("lc", macros[1])):
        torch._dynamo.reset()
        with tracing_gradients():
            explained = torch._dynamo.explain(learner._gradients)(name, batch)
        assert (explained.graph_count, explained.graph_break_count) == (1, 0), (name, explained.break_reasons)
    torch._dynamo.reset()


@pytest.mark.parametrize(
    "device",
    ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU"))],
)
def test_buffers_live_on_the_learners_device_and_reload_there(samples, device):
    """``make_buffer(device=...)``: CPU frames extended into the buffer are stored and sampled on ``device``; a
    checkpointed buffer (read onto the CPU, as checkpoints are) reloads onto ``device`` with the same contents."""
    from kddrl_trl.training import make_buffer
    from kddrl_trl.training.trainer import load_buffer

    frames, _ = samples
    rb = make_buffer(100, 16, 0, device=device)
    for f in frames[:2]:
        rb.extend(f)  # CPU TensorDicts, as the collector writes them
    assert len(rb) == 64 and rb.sample().device.type == device
    buf = io.BytesIO()
    torch.save(rb.state_dict(), buf)
    buf.seek(0)
    back = make_buffer(100, 16, 0, device=device)
    load_buffer(back, torch.load(buf, map_location="cpu", weights_only=False))
    assert len(back) == 64 and back.sample().device.type == device
    for key, value in rb.storage[:64].items(True, True):
        assert torch.equal(back.storage[:64].get(key), value), key
    back.extend(frames[2])  # and it keeps filling where the saved one stopped
    assert len(back) == 96


def test_policy_snapshot_acts_like_the_learner_after_sync(samples):
    """:class:`~kddrl_trl.collectors.PolicySnapshot` (a non-CPU learner's acting policy; here around a CPU
    learner's): a copy, stale after an update until ``sync()``, then acting as the learner's own policy does."""
    from kddrl_trl.collectors import PolicySnapshot

    frames, _ = samples
    learner = HierarchicalLearner(**SMALL)
    acting = PolicySnapshot(learner._policy(explore=False))
    obs = frames[0].exclude("next").clone()
    obs.set(K.LC_HELD, torch.nn.functional.one_hot(torch.ones(obs.shape[0], dtype=torch.long), 3).float())
    for f in frames[:2]:
        learner.update_cf(f)
    own = learner._policy(explore=False)(obs.clone()).get(K.CF_ACTION)
    assert not torch.equal(acting(obs.clone()).get(K.CF_ACTION), own)  # stale: the update moved the actor
    acting.sync()
    torch.testing.assert_close(acting(obs.clone()).get(K.CF_ACTION), own)
    assert all(not t.is_cuda for t in acting.state_dict().values())
