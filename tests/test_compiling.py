"""A job run after many others in one process (a launcher's reused worker) still gets compiled graphs."""

import logging

import torch

from kddrl_trl.compiling import WarmCompiled, fresh_compiler


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
