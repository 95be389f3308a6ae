"""A job run after many others in one process (a launcher's reused worker) still gets compiled graphs; a warm
compiled loss given an input of other strides compiles a graph for it instead of running the old one."""

import logging

import torch

from kddrl_trl.compiling import WarmCompiled, fresh_compiler, inductor_options


def _jobs(n: int, fresh: bool) -> None:
    """``n`` jobs in one process, each compiling the same code over a network of its own structure (as the
    learners of a sweep over algorithms do), called as a learner calls its loss."""
    for j in range(n):
        if fresh:
            fresh_compiler()
        net = torch.nn.Sequential(*[torch.nn.Linear(3, 3) for _ in range(j + 1)])
        loss = WarmCompiled(torch.compile(lambda name, x: net(x).sum(), backend="eager"))
        for _ in range(4):
            loss("critic", torch.ones(2, 3))


def test_each_job_compiles_afresh_in_a_reused_process(caplog):
    limit = torch._dynamo.config.recompile_limit
    fresh_compiler()
    with caplog.at_level(logging.INFO, logger="kddrl_trl.compiling"):
        _jobs(limit + 2, fresh=False)  # without: past the recompile limit, every call misses its graph
    misses = [r for r in caplog.records if "needs a new graph" in r.getMessage()]
    assert misses, "the control should reach TorchDynamo's recompile limit"
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="kddrl_trl.compiling"):
        _jobs(limit + 2, fresh=True)
    assert not [r for r in caplog.records if "needs a new graph" in r.getMessage()]


def test_a_warm_loss_compiled_without_size_asserts_still_refuses_other_strides(caplog):
    """``inductor_options`` drops TorchInductor's size asserts on the CPU because TorchDynamo's guards check the
    inputs' strides before a graph runs, also under :class:`WarmCompiled`'s guard skipping: an input of the same
    shape and other strides (a transposed view) gets a graph of its own and the right result, not the old graph's
    reading of its memory."""
    fresh_compiler()
    w = torch.randn(4, 4)
    fn = torch.compile(lambda name, x: (x @ w).relu() + x.sum(), dynamic=False, options=inductor_options("cpu"))
    loss = WarmCompiled(fn)
    for _ in range(3):
        loss("critic", torch.randn(4, 4))
    x = torch.randn(4, 4).t()
    assert not x.is_contiguous()
    with caplog.at_level(logging.INFO, logger="kddrl_trl.compiling"):
        out = loss("critic", x)
    assert any("needs a new graph" in r.getMessage() for r in caplog.records)
    torch.testing.assert_close(out, (x @ w).relu() + x.sum())
