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
    misses = [r for r in caplog.records if "no graph to call directly" in r.getMessage()]
    assert misses, "the control should reach TorchDynamo's recompile limit"
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="kddrl_trl.compiling"):
        _jobs(limit + 2, fresh=True)
    assert not [r for r in caplog.records if "no graph to call directly" in r.getMessage()]


def test_a_warm_loss_compiled_without_size_asserts_still_refuses_other_strides():
    """``inductor_options`` drops TorchInductor's size asserts on the CPU because a graph is only run on inputs of
    its own strides: TorchDynamo's guards check them, and :class:`WarmCompiled` calls a warm graph directly only
    for arguments of its signature (strides included). An input of the same shape and other strides (a transposed
    view) gets a graph of its own and the right result, not the old graph's reading of its memory."""
    fresh_compiler()
    w = torch.randn(4, 4)
    fn = torch.compile(lambda name, x: (x @ w).relu() + x.sum(), dynamic=False, options=inductor_options("cpu"))
    loss = WarmCompiled(fn)
    for _ in range(3):
        loss("critic", torch.randn(4, 4))
    (warm,) = loss.direct.values()
    assert warm is not None, "the contiguous input's graph is called directly once warm"
    x = torch.randn(4, 4).t()
    assert not x.is_contiguous()
    for _ in range(3):
        torch.testing.assert_close(loss("critic", x), (x @ w).relu() + x.sum())
    assert len(loss.direct) == 2 and None not in loss.direct.values()
    first, second = loss.direct.values()
    assert first.__code__ is not second.__code__, "each stride layout runs its own graph"


def test_a_warm_graph_is_called_without_torchdynamo_and_gives_its_bits():
    """Once warm, :class:`WarmCompiled` runs the cache entry's own transformed bytecode (no second compile), and
    the result is the guarded call's bit for bit; a function with a graph break stays under TorchDynamo, and a graph
    dropped by ``torch._dynamo.reset`` is compiled again."""
    fresh_compiler()
    net = torch.nn.Sequential(torch.nn.Linear(5, 8), torch.nn.ReLU(), torch.nn.Linear(8, 1))
    frames = []

    def backend(gm, example_inputs):
        frames.append(gm)
        return gm.forward

    loss = WarmCompiled(torch.compile(lambda name, x: net(x).pow(2).mean(), dynamic=False, backend=backend))
    x = torch.randn(16, 5)
    reference = loss("value", x)
    for _ in range(4):
        assert torch.equal(loss("value", x), reference)
    assert len(frames) == 1 and None not in loss.direct.values()
    (warm,) = loss.direct.values()
    assert warm.__code__ is not loss._func.__code__, "the entry's transformed bytecode, not the function's own"
    assert torch.equal(warm("value", x), reference)

    def broken(name, x):
        y = net(x)
        torch._dynamo.graph_break()
        return y.sum()

    split = WarmCompiled(torch.compile(broken, dynamic=False, backend="eager"))
    for _ in range(4):
        torch.testing.assert_close(split("value", x), net(x).sum())
    assert list(split.direct.values()) == [None], "a frame that resumes after a graph break stays under TorchDynamo"

    torch._dynamo.reset()
    assert torch.equal(loss("value", x), reference)
    assert torch.equal(loss("value", x), reference)


def test_compile_seconds_count_this_jobs_compiling_only():
    from kddrl_trl.compiling import compile_counts, compile_seconds, fresh_compiler

    fresh_compiler()
    assert compile_seconds() == 0.0 and compile_counts()["graphs"] == 0
    torch.compile(lambda x: (x * 3.0).cos().sum(), backend="eager")(torch.randn(4))
    assert compile_seconds() > 0.0 and compile_counts()["graphs"] == 1
    fresh_compiler()  # the next job starts from zero
    assert compile_seconds() == 0.0 and compile_counts() == dict.fromkeys(compile_counts(), 0)


def test_auto_trains_short_jobs_eagerly_and_an_explicit_choice_stands():
    """``compile=auto`` is eager below :data:`SHORT_RUN_EPISODES` training episodes (the compile does not pay for
    itself there: ``benchmarks/results/compile_cost.json``), compiles a long job where a C++ compiler is found, and
    ``true`` / ``false`` are kept whatever the length."""
    from kddrl_trl.compiling import SHORT_RUN_EPISODES, _compiler_found, resolve_compile

    assert resolve_compile("auto", SHORT_RUN_EPISODES - 1) is False
    assert resolve_compile("auto", SHORT_RUN_EPISODES) is _compiler_found()
    assert resolve_compile("auto") is _compiler_found()  # not a training job
    assert resolve_compile("true", 5) is True and resolve_compile(False, 5000) is False
