"""The whole-step prototype of ``benchmarks/whole_step_update.py``: its in-graph Adam is ``torch.optim.Adam``, so
the benchmark's two arms time the same algorithm."""

from __future__ import annotations

import pytest
import torch
from testkit import load_benchmark


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("whole_step_update")


def test_the_in_graph_adam_steps_as_torch_adam(bench):
    """Five steps of ``adam_`` (the ``_foreach`` Adam the whole-step graph holds) on random gradients reach
    ``torch.optim.Adam`` 's weights to float rounding; a wrong bias correction or sign would be off by ~lr."""
    g = torch.Generator().manual_seed(0)
    ours = [torch.randn(4, 3, generator=g), torch.randn(3, generator=g)]
    ref = [p.clone().requires_grad_() for p in ours]
    opt = torch.optim.Adam(ref, lr=3e-3, foreach=False)
    m, v, t = bench.adam_state(ours)
    for _ in range(5):
        grads = [torch.randn(p.shape, generator=g) for p in ours]
        for p, gr in zip(ref, grads, strict=True):
            p.grad = gr.clone()
        opt.step()
        bench.adam_(ours, grads, m, v, t, lr=3e-3)
    for a, b in zip(ours, ref, strict=True):
        torch.testing.assert_close(a, b.detach(), rtol=0, atol=1e-6)
    assert t.item() == 5
