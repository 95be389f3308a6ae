"""Issue 15: the learners' update functions (one per gradient step, compiled at the one compile site, CUDA-graphed
on a GPU) against the TorchRL reference loop they replace, and the ``device`` / ``cudagraphs`` options."""
from __future__ import annotations

import io

import pytest
import torch

from kddrl_trl.training import HierarchicalLearner

from conftest import SMALL, fake_samples


@pytest.fixture(scope="module")
def samples():
    """Buffer-L and buffer-H samples collected from the fake env with the full transform stack."""
    return fake_samples(6, 3)


def reference_steps(learner: HierarchicalLearner, frames, macros) -> None:
    """The update loop before issue 15, step by step: the learner's losses, its optimisers, TorchRL's
    ``SoftUpdate.step()`` (tensor by tensor) and the target embedding lerped parameter by parameter."""
    def soft_embedding():
        with torch.no_grad():
            for t, s in zip(learner.target_embedding.parameters(), learner.embedding.parameters()):
                t.lerp_(s, learner.embed_tau)

    for i, (f, m) in enumerate(zip(frames, macros * 2)):
        torch.manual_seed(100 + i)
        learner._descend(learner.loss("cf_value", f), learner.opt_critic, learner.opt_embed)
        if (i + 1) % learner.td3.policy_delay == 0:
            learner._descend(learner.loss("cf_actor", f), learner.opt_actor)
            learner.td3.target_updater.step()
            soft_embedding()
        if i % 2 == 0:
            learner._descend(learner.loss("lc", m), learner.opt_lc, learner.opt_embed)
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
    """Eager update functions (one ``_foreach_lerp_`` per target group) vs TorchRL's ``SoftUpdate`` loop: the same
    networks, targets and target embedding after 6 TD3 and 3 D3QN updates (and the updates moved them)."""
    frames, macros = samples
    torch.manual_seed(1)
    ours = HierarchicalLearner(**SMALL)
    torch.manual_seed(1)
    ref = HierarchicalLearner(**SMALL)
    assert_same_tensors(ours, ref)
    start = {k: v.clone() for k, v in ours.state_dict().items()}
    learner_steps(ours, frames, macros)
    reference_steps(ref, frames, macros)
    assert_same_tensors(ours, ref)
    moved = [n for n, t in ours.state_dict().items() if t.is_floating_point() and not torch.equal(t, start[n])]
    assert any("target_embedding" in n for n in moved) and any("cf_loss.target_" in n for n in moved)
    assert any("lc_loss.target_" in n for n in moved)
    assert ours.counters.tolist() == [3, 6, 3]


@pytest.mark.slow
def test_compiled_update_functions_match_the_eager_ones(samples, monkeypatch):
    """``compile=True`` (the one compile site: each update function through ``torch.compile``) gives the eager
    parameters after the same updates, within float tolerance (Inductor's own RNG would draw other TD3 target
    noise than eager PyTorch: ``fallback_random`` makes it draw the same)."""
    import torch._inductor.config as inductor_config

    monkeypatch.setattr(inductor_config, "fallback_random", True)
    frames, macros = samples
    torch.manual_seed(1)
    eager = HierarchicalLearner(**SMALL)
    torch.manual_seed(1)
    compiled = HierarchicalLearner(**SMALL, compile=True)
    assert_same_tensors(eager, compiled)
    learner_steps(eager, frames, macros)
    learner_steps(compiled, frames, macros)
    assert_same_tensors(eager, compiled, rtol=1e-4, atol=1e-5)


def test_device_auto_is_the_cpu_without_a_gpu_and_cuda_fails_at_once(monkeypatch):
    from kddrl_trl.factories import make_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert make_device("auto") == torch.device("cpu") and make_device("cpu") == torch.device("cpu")
    with pytest.raises(SystemExit, match="device=cuda but no CUDA device is available"):
        make_device("cuda")


def test_cudagraphs_are_refused_on_the_cpu_and_auto_is_off_there():
    learner = HierarchicalLearner(**SMALL, cudagraphs="auto")
    assert learner.device == torch.device("cpu") and learner.cudagraphs is False
    assert learner.policy().__class__.__name__ == "MultiRatePolicy"  # nothing wrapped on a CPU learner
    with pytest.raises(ValueError, match="cudagraphs=true needs device=cuda"):
        HierarchicalLearner(**SMALL, cudagraphs=True)


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
        assert all(torch.isfinite(torch.tensor(v)) for v in gpu.update_cf(f).values())
    td = gpu.policy(explore=False)(frames[0].exclude("next").clone())
    assert td.get(("cf", "action")).device.type == "cpu"
    buf = io.BytesIO()
    torch.save(gpu.full_state_dict(), buf)
    buf.seek(0)
    back = HierarchicalLearner(**SMALL)
    back.load_full_state_dict(torch.load(buf, map_location="cpu", weights_only=False))
    got, ref = cpu_state(gpu), cpu_state(back)
    for name in ref:
        torch.testing.assert_close(ref[name], got[name], msg=name)
