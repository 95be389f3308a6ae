"""Training throughput of KDDRL, measured in one run (issue: learning, "Throughput").

(a) ``update``: the learner's cost per collected frame — one TD3 update (critic every update; actor and
    soft target updates every ``policy_delay``) plus 1/``lc_period`` of a D3QN update (one per decision) —
    of :class:`kddrl_trl.training.HierarchicalLearner` (TorchRL ``TD3Loss`` / ``DQNLoss`` / ``SoftUpdate``,
    TensorDict states, shared embedding), eager and compiled (``compile=True``: the learner's one compile
    site, :meth:`HierarchicalLearner.loss`), against a **plain-PyTorch reference** with the *same* network
    modules (deep copies holding the losses' weights), the same batch tensors and the same arithmetic (double-DQN
    target with masked argmax, twin critics with clipped target smoothing, the D3QN's greedy next lane-change
    action on decision frames in the TD3 target, delayed actor on detached s_e, Polyak updates of every target
    incl. the embedding's; :class:`PlainKDDRL`, proved equal by ``tests/training/test_learner_update.py``).
    ``update_ratio_vs_plain`` = plain time / ours (>= 1.0: TorchRL costs nothing extra). Replay sampling is outside the
    timed part for both. On the CPU also ``compiled_python_wrapper``: the compiled learner with TorchInductor's Python
    wrapper instead
    of the C++ one (:func:`python_wrapper`); ``cpp_wrapper_gain`` = its time / the compiled arm's; and
    ``compiled_size_asserts``: the C++ wrapper with TorchInductor's size asserts, which
    :func:`kddrl_trl.compiling.inductor_options` drops; ``size_asserts_gain`` = its time / the compiled arm's; and
    ``compiled_dynamo_frames``: the same graphs called through TorchDynamo's frame evaluation with most guards
    skipped (:class:`DynamoFrames`) instead of directly (:class:`kddrl_trl.compiling.WarmCompiled`);
    ``direct_call_gain`` = its time / the compiled arm's; and ``compiled_torch_adam``: the learner's optimisers as
    ``torch.optim.Adam(fused=True)``, each stepped by its own ``step()``, instead of :mod:`kddrl_trl.training.adam`'s
    lean steps (:func:`~kddrl_trl.training.adam.step_all`); ``lean_adam_gain`` = its time / the compiled arm's.
    Every timed pass starts from batches without the ``keys.PRIORITY`` an update writes into them, as a fresh
    sample in training does (a key more is another graph signature, compiled inside the timed pass). Each arm
    that compiles records, from its first pass, what TorchDynamo compiled (``compiles``: per graph the seconds of
    the whole compile, of its backend and of TorchDynamo's own tracing and guards), a training process's fixed cost.
(b) ``collect``: frames/s of ``SumoHighwayEnv`` + the full transform stack (as configured for training in
    ``conf/algo/kddrl.yaml`` and ``compile`` of ``conf/config.yaml``, i.e. compiled when a C++ compiler is
    found) + DecisionClock + both exploring policies through
    :class:`kddrl_trl.collectors.MultiTimescaleCollector` (writing both replay buffers), against the libsumo
    limit of ``benchmarks/env_throughput.py`` (a) measured in the same run at the same K.
    ``collect_ratio_vs_sim`` (goal >= 0.5). The limit includes the env's own observation building (the per-ego
    libsumo queries), so making that cheaper raises both numbers and *lowers* the ratio: compare ``collect_fps``
    too, measured back to back on the same machine. With (a), per K: ``learner_compile_gain`` = the share of the
    training wall time (collection + updates per ego-frame, eager learner) that compiling the learner saves
    (a compile site is kept only where it earns >= 5 %). With ``--collect-direct-gain N``: the same collection
    with the compiled stack's every call under TorchDynamo's guards instead of its warm graph called directly, N
    turns each, and ``collect_direct_gain``, the median over the turns of fps(direct) / fps(guarded).
(w) ``collect_scaling`` (``--workers 1,2``): the collection of (b) at K = ``--workers-roads`` (8) with N env
    processes (``collector.workers=N``: :meth:`MultiTimescaleCollector.from_env` over N
    :class:`~kddrl_trl.collectors.workers.WorkerEnv` factories; N = 1 is the single-process path), the learner's
    weights synced to the workers after every batch as in training, in wall time; per N,
    ``collect_scaling[N]`` = fps(N) / (N x fps(1)), both measured in this run (1.0: perfect scaling). It can only
    approach 1.0 while the machine has a free core per worker beside the learner process.
(c) ``train_1000_episodes_s``: read from a finished run's ``summary.json`` (``--full-run RUN_DIR``), the
    training wall time of ``python -m kddrl_trl.train`` (1000 episodes, baseline) — goal <= 400 s (issue
    "Training speed"; it was 654 s). With ``--baseline-run RUN_DIR`` (a run of the same job and seed on other
    code, trained side by side with ``--full-run``'s, one core each): ``full_run_vs_baseline``, the ratio of the two
    training times and whether the two runs' training (and evaluation) records are identical.

    python -m benchmarks.train_throughput [--roads 8] [--updates 200] [--frames 2000] [--clock wall|cpu]
                                          [--full-run runs/... [--baseline-run runs/...]] [--device cpu|cuda]
                                          [--skip-collect] [--workers 1,2] [--skip-update] [--compile auto|true|false]

``--device cuda`` runs (a) on the GPU: the learner (compiled arm: compiled update functions in
``CudaGraphModule``, capturable Adam), the plain reference's networks and the batches moved there, and writes a
``gpu`` entry (device name, TD3 / D3QN updates per second of ours and of the plain reference, and (r): TorchRL's
own compiled, CUDA-graphed TD3 on a MuJoCo-sized task, the reference the issue's GPU goal names, with our TD3
update's speed as a ratio of it, both measured in the run) besides the CPU ratios of a CPU run
(``--torchrl-reference on`` measures (r) on the CPU too). ``--skip-collect`` measures (a) only (and (w) if asked);
``--skip-update`` leaves (a) out.
``--compile`` overrides the transform stack's ``compile`` of conf/config.yaml in (b) and (w).
The process sets the CPU's flush-to-zero mode as every job does by default (``flush_denormal``).
``--floor`` adds the compute floor (:func:`measure_floor`) and our update in parts (:func:`update_parts`).

Prints a table and writes ``benchmarks/results/train_throughput.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf
from tensordict import TensorDictBase
from torch._dynamo.utils import clear_compilation_metrics, get_compilation_metrics
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from benchmarks.env_throughput import machine_info, measure_sim, write_json  # noqa: E402
from kddrl_trl import keys as K  # noqa: E402
from kddrl_trl.collectors import MultiTimescaleCollector
from kddrl_trl.collectors.workers import WorkerEnv  # noqa: E402
from kddrl_trl.compiling import inductor_options, resolve_compile, tracing_gradients  # noqa: E402
from kddrl_trl.devtools.bench_results import keep_previous  # noqa: E402
from kddrl_trl.devtools.plain_kddrl import PlainKDDRL, tensors  # noqa: E402
from kddrl_trl.envs import FakeHighwayEnv, SumoHighwayEnv  # noqa: E402
from kddrl_trl.eval.protocol import worker_seed  # noqa: E402
from kddrl_trl.generative import shipped_traffic  # noqa: E402
from kddrl_trl.process_settings import apply_flush_denormal  # noqa: E402
from kddrl_trl.reporting.records import record_bytes  # noqa: E402
from kddrl_trl.training import HierarchicalLearner, make_buffer  # noqa: E402
from kddrl_trl.training.learner import adam  # noqa: E402
from kddrl_trl.transforms import (
    DecisionClock,  # noqa: E402
    PredictiveStack,  # noqa: E402
    make_kddrl_transforms,  # noqa: E402
)
from kddrl_trl.transforms.stack import warm_frames  # noqa: E402

CONF = Path(__file__).resolve().parents[1] / "src" / "kddrl_trl" / "conf" / "algo" / "kddrl.yaml"
FRAMES_PER_ENV = 20  # frames per env row per collected batch in (b) and (w)


def learner_kwargs(compile: bool | str) -> tuple[dict, int]:
    """The learner options of ``conf/algo/kddrl.yaml`` (with ``compile`` set) and its ``lc_period``."""
    cfg = OmegaConf.to_container(OmegaConf.load(CONF), resolve=True)
    return {**cfg["learner"], "compile": compile}, int(cfg["lc_period"])


def buffer_keys() -> list:
    """The keys a buffer entry keeps for the KDDRL learner of ``conf/algo/kddrl.yaml`` (a superset of the other
    learners' keys): what :func:`sample_batches` is asked for."""
    return HierarchicalLearner(**learner_kwargs(False)[0]).buffer_keys()


def batch_sizes() -> tuple[int, int]:
    """The minibatch sizes of training (``train.batch_size_cf`` / ``train.batch_size_lc`` of conf/config.yaml)."""
    train = OmegaConf.load(CONF.parents[1] / "config.yaml")["train"]
    return int(train["batch_size_cf"]), int(train["batch_size_lc"])


def transform_kwargs(compile: bool | str | None = None) -> dict:
    """The transform options of ``conf/algo/kddrl.yaml`` with the ``compile`` of conf/config.yaml (as training
    builds the stack), or ``compile`` when given."""
    cfg = OmegaConf.to_container(OmegaConf.load(CONF), resolve=True)["transforms"]
    cfg.pop("enabled", None)
    cfg["weights"] = shipped_traffic(cfg.get("weights", "auto"), "sumo")  # as make_transforms resolves it on SUMO
    if compile is None:
        compile = OmegaConf.load(CONF.parents[1] / "config.yaml")["compile"]
    return {**cfg, "compile": resolve_compile(compile)}  # as make_job resolves it


def collect_env(k: int, compile: bool | str | None = None, *, seed: int) -> TransformedEnv:
    """The env of (b): ``SumoHighwayEnv`` with ``k`` roads + the KDDRL transform stack + the decision clock."""
    lc_period = learner_kwargs(False)[1]
    return TransformedEnv(
        SumoHighwayEnv("baseline", num_roads=k, seed=seed),
        Compose(make_kddrl_transforms(seed=seed, **transform_kwargs(compile)), DecisionClock(lc_period)),
    )


def sample_batches(n_frames: int, seed: int, keys: list, batch_size_cf: int | None = None):
    """Frames and macro-transitions with every key the learner reads (from the fake env: only shapes and
    plausible values matter for timing); TD3 minibatches of ``batch_size_cf`` (None: training's)."""
    env = TransformedEnv(
        FakeHighwayEnv(num_roads=8, seed=seed), Compose(make_kddrl_transforms(seed=seed), DecisionClock(20))
    )
    learner = HierarchicalLearner(**learner_kwargs(False)[0])
    rb_cf = make_buffer(10 * n_frames, batch_size_cf or batch_sizes()[0], seed)
    rb_lc = make_buffer(10 * n_frames, batch_sizes()[1], seed)
    mtc = MultiTimescaleCollector.from_env(
        env, learner.policy(), frames_per_env=50, frame_buffer=rb_cf, macro_buffer=rb_lc, frame_keys=keys
    )
    for _ in mtc:
        if len(rb_cf) >= n_frames and len(rb_lc) >= batch_sizes()[1]:
            break
    mtc.shutdown()
    return rb_cf, rb_lc


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _unprioritized(batches: list) -> list:
    """``batches`` without the ``keys.PRIORITY`` an update wrote into them (a TensorDict's, in place)."""
    for b in batches:
        if isinstance(b, TensorDictBase) and K.PRIORITY in b.keys():
            del b[K.PRIORITY]
    return batches


def time_updates(
    update_cf, update_lc, cf_batches, lc_batches, lc_period: int, device: torch.device = torch.device("cpu")
) -> tuple[float, float, float]:
    """Seconds per TD3 update, per D3QN update, and per frame (TD3 + D3QN / lc_period), each pass on batches as
    fresh samples come (:func:`_unprioritized`)."""
    n = len(cf_batches)
    for b in _unprioritized(cf_batches)[:10]:
        update_cf(b)
    for b in _unprioritized(lc_batches)[:5]:
        update_lc(b)
    _unprioritized(cf_batches)
    _unprioritized(lc_batches)
    _sync(device)
    t0 = time.perf_counter()
    for b in cf_batches:
        update_cf(b)
    _sync(device)
    t_cf = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    for b in lc_batches:
        update_lc(b)
    _sync(device)
    t_lc = (time.perf_counter() - t0) / len(lc_batches)
    return t_cf, t_lc, t_cf + t_lc / lc_period


def measure_update(
    updates: int, seed: int, repeats: int, device: torch.device = torch.device("cpu"), batch_size_cf: int | None = None
) -> dict:
    """The three arms (plain reference, eager learner, compiled learner) on the same batches, taking turns
    ``repeats`` times (the drifts of a shared machine hit all alike); medians over the turns. On ``device``
    (CUDA: the compiled arms are also CUDA-graphed; the batches are on the device beforehand, as the learner's
    buffers sample them there, and in the extra arm ``compiled_cpu_batches`` moved there by the learner, update by
    update, as when the buffers stay on the CPU)."""
    torch.manual_seed(seed)
    kw, lc_period = learner_kwargs(False)
    probe = HierarchicalLearner(**kw)
    rb_cf, rb_lc = sample_batches(4000, seed, probe.buffer_keys(), batch_size_cf)
    cf_batches = [rb_cf.sample() for _ in range(updates)]
    lc_batches = [rb_lc.sample() for _ in range(max(updates // 4, 20))]
    arms = {}
    names = ("plain", "eager", "compiled") + (
        ("compiled_cpu_batches",)
        if device.type == "cuda"
        else ("compiled_python_wrapper", "compiled_size_asserts", "compiled_dynamo_frames", "compiled_torch_adam")
    )
    on_device = [b.to(device) for b in cf_batches], [b.to(device) for b in lc_batches]  # as the buffers sample
    for name in names:
        compiled = name.startswith("compiled")
        learner = HierarchicalLearner(
            **learner_kwargs(compiled)[0], device=device, cudagraphs=compiled and device.type == "cuda"
        )
        if name == "plain":
            ref = PlainKDDRL(learner)
            arms[name] = (
                lambda b: ref.update_cf(*b),
                lambda b: ref.update_lc(*b),
                [tensors(b, device) for b in cf_batches],
                [tensors(b, device) for b in lc_batches],
            )
        elif name == "compiled_cpu_batches":  # the batches moved by the learner, update by update
            arms[name] = (learner.update_cf, learner.update_lc, cf_batches, lc_batches)
        else:
            if name == "compiled_python_wrapper":
                python_wrapper(learner)
            if name == "compiled_size_asserts":
                recompiled_step(learner, "step_size_asserts", {"cpp_wrapper": True})
            if name == "compiled_dynamo_frames":
                recompiled_step(learner, "step_dynamo_frames", inductor_options("cpu"), caller=DynamoFrames)
            if name == "compiled_torch_adam":
                torch_adam(learner)
            arms[name] = (learner.update_cf, learner.update_lc, *on_device)
    runs, wall, compiles = {n: [] for n in arms}, dict.fromkeys(arms, 0.0), {}
    for turn in range(repeats):
        for name, fns in arms.items():
            if turn == 0:
                clear_compilation_metrics()
            t0 = time.perf_counter()
            runs[name].append(time_updates(*fns, lc_period, device))
            wall[name] += time.perf_counter() - t0
            if turn == 0:
                compiles[name] = compile_costs()
    rows = {}
    for name in arms:
        rows[name] = {
            "td3_update_s": statistics.median(r[0] for r in runs[name]),
            "d3qn_update_s": statistics.median(r[1] for r in runs[name]),
            "per_frame_s": statistics.median(r[2] for r in runs[name]),
            "wall_s_incl_compile": wall[name],
            **({"compiles": compiles[name]} if compiles[name] else {}),
        }
        spent = [sum(c[k] for c in compiles[name]) for k in ("compile_s", "dynamo_s")]
        print(
            f"  update {name}: {1 / rows[name]['td3_update_s']:.0f} TD3 updates/s, "
            f"{1 / rows[name]['d3qn_update_s']:.0f} D3QN updates/s"
            + (
                f"; compiled {len(compiles[name])} graphs in {spent[0]:.1f} s ({spent[1]:.1f} s tracing)"
                if compiles[name]
                else ""
            ),
            flush=True,
        )
    return {
        "device": str(device),
        "lc_period": lc_period,
        "batch_size_cf": int(cf_batches[0].numel()),
        "batch_size_lc": int(lc_batches[0].numel()),
        **rows,
    }


def compile_costs() -> list[dict]:
    """What TorchDynamo compiled since its counters were last cleared, one row per graph: the function, the whole
    compile's seconds, its backend's (TorchInductor, caches warm or cold as the machine has them) and the rest,
    TorchDynamo's own tracing and guards (``torch._dynamo.utils.get_compilation_metrics``)."""
    rows = []
    for m in get_compilation_metrics():
        total, backend = m.entire_frame_compile_time_s or 0.0, m.backend_compile_time_s or 0.0
        rows.append(
            {
                "function": m.co_name,
                "compile_s": total,
                "backend_s": backend,
                "dynamo_s": total - backend,
                "graph_ops": m.graph_op_count,
            }
        )
    return rows


class DynamoFrames:
    """A compiled gradient function called as :class:`kddrl_trl.compiling.WarmCompiled` called it before it ran warm
    graphs directly: through TorchDynamo's frame evaluation, each name's first ``warmup`` calls with every guard,
    later ones under ``torch.compiler.set_stance(skip_guard_eval_unsafe=True)`` (which still looks the graph up and
    checks every input tensor's shape). The arm ``compiled_dynamo_frames``: what the direct call earns."""

    def __init__(self, fn, warmup: int = 2):
        self.fn, self.warmup, self.calls = fn, warmup, {}

    def __call__(self, name: str, *args):
        self.calls[name] = self.calls.get(name, 0) + 1
        if self.calls[name] <= self.warmup:
            with tracing_gradients():
                return self.fn(name, *args)
        with torch.compiler.set_stance(skip_guard_eval_unsafe=True):
            return self.fn(name, *args)


def recompiled_step(learner: HierarchicalLearner, name: str, options: dict, caller=None) -> None:
    """The learner's compiled step (its loss and gradients, :meth:`~kddrl_trl.training.Learner._gradients`) compiled
    as ``compile=True`` compiles it, but with the TorchInductor ``options`` given instead of those of
    :func:`kddrl_trl.compiling.inductor_options`, and called through ``caller`` (None:
    :class:`~kddrl_trl.compiling.WarmCompiled`, as training calls it). It is compiled from a copy of its code object
    named ``name``, so that TorchDynamo keeps its graphs apart from those of the ``compiled`` arm (its cache is per
    code object) and the arms can take turns in one process."""
    from types import FunctionType

    from kddrl_trl.compiling import WarmCompiled

    fn = type(learner)._gradients
    copy = FunctionType(fn.__code__.replace(co_name=name), fn.__globals__, name)
    bound = copy.__get__(learner)
    learner.__dict__["_gradients"] = (caller or WarmCompiled)(torch.compile(bound, dynamic=False, options=options))


def torch_adam(learner: HierarchicalLearner) -> None:
    """The arm ``compiled_torch_adam``: ``learner``'s optimisers, before its first update, as
    ``torch.optim.Adam(fused=True)`` on the same parameters and learning rates (no lean step: each steps through
    ``torch.optim``, its own kernel call)."""
    for name, opt in learner.optimizers().items():  # each held as ``opt_<name>``
        setattr(learner, f"opt_{name}", adam(opt.param_groups[0]["params"], opt.param_groups[0]["lr"], lean=False))


def python_wrapper(learner: HierarchicalLearner) -> None:
    """:func:`recompiled_step` with TorchInductor's default Python wrapper instead of the C++ one: the arm
    ``compiled_python_wrapper``, which tells what the C++ wrapper earns."""
    recompiled_step(learner, "step_python_wrapper", {})


def update_flops(seed: int, buffers: tuple, updates: int = 8) -> dict:
    """FLOPs of one TD3 and one D3QN update of the plain reference (the arithmetic every arm does), counted by
    ``torch.utils.flop_counter.FlopCounterMode`` over ``updates`` consecutive updates (the TD3 actor steps every
    second update) on samples of ``buffers`` (:func:`sample_batches`' two) and averaged."""
    from torch.utils.flop_counter import FlopCounterMode

    torch.manual_seed(seed)
    rb_cf, rb_lc = buffers
    ref = PlainKDDRL(HierarchicalLearner(**learner_kwargs(False)[0]))
    out = {}
    for name, update, rb in (("td3", ref.update_cf, rb_cf), ("d3qn", ref.update_lc, rb_lc)):
        batches = [tensors(rb.sample()) for _ in range(updates)]
        with FlopCounterMode(display=False) as counter:
            for b in batches:
                update(*b)
        out[f"{name}_flops_per_update"] = counter.get_total_flops() / updates
    return out


def gemm_rate(threads: int, size: int = 128, batch: int = 2, seconds: float = 1.0) -> float:
    """Sustained FP32 GEMM rate (FLOP/s) of ``[batch, size, size] @ [batch, size, size]`` products in a loop, the
    shapes of the updates' layers (128-wide MLPs, batch 128, twin critics), with ``threads`` torch threads."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        a, b = torch.randn(batch, size, size), torch.randn(batch, size, size)
        for _ in range(50):
            torch.bmm(a, b)
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            for _ in range(100):
                torch.bmm(a, b)
            n += 100
        return 2.0 * batch * size**3 * n / (time.perf_counter() - t0)
    finally:
        torch.set_num_threads(before)


#: the matrix products of an update (what the floor counts), as the profiler names them
GEMM_OPS = ("aten::mm", "aten::addmm", "aten::bmm", "aten::baddbmm")


def gemm_in_update(seed: int, buffers: tuple, updates: int = 100) -> dict:
    """Seconds per TD3 / D3QN update spent in the update's own matrix products, as they run inside our compiled
    update: the self time of its GEMM calls (:data:`GEMM_OPS`) under ``torch.profiler`` over ``updates`` updates.
    The loss is compiled with TorchInductor's Python wrapper (:func:`python_wrapper`: the same kernels, and its
    GEMMs are ATen calls the profiler sees; the C++ wrapper calls them past the profiler), on samples of
    ``buffers`` (:func:`sample_batches`' two). Against the floor this says how much of the gap is the products
    themselves (the floor's loop runs one product back to back; inside the update each follows other work) and how
    much is everything else."""
    from torch.profiler import ProfilerActivity, profile

    torch.manual_seed(seed)
    learner = HierarchicalLearner(**learner_kwargs(True)[0])
    python_wrapper(learner)
    rb_cf, rb_lc = buffers
    out = {}
    for agent, update, rb in (("td3", learner.update_cf, rb_cf), ("d3qn", learner.update_lc, rb_lc)):
        batches = [rb.sample() for _ in range(updates)]
        for b in batches[:10]:
            update(b)
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            for b in batches:
                update(b)
        gemm_us = sum(e.self_cpu_time_total for e in prof.key_averages() if e.key in GEMM_OPS)
        out[f"{agent}_gemm_in_update_s"] = 1e-6 * gemm_us / updates
    return out


def update_parts(seed: int, buffers: tuple, updates: int = 400, passes: int = 3) -> dict:
    """Seconds per TD3 / D3QN update in each part of our compiled update as training runs it (the C++ wrapper, warm
    graphs called directly, ``flush_denormal`` on as every job sets it): the loss-and-gradients graph
    (``Learner._gradients``), the optimiser steps (``step_all``), the soft target updates, and the rest (Python,
    TensorDict, the priorities), each the median over ``passes`` passes of ``updates`` updates on samples of
    ``buffers``. With :func:`gemm_in_update` this bounds the update as it is built: the products at their speed inside
    it, the optimiser steps and the soft updates (each reads and writes all of its tensors) take
    ``*_bound_over_floor`` of the floor before the graphs' other kernels and the rest add anything."""
    from kddrl_trl.training import base

    torch.manual_seed(seed)
    learner = HierarchicalLearner(**learner_kwargs(True)[0])
    acc = dict.fromkeys(("gradients", "optimizer", "soft"), 0.0)

    def timed(part: str, fn):
        def call(*args):
            t0 = time.perf_counter()
            out = fn(*args)
            acc[part] += time.perf_counter() - t0
            return out

        return call

    learner._gradients = timed("gradients", learner._gradients)
    learner._soft_cf, learner._soft_lc = timed("soft", learner._soft_cf), timed("soft", learner._soft_lc)
    step_all = base.step_all
    base.step_all = timed("optimizer", step_all)
    rb_cf, rb_lc = buffers
    out = {}
    try:
        for agent, update, rb in (("td3", learner.update_cf, rb_cf), ("d3qn", learner.update_lc, rb_lc)):
            batches = [rb.sample() for _ in range(updates)]
            for b in _unprioritized(batches)[:20]:
                update(b)
            runs = []
            for _ in range(passes):
                acc.update(dict.fromkeys(acc, 0.0))
                t0 = time.perf_counter()
                for b in _unprioritized(batches):
                    update(b)
                total = time.perf_counter() - t0
                runs.append({**{k: v / updates for k, v in acc.items()}, "total": total / updates})
            parts = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
            parts["rest"] = parts["total"] - parts["gradients"] - parts["optimizer"] - parts["soft"]
            out[f"{agent}_parts_s"] = parts
    finally:
        base.step_all = step_all
    return out


def measure_floor(update: dict, seed: int, threads: list[int]) -> dict:
    """The compute floor of one update: its FLOPs over the GEMM rate at its shapes, per thread count; and our
    compiled update's and the plain reference's time per TD3 / D3QN update (``update``, measured at
    ``update["torch_threads"]``) over the floor at that thread count. Also the time of the update's own GEMMs as
    they run inside it (:func:`gemm_in_update`) over the floor (``*_gemm_in_update_over_floor``) and as a share of
    the update (``*_gemm_share_of_update``, of the ``compiled_python_wrapper`` arm's time, whose kernels it
    profiles)."""
    buffers = sample_batches(4000, seed, buffer_keys())
    flops = update_flops(seed, buffers)
    rates = {str(t): gemm_rate(t) for t in threads}
    out = {**flops, "gemm_flop_per_s": rates, "threads_of_update": update["torch_threads"]}
    rate = rates.get(str(update["torch_threads"])) or gemm_rate(update["torch_threads"])
    for agent in ("td3", "d3qn"):
        floor = flops[f"{agent}_flops_per_update"] / rate
        out[f"{agent}_floor_s"] = floor
        for arm in ("compiled", "plain"):
            out[f"{agent}_{arm}_over_floor"] = update[arm][f"{agent}_update_s"] / floor
    out.update(gemm_in_update(seed, buffers))
    out.update(update_parts(seed, buffers))
    for agent in ("td3", "d3qn"):
        out[f"{agent}_gemm_in_update_over_floor"] = out[f"{agent}_gemm_in_update_s"] / out[f"{agent}_floor_s"]
        parts = out[f"{agent}_parts_s"]
        out[f"{agent}_bound_over_floor"] = (
            out[f"{agent}_gemm_in_update_s"] + parts["optimizer"] + parts["soft"]
        ) / out[f"{agent}_floor_s"]
        if "compiled_python_wrapper" in update:
            out[f"{agent}_gemm_share_of_update"] = (
                out[f"{agent}_gemm_in_update_s"] / update["compiled_python_wrapper"][f"{agent}_update_s"]
            )
    return out


def measure_torchrl_td3(
    updates: int,
    repeats: int,
    device: torch.device,
    batch_size: int = 256,
    obs: int = 17,
    act: int = 6,
    hidden: tuple[int, ...] = (256, 256),
    probe=None,
) -> dict:
    """(r): the reference the issue's GPU goal names, TorchRL's own TD3 as its ``sota-implementations`` run it:
    ``TD3Loss`` (twin critics) on a MuJoCo-sized task (by default 17-dim observations, 6 actions, 2 x 256 MLPs),
    batch ``batch_size``, each update ``torch.compile`` d and (on CUDA) wrapped in ``CudaGraphModule`` with
    capturable Adam; the critic step and, every second update (``policy_delay`` 2), the critic + actor +
    ``SoftUpdate`` step, as two functions. Updates per second on random batches already on ``device``, median over
    ``repeats``. ``probe(call, graphs)``, if given, is called after the timing with ``call(i)`` (the ``i``-th update
    as timed) and, on CUDA, the two CUDA graphs in the order the updates replay them; what it returns is added."""
    from tensordict import TensorDict
    from tensordict.nn import CudaGraphModule, TensorDictModule
    from torchrl.data import Bounded
    from torchrl.modules import MLP, ValueOperator
    from torchrl.objectives import SoftUpdate, TD3Loss

    b, cells = batch_size, list(hidden)
    torch.manual_seed(0)
    actor = TensorDictModule(
        torch.nn.Sequential(MLP(obs, act, num_cells=cells), torch.nn.Tanh()), ["observation"], ["action"]
    ).to(device)
    critic = ValueOperator(MLP(obs + act, 1, num_cells=cells), in_keys=["observation", "action"]).to(device)
    loss = TD3Loss(
        actor,
        critic,
        action_spec=Bounded(-torch.ones(act), torch.ones(act), device=device),
        num_qvalue_nets=2,
        loss_function="l2",
        delay_actor=True,
        delay_qvalue=True,
    )
    loss.make_value_estimator(gamma=0.99)
    target = SoftUpdate(loss, tau=0.005)
    graphs = device.type == "cuda"
    opt_a = torch.optim.Adam(loss.actor_network_params.flatten_keys().values(), lr=3e-4, capturable=graphs)
    opt_c = torch.optim.Adam(loss.qvalue_network_params.flatten_keys().values(), lr=3e-4, capturable=graphs)

    def value(td):
        q, _ = loss.value_loss(td)
        q.backward()
        opt_c.step()
        opt_c.zero_grad(set_to_none=True)
        return TensorDict({"q": q.detach()})

    def full(td):
        out = value(td)
        a, _ = loss.actor_loss(td)
        a.backward()
        opt_a.step()
        opt_a.zero_grad(set_to_none=True)
        target.step()
        return out.set("a", a.detach())

    steps = [torch.compile(f) for f in (value, full)]
    if graphs:
        steps = [CudaGraphModule(f, in_keys=[], out_keys=[], warmup=5) for f in steps]

    def batch():
        flags = {k: torch.zeros(b, 1, dtype=torch.bool, device=device) for k in ("done", "terminated")}
        return TensorDict(
            {
                "observation": torch.randn(b, obs, device=device),
                "action": torch.rand(b, act, device=device) * 2 - 1,
                "next": {
                    "observation": torch.randn(b, obs, device=device),
                    "reward": torch.randn(b, 1, device=device),
                    **flags,
                },
            },
            [b],
        )

    batches = [batch() for _ in range(updates)]
    for i, td in enumerate(batches[:12]):
        steps[i % 2](td)
    runs = []
    for _ in range(repeats):
        _sync(device)
        t0 = time.perf_counter()
        for i, td in enumerate(batches):
            steps[i % 2](td)
        _sync(device)
        runs.append((time.perf_counter() - t0) / len(batches))
    per_update = statistics.median(runs)
    print(
        f"  TorchRL's own TD3 (batch {b}, {obs}-dim obs, {act} actions, {cells}): {1 / per_update:.0f} updates/s",
        flush=True,
    )
    out = {"batch_size": b, "td3_update_s": per_update, "td3_updates_per_s": 1.0 / per_update}
    if probe is not None:
        out.update(probe(lambda i: steps[i % 2](batches[i % len(batches)]), [s.graph for s in steps] if graphs else []))
    return out


CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


class _OnDevice(torch.nn.Module):
    """A policy run on ``device``: inputs moved there, actions moved back to the env's CPU TensorDict."""

    def __init__(self, policy, device: torch.device):
        super().__init__()
        self.policy, self.device = policy, device

    def forward(self, td):
        out = self.policy(td.select(*self.policy.in_keys, strict=False).to(self.device, non_blocking=True))
        for key in self.policy.out_keys:
            td.set(key, out.get(key).cpu())
        return td


def measure_acting(k: int, calls: int, seed: int, devices: list[torch.device]) -> dict:
    """(p): milliseconds per call of the exploring acting policy (both agents, ``learner.policy()``) on a ``k``-row
    TensorDict of the env (fake env + KDDRL transform stack + decision clock, on the CPU as in training), with the
    learner on each of ``devices``: the policy run on that device, its inputs moved there and its actions back
    (for a CUDA learner what TorchRL's ``policy_device`` does). Tells where acting is fastest: training acts on the
    CPU (:class:`~kddrl_trl.collectors.PolicySnapshot`) because the CPU measured faster."""
    env = TransformedEnv(
        FakeHighwayEnv(num_roads=k, seed=seed),
        Compose(make_kddrl_transforms(seed=seed), DecisionClock(learner_kwargs(False)[1])),
    )
    td = env.reset()
    rows = {}
    for device in devices:
        learner = HierarchicalLearner(**learner_kwargs(False)[0], device=device)
        policy = learner._policy() if device.type == "cpu" else _OnDevice(learner._policy(), device)
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):  # exploring, as a collector acts
            for _ in range(20):
                policy(td.clone())
            _sync(device)
            t0 = time.perf_counter()
            for _ in range(calls):
                policy(td.clone())
            _sync(device)
        rows[str(device)] = 1e3 * (time.perf_counter() - t0) / calls
        print(f"  acting policy, learner on {device}, K={k}: {rows[str(device)]:.2f} ms per call", flush=True)
    env.close()
    return {"num_roads": k, "calls": calls, "ms_per_call": rows, "fastest": min(rows, key=rows.get)}


class _Stopwatch:
    """Seconds spent in chosen methods of chosen objects, summed per part (:func:`measure_collect`'s breakdown).
    ``wrap(obj, method, part)`` replaces the bound method on the instance by a timed call of it; ``running``
    switches the timing on (off: the calls only pass through)."""

    def __init__(self, timer):
        self.timer, self.seconds, self.running, self.depth = timer, {}, False, 0

    def wrap(self, obj, method: str, part: str) -> None:
        inner = getattr(obj, method)
        self.seconds.setdefault(part, 0.0)

        def timed(*args, **kwargs):
            if not self.running or self.depth:  # a part called inside another counts for the outer one
                return inner(*args, **kwargs)
            self.depth += 1
            t0 = self.timer()
            try:
                return inner(*args, **kwargs)
            finally:
                self.seconds[part] += self.timer() - t0
                self.depth -= 1

        object.__setattr__(obj, method, timed)  # on the instance, past nn.Module's own __setattr__


def measure_collect(
    k: int, frames: int, seed: int, clock: str = "wall", compile: bool | str | None = None, direct: bool = True
) -> dict:
    """(b) at ``k`` roads; ``clock="cpu"`` times both arms in CPU seconds of this (single-threaded) process, which a
    shared, saturated machine does not distort as it does wall time. ``direct=False``: the compiled stack's every
    call under TorchDynamo's guards, as before its warm graph was called directly
    (:func:`kddrl_trl.transforms.stack.warm_frames`).

    ``breakdown``: where the collection's time goes, in milliseconds per env step (``k`` ego-frames) and as shares:
    ``env`` (``SumoHighwayEnv`` 's step and partial resets: SUMO and the observation building), ``transforms``
    (the transform stack and the decision clock, on every step and reset), ``policy`` (both agents' acting call),
    ``buffers`` (the macro-transition writer and both buffers' writes) and ``torchrl``: the rest of the wall time,
    TorchRL's own collector and ``TransformedEnv`` plumbing (the rollout loop, ``step_mdp``, the TensorDict
    copies). The parts are timed around those calls only, so nothing else is counted twice."""
    timer = CLOCKS[clock]
    sim_fps, _ = measure_sim("baseline", k, seed, frames // k, 20, timer=timer)
    learner = HierarchicalLearner(**learner_kwargs(False)[0])
    env = collect_env(k, compile, seed=seed)
    rb_cf, rb_lc = make_buffer(frames * 2, 256, seed), make_buffer(frames, 64, seed)
    policy = learner.policy()
    if not direct:
        for t in env.transform.modules():
            if isinstance(t, PredictiveStack):
                warm_frames(t).guard_every_call()
    mtc = MultiTimescaleCollector.from_env(
        env,
        policy,
        frames_per_env=FRAMES_PER_ENV,
        frame_buffer=rb_cf,
        macro_buffer=rb_lc,
        frame_keys=learner.buffer_keys(),
    )
    watch = _Stopwatch(timer)
    for obj, method, part in (
        (env.base_env, "_step", "env"),
        (env.base_env, "_reset", "env"),
        (env.transform, "_step", "transforms"),
        (env.transform, "_reset", "transforms"),
        (policy, "forward", "policy"),
        (mtc, "writer", "buffers"),
        (rb_cf, "extend", "buffers"),
        (rb_lc, "extend", "buffers"),
    ):
        watch.wrap(obj, method, part)
    try:
        it = iter(mtc)
        for _ in range(3):  # warm-up batches (and the one-off compile of the stack), untimed
            next(it)
        watch.running = True
        t0, n = timer(), 0
        while n < frames:
            n += next(it).frames.numel()
        elapsed = timer() - t0
        fps = n / elapsed
    finally:
        mtc.shutdown(close_env=False)
        env.close()
    parts = {**watch.seconds, "torchrl": elapsed - sum(watch.seconds.values())}
    steps = n / k
    return {
        "num_roads": k,
        "clock": clock,
        **({} if direct else {"direct": False}),
        "sim_limit_fps": sim_fps,
        "collect_fps": fps,
        "collect_ratio_vs_sim": fps / sim_fps,
        "breakdown": {
            "ms_per_env_step": {name: 1e3 * t / steps for name, t in parts.items()},
            "share": {name: t / elapsed for name, t in parts.items()},
        },
    }


def measure_collect_workers(
    k: int, workers: list[int], frames: int, seed: int, compile: bool | str | None = None, backend: str = "process"
) -> dict:
    """(w): collection frames/s (wall clock) with each N of ``workers`` env processes (``backend="ray"``: Ray
    actors, N = 1 included; ``benchmarks/scale_out.py``) at ``k`` roads each, and ``collect_scaling`` per N =
    fps(N) / (N x fps(1))."""
    from functools import partial

    if 1 not in workers:
        raise SystemExit(f"--workers {workers}: the scaling is measured against 1 worker, list it too")
    rows = []
    for n in workers:
        learner = HierarchicalLearner(**learner_kwargs(False)[0])
        make = partial(collect_env, k, compile)
        envs = [WorkerEnv(make, worker_seed(seed, i), seed_torch=n > 1) for i in range(n)]
        rb_cf, rb_lc = make_buffer(frames * 2, 256, seed), make_buffer(frames, 64, seed)
        mtc = MultiTimescaleCollector.from_env(
            envs,
            learner.policy(),
            frames_per_env=FRAMES_PER_ENV,
            rows=k,
            frame_buffer=rb_cf,
            macro_buffer=rb_lc,
            frame_keys=learner.buffer_keys(),
            backend=backend,
        )
        try:
            it = iter(mtc)
            for _ in range(3):  # warm-up batches (and one-off compiles), untimed
                next(it)
                mtc.update_policy_weights_()
            t0, got = time.perf_counter(), 0
            while got < frames:
                got += next(it).frames.numel()
                mtc.update_policy_weights_()
            fps = got / (time.perf_counter() - t0)
        finally:
            mtc.shutdown()
        rows.append({"workers": n, "num_roads": k, "backend": backend, "collect_fps": fps})
        print(f"  collect with {n} {backend} worker(s), K={k}: {fps:.0f} frames/s", flush=True)
    one = next(r["collect_fps"] for r in rows if r["workers"] == 1)
    return {
        "clock": "wall",
        "runs": rows,
        "collect_scaling": {str(r["workers"]): r["collect_fps"] / (r["workers"] * one) for r in rows},
    }


def compare_runs(run: Path, baseline: Path) -> dict:
    """(c'): two finished runs of one job and seed, ``run`` on this code and ``baseline`` on other code, trained
    side by side (one core each: the load is the same for both): the ratio of their training wall times, and
    whether their training and evaluation records are byte for byte the same (a change that should not alter
    the arithmetic)."""
    a, b = (json.loads((d / "summary.json").read_text())["training"]["elapsed_s"] for d in (run, baseline))

    def same(name: str) -> bool:
        return record_bytes(run, name) == record_bytes(baseline, name)

    evals = [json.loads((d / "summary.json").read_text()).get("episodes") for d in (run, baseline)]
    return {
        "baseline_dir": str(baseline),
        "elapsed_s": a,
        "baseline_elapsed_s": b,
        "time_ratio": a / b,
        "train_records_identical": same("train_episodes.csv"),
        # evaluations of different lengths (eval_episodes=) do not compare
        "eval_records_identical": same("eval_episodes.csv") if evals[0] == evals[1] else None,
    }


def learner_compile_gain(update: dict, collect_fps: float) -> float:
    """Share of the training wall time per ego-frame (collection + the eager learner's updates) that the
    compiled learner saves."""
    eager, compiled = update["eager"]["per_frame_s"], update["compiled"]["per_frame_s"]
    return (eager - compiled) / (1.0 / collect_fps + eager)


#: keys of the results file that describe a run rather than hold a measurement
def same_batch(batches: list[int], updates: int, seed: int, repeats: int, device: torch.device, update: dict) -> dict:
    """Our compiled, CUDA-graphed TD3 update and TorchRL's own (r) at the same TD3 minibatch, for each of
    ``batches`` (``update``: (a) already measured at training's batch, reused there). Per batch: both rates in
    updates/s and their ratio (ours / TorchRL's; above 1: ours is faster)."""
    out = {}
    for b in batches:
        ours = update if b == update["batch_size_cf"] else measure_update(updates, seed, repeats, device, b)
        ref = measure_torchrl_td3(updates, repeats, device, batch_size=b)
        out[str(b)] = {
            "td3_updates_per_s": 1.0 / ours["compiled"]["td3_update_s"],
            "d3qn_updates_per_s": 1.0 / ours["compiled"]["d3qn_update_s"],
            "torchrl_td3_updates_per_s": 1.0 / ref["td3_update_s"],
            "td3_ratio_vs_torchrl_same_batch": ref["td3_update_s"] / ours["compiled"]["td3_update_s"],
        }
        print(
            f"  batch {b}: ours {out[str(b)]['td3_updates_per_s']:.0f} TD3 updates/s, TorchRL's "
            f"{out[str(b)]['torchrl_td3_updates_per_s']:.0f}: ratio "
            f"{out[str(b)]['td3_ratio_vs_torchrl_same_batch']:.2f}",
            flush=True,
        )
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--roads", type=int, nargs="+", default=[8, 32])
    p.add_argument("--updates", type=int, default=200, help="TD3 updates timed per repeat")
    p.add_argument("--frames", type=int, default=4000, help="ego-frames timed for collection")
    p.add_argument(
        "--clock",
        choices=sorted(CLOCKS),
        default="wall",
        help="collection timing: wall seconds, or CPU seconds of this process (a shared machine)",
    )
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--full-run", type=Path, default=None, help="run dir of a finished 1000-episode training")
    p.add_argument(
        "--baseline-run",
        type=Path,
        default=None,
        help="with --full-run: a run of the same job and seed made with other code, side by side with it",
    )
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "train_throughput.json")
    p.add_argument("--device", default="cpu", help="where (a) runs: cpu | cuda (cuda adds the 'gpu' entry)")
    p.add_argument("--skip-collect", action="store_true", help="leave (b) out")
    p.add_argument(
        "--collect-direct-gain",
        type=int,
        default=0,
        metavar="N",
        help="(b) also with the stack's graph under TorchDynamo's guards, N turns each: collect_direct_gain, the "
        "median of the turns' fps ratios",
    )
    p.add_argument("--batch-size-cf", type=int, default=None, help="(a): TD3 minibatch (default: training's 128)")
    p.add_argument(
        "--acting-calls",
        type=int,
        default=0,
        help="(p): time this many acting-policy calls at each K of --roads, learner on the CPU and on "
        "--device (0: skip)",
    )
    p.add_argument("--skip-update", action="store_true", help="leave (a) out")
    p.add_argument(
        "--floor",
        action="store_true",
        help="(a): also the compute floor: the updates' FLOPs over the GEMM rate at their shapes (floor)",
    )
    p.add_argument("--floor-threads", type=int, nargs="+", default=[1, 2], help="--floor: GEMM rates at these")
    p.add_argument(
        "--gpu-batches",
        type=int,
        nargs="*",
        default=[],
        help="with --device cuda: (a)'s compiled TD3 and (r) again at each of these TD3 minibatches, "
        "side by side (gpu.by_batch; gpu.td3_ratio_vs_torchrl_same_batch at training's batch)",
    )
    p.add_argument(
        "--torchrl-reference",
        choices=["auto", "on", "off"],
        default="auto",
        help="(r): TorchRL's own compiled TD3 as the GPU goal's reference (auto: with --device cuda)",
    )
    p.add_argument(
        "--update-threads",
        type=int,
        default=len(os.sched_getaffinity(0)),
        help="(a): torch threads of the updates (default: the cores, torch's default and so training's)",
    )
    p.add_argument("--workers", default="", help="(w): comma-separated worker counts, e.g. 1,2 (1 must be in)")
    p.add_argument("--workers-roads", type=int, default=8, help="(w): roads per worker")
    p.add_argument(
        "--note",
        default=None,
        help="free text stored in the JSON (e.g. how --full-run / --baseline-run "
        "were run: side by side, one core each, which codes)",
    )
    p.add_argument(
        "--compile",
        default=None,
        choices=["auto", "true", "false"],
        help="the transform stack's compile in (b) and (w) (default: conf/config.yaml's)",
    )
    args = p.parse_args(argv)
    compile = None if args.compile is None else resolve_compile(args.compile)
    apply_flush_denormal(True)  # as every job sets it by default (``flush_denormal``), for every arm alike

    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit(f"--device {args.device}: no CUDA device is available here")
    env_threads = 1  # the env and the acting policy: single-threaded (env_throughput.py); the updates get their own
    torch.set_num_threads(args.update_threads)
    update = (
        None if args.skip_update else measure_update(args.updates, args.seed, args.repeats, device, args.batch_size_cf)
    )
    if update is not None:
        update["torch_threads"] = torch.get_num_threads()
    floor = (
        measure_floor(update, args.seed, args.floor_threads)
        if args.floor and update is not None and device.type == "cpu"
        else None
    )
    reference = (
        measure_torchrl_td3(args.updates, args.repeats, device)
        if args.torchrl_reference == "on" or (args.torchrl_reference == "auto" and device.type == "cuda")
        else None
    )
    torch.set_num_threads(env_threads)
    acting = (
        [
            measure_acting(k, args.acting_calls, args.seed, list(dict.fromkeys([torch.device("cpu"), device])))
            for k in args.roads
        ]
        if args.acting_calls
        else []
    )
    collect = (
        []
        if args.skip_collect
        else [measure_collect(k, args.frames, args.seed, args.clock, compile) for k in args.roads]
    )
    if args.collect_direct_gain and not args.skip_collect:  # the same collection without the direct calls, in turns
        for c in collect:
            turns = [
                (c["collect_fps"], measure_collect(c["num_roads"], args.frames, args.seed, args.clock, compile, False))
            ]
            for _ in range(args.collect_direct_gain - 1):
                on = measure_collect(c["num_roads"], args.frames, args.seed, args.clock, compile)["collect_fps"]
                off = measure_collect(c["num_roads"], args.frames, args.seed, args.clock, compile, False)
                turns.append((on, off))
            c["collect_fps_not_direct"] = [off["collect_fps"] for _, off in turns]
            c["collect_fps_direct"] = [on for on, _ in turns]
            c["breakdown_not_direct"] = turns[-1][1]["breakdown"]
            c["collect_direct_gain"] = statistics.median(on / off["collect_fps"] for on, off in turns)
            print(f"  K={c['num_roads']}: direct calls earn x{c['collect_direct_gain']:.3f} collection fps", flush=True)
    for c in collect:
        if update is not None:
            c["learner_compile_gain"] = learner_compile_gain(update, c["collect_fps"])
    result = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "machine": machine_info(),
        "update": update,
        **({"torchrl_td3_reference": reference} if reference is not None and device.type != "cuda" else {}),
        "collect": collect,
        **({"note": args.note} if args.note else {}),
        **({"floor": floor} if floor else {}),
    }
    if args.workers:
        workers = measure_collect_workers(
            args.workers_roads, [int(n) for n in args.workers.split(",")], args.frames, args.seed, compile
        )
        result["collect_workers"] = workers["runs"]
        result["collect_scaling"] = workers["collect_scaling"]
    if update is not None and device.type == "cuda":
        result["gpu"] = {
            "device_name": torch.cuda.get_device_name(device),
            **{
                f"{arm}_{agent}_updates_per_s": 1.0 / update[arm][f"{agent}_update_s"]
                for arm in ("compiled", "compiled_cpu_batches", "eager", "plain")
                for agent in ("td3", "d3qn")
            },
            "td3_updates_per_s": 1.0 / update["compiled"]["td3_update_s"],
            "d3qn_updates_per_s": 1.0 / update["compiled"]["d3qn_update_s"],
            "batch_size_cf": update["batch_size_cf"],
            "ratio_vs_plain": update["plain"]["per_frame_s"] / update["compiled"]["per_frame_s"],
        }
        if reference is not None:
            result["gpu"]["torchrl_td3_reference"] = reference
            result["gpu"]["td3_ratio_vs_torchrl_reference"] = (
                reference["td3_update_s"] / update["compiled"]["td3_update_s"]
            )
        if acting:
            result["gpu"]["acting"] = acting
        if args.gpu_batches:
            result["gpu"]["by_batch"] = same_batch(
                args.gpu_batches, args.updates, args.seed, args.repeats, device, update
            )
            train_batch = str(update["batch_size_cf"])
            if train_batch in result["gpu"]["by_batch"]:
                result["gpu"]["td3_ratio_vs_torchrl_same_batch"] = result["gpu"]["by_batch"][train_batch][
                    "td3_ratio_vs_torchrl_same_batch"
                ]
    elif acting:
        result["acting"] = acting
    elif update is not None:
        result["update_ratio_vs_plain"] = update["plain"]["per_frame_s"] / update["compiled"]["per_frame_s"]
        result["update_ratio_vs_plain_eager"] = update["plain"]["per_frame_s"] / update["eager"]["per_frame_s"]
        if "compiled_python_wrapper" in update:  # what the C++ wrapper earns: > 1.0 is a gain
            result["cpp_wrapper_gain"] = (
                update["compiled_python_wrapper"]["per_frame_s"] / update["compiled"]["per_frame_s"]
            )
        if "compiled_size_asserts" in update:  # what dropping the size asserts earns: > 1.0 is a gain
            result["size_asserts_gain"] = (
                update["compiled_size_asserts"]["per_frame_s"] / update["compiled"]["per_frame_s"]
            )
        if "compiled_torch_adam" in update:  # what the lean optimiser steps earn: > 1.0 is a gain
            result["lean_adam_gain"] = update["compiled_torch_adam"]["per_frame_s"] / update["compiled"]["per_frame_s"]
        if "compiled_dynamo_frames" in update:  # what calling warm graphs directly earns: > 1.0 is a gain
            result["direct_call_gain"] = (
                update["compiled_dynamo_frames"]["per_frame_s"] / update["compiled"]["per_frame_s"]
            )
    if collect:
        result["collect_ratio_vs_sim"] = min(c["collect_ratio_vs_sim"] for c in collect)
    if args.full_run is not None:
        summary = json.loads((args.full_run / "summary.json").read_text())
        result["train_1000_episodes_s"] = summary["training"]["elapsed_s"]
        result["full_run"] = {
            "dir": str(args.full_run),
            "episodes": summary["training"]["episodes"],
            "frames": summary["training"]["frames"],
        }
        if args.baseline_run is not None:
            result["full_run_vs_baseline"] = compare_runs(args.full_run, args.baseline_run)
    if args.out.is_file():  # keep what this run did not measure (a CPU run keeps the gpu entry and vice versa)
        keep_previous(result, json.loads(args.out.read_text()))

    update = result.get("update")
    if update:
        print(
            f"\n{'learner (per collected frame)':<34}{'TD3 upd/s':>10}{'D3QN upd/s':>11}{'frame cost ms':>14}"
            f"{'ratio vs plain':>15}"
        )
        print(f"(device {update['device']})")
        for name in [
            n
            for n in (
                "plain",
                "eager",
                "compiled",
                "compiled_python_wrapper",
                "compiled_size_asserts",
                "compiled_cpu_batches",
            )
            if n in update
        ]:
            r = update[name]
            print(
                f"{name:<34}{1 / r['td3_update_s']:>10.0f}{1 / r['d3qn_update_s']:>11.0f}"
                f"{1e3 * r['per_frame_s']:>14.2f}{update['plain']['per_frame_s'] / r['per_frame_s']:>15.2f}"
            )
    if floor:
        print(
            f"\n{'compute floor (FLOPs / GEMM rate)':<34}{'MFLOP':>8}{'floor ms':>10}{'ours/floor':>12}"
            f"{'plain/floor':>13}   GEMM GFLOP/s by threads: "
            + ", ".join(f"{t}: {r / 1e9:.0f}" for t, r in floor["gemm_flop_per_s"].items())
        )
        for agent in ("td3", "d3qn"):
            print(
                f"{agent:<34}{floor[f'{agent}_flops_per_update'] / 1e6:>8.1f}{1e3 * floor[f'{agent}_floor_s']:>10.3f}"
                f"{floor[f'{agent}_compiled_over_floor']:>12.2f}{floor[f'{agent}_plain_over_floor']:>13.2f}"
            )
        if "td3_gemm_in_update_s" in floor:
            print(f"\n{'GEMMs inside our update':<34}{'ms':>8}{'÷ floor':>10}{'share of update':>17}")
            for agent in ("td3", "d3qn"):
                share = floor.get(f"{agent}_gemm_share_of_update")
                print(
                    f"{agent:<34}{1e3 * floor[f'{agent}_gemm_in_update_s']:>8.3f}"
                    f"{floor[f'{agent}_gemm_in_update_over_floor']:>10.2f}"
                    + (f"{100 * share:>16.0f}%" if share is not None else "")
                )
        if "td3_parts_s" in floor:
            print(
                f"\n{'our update in parts, ms':<34}{'graph':>8}{'optim':>8}{'soft':>8}{'rest':>8}{'total':>8}"
                f"{'bound ÷ floor':>15}"
            )
            for agent in ("td3", "d3qn"):
                parts = floor[f"{agent}_parts_s"]
                print(
                    f"{agent:<34}"
                    + "".join(f"{1e3 * parts[k]:>8.3f}" for k in ("gradients", "optimizer", "soft", "rest", "total"))
                    + f"{floor[f'{agent}_bound_over_floor']:>15.2f}"
                )
    if result.get("collect"):
        print(
            f"\n{'collection (SUMO + stack + policies)':<38}{'K':>3}{'sim limit fps':>15}{'collect fps':>13}"
            f"{'ratio':>8}{'compiled learner saves':>24}"
        )
    for c in result.get("collect", []):
        gain = f"{100 * c['learner_compile_gain']:>17.1f}% of wall" if "learner_compile_gain" in c else ""
        print(
            f"{'':<38}{c['num_roads']:>3}{c['sim_limit_fps']:>15.0f}{c['collect_fps']:>13.0f}"
            f"{c['collect_ratio_vs_sim']:>8.2f}{gain}"
        )
    for c in result.get("collect", []):
        parts = c["breakdown"]["ms_per_env_step"]
        print(f"\n{'collection, per env step, K = ' + str(c['num_roads']):<38}{'ms':>8}{'share':>8}")
        for name, ms in parts.items():
            print(f"{'  ' + name:<38}{ms:>8.2f}{100 * c['breakdown']['share'][name]:>7.1f}%")
    if result.get("collect_workers"):
        print(
            f"\n{'collection with worker processes':<38}{'N':>3}{'K':>4}{'collect fps':>13}{'fps(N) / (N fps(1))':>21}"
        )
        for r in result["collect_workers"]:
            print(
                f"{'':<38}{r['workers']:>3}{r['num_roads']:>4}{r['collect_fps']:>13.0f}"
                f"{result['collect_scaling'][str(r['workers'])]:>21.2f}"
            )
    if "train_1000_episodes_s" in result:
        print(
            f"\nfull training run: {result['train_1000_episodes_s']:.0f} s for {result['full_run']['episodes']} "
            f"episodes ({result['full_run']['frames']} frames)"
        )
    if args.full_run is not None and args.baseline_run is not None:
        ab = result["full_run_vs_baseline"]
        print(
            f"against {ab['baseline_dir']}: training time ratio {ab['time_ratio']:.3f} ({ab['elapsed_s']:.0f} / "
            f"{ab['baseline_elapsed_s']:.0f} s); training records identical: {ab['train_records_identical']}, "
            f"evaluation records identical: {ab['eval_records_identical']}"
        )
    write_json(args.out, result)
    print(f"\nwritten {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
