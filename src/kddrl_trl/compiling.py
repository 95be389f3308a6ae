"""When to ``torch.compile``: one rule for the two compile sites (the fused transform stack and the learner).

The sites themselves are :func:`kddrl_trl.transforms.stack.compiled_frames` (the fused predictive-state stack)
and the learner's gradient function (:meth:`kddrl_trl.training.Learner._compile`, for every learner; its measured
gain is stated on :class:`kddrl_trl.training.HierarchicalLearner`), both called through :class:`WarmCompiled`.
"""

from __future__ import annotations

import inspect
import itertools
import logging
import shutil
import types
from collections.abc import Callable
from functools import lru_cache

import torch
from tensordict import TensorDict, TensorDictBase
from torch._dynamo import config as dynamo_config

log = logging.getLogger(__name__)


@lru_cache(maxsize=1)
def _compiler_found() -> bool:
    """Whether a C++ compiler is on the PATH (looked up, and logged, once per process)."""
    found = next((c for c in ("c++", "g++", "clang++") if shutil.which(c)), None)
    log.info("compile=auto: %s", f"{found} found, compiling" if found else "no C++ compiler on the PATH, eager")
    return found is not None


#: ``compile=auto`` trains eagerly below this many training episodes. Compiling costs a process a fixed time, which
#: a job earns back per update; ``benchmarks/compile_cost.py --episodes 20 100 300`` (``results/compile_cost.json``)
#: measured on 2 CPU cores that the compiled job takes less process time than the eager one from 37 training
#: episodes with warm compile caches and from 117 with cold ones (the first compiled job of a code version on a
#: machine), and half of it at 300. Below 100 the compiled job saves at most seconds with warm caches and costs more
#: with cold ones.
SHORT_RUN_EPISODES = 100


def resolve_compile(compile: bool | str, episodes: int | None = None) -> bool:
    """A ``compile`` option -> bool. ``"auto"`` compiles when a C++ compiler is on the PATH (the CPU backend of
    ``torch.compile`` needs one) and the job runs at least :data:`SHORT_RUN_EPISODES` episodes (``episodes``: a
    training job's training episodes, an evaluation's episodes; None: not known), below which the compile does not
    pay for itself, and logs which way it went; anything else must be a bool."""
    if isinstance(compile, str):
        if compile.lower() in ("true", "false"):
            return compile.lower() == "true"
        if compile.lower() != "auto":
            raise ValueError(f"compile must be true, false or 'auto', got {compile!r}")
        if episodes is not None and episodes < SHORT_RUN_EPISODES:
            log.info("compile=auto: %d episodes (< %d), eager", episodes, SHORT_RUN_EPISODES)
            return False
        return _compiler_found()
    if not isinstance(compile, bool):
        raise ValueError(f"compile must be true, false or 'auto', got {compile!r}")
    return compile


def fresh_compiler() -> None:
    """Empties TorchDynamo's caches, at the start of every job of an entry point.

    A launcher may run many jobs in one worker process (Hydra's joblib launcher reuses loky workers, Ray reuses its
    workers), and TorchDynamo keeps every graph compiled so far, each guarded on the objects of the job that made
    it. A code object holds at most ``torch._dynamo.config.recompile_limit`` graphs (8); past that a new job's
    calls of the same code (the learner's gradient function, the transform stack) run eagerly, and under
    :class:`WarmCompiled` each call first fails its guard-skipping attempt: the same numbers, several times slower.
    The graphs' kernels stay in TorchInductor's on-disk cache, so a job recompiles no faster or slower than the
    first job of a fresh process. Its compile timers and counters restart too (:func:`compile_seconds`,
    :func:`compile_counts`)."""
    from torch._dynamo.utils import compilation_time_metrics, counters

    torch._dynamo.reset()
    compilation_time_metrics.clear()
    counters.clear()


def compile_seconds() -> float:
    """Seconds TorchDynamo and TorchInductor spent compiling in this process since the job started
    (:func:`fresh_compiler`): tracing, lowering and code generation, cache hits included; worker processes are not
    counted. A run's ``summary.json`` records it as ``compile_s``."""
    from torch._dynamo.utils import compilation_time_metrics

    return float(sum(compilation_time_metrics.get("_compile.compile_inner", ())))


def compile_counts() -> dict[str, int]:
    """What this process compiled since the job started (:func:`fresh_compiler`): the graphs TorchDynamo captured,
    and how many of them TorchInductor's FX-graph cache and AOTAutograd's cache (on disk, shared by every process of
    the machine) served (``*_hit``) or had to build (``*_miss``). A run's ``summary.json`` records it as
    ``compile_counts``."""
    from torch._dynamo.utils import counters

    return {
        "graphs": int(counters["stats"]["unique_graphs"]),
        "fxgraph_cache_hit": int(counters["inductor"]["fxgraph_cache_hit"]),
        "fxgraph_cache_miss": int(counters["inductor"]["fxgraph_cache_miss"]),
        "autograd_cache_hit": int(counters["aot_autograd"]["autograd_cache_hit"]),
        "autograd_cache_miss": int(counters["aot_autograd"]["autograd_cache_miss"]),
    }


def resolve_cudagraphs(cudagraphs: bool | str, device: torch.device) -> bool:
    """A ``cudagraphs`` option (true | false | auto) -> bool: ``auto`` is on for a CUDA learner, off on the CPU;
    ``true`` on a CPU learner is refused (CUDA graphs exist on CUDA only)."""
    if isinstance(cudagraphs, str):
        if cudagraphs.lower() not in ("true", "false", "auto"):
            raise ValueError(f"cudagraphs must be true, false or auto, got {cudagraphs!r}")
        if cudagraphs.lower() == "auto":
            return device.type == "cuda"
        cudagraphs = cudagraphs.lower() == "true"
    if not isinstance(cudagraphs, bool):
        raise ValueError(f"cudagraphs must be true, false or auto, got {cudagraphs!r}")
    if cudagraphs and device.type != "cuda":
        raise ValueError(f"cudagraphs=true needs device=cuda (the learner is on {device}); use cudagraphs=auto")
    return cudagraphs


def resolved(name: str, value) -> bool:
    """A knob a part receives already resolved (:func:`kddrl_trl.factories.make_job` resolves ``compile`` and
    ``cudagraphs`` once per job): a bool, or a ``ValueError`` naming the knob and the resolver."""
    if not isinstance(value, bool):
        raise ValueError(
            f"{name} must be a bool here, got {value!r}: resolve it first (kddrl_trl.compiling.resolve_{name})"
        )
    return value


def inductor_options(device: torch.device | str) -> dict:
    """TorchInductor options of a compile site whose kernels run on ``device``. On the CPU:

    - a C++ wrapper (``cpp_wrapper``) calls the generated kernels instead of Python code, one Python-level call per
      compiled graph instead of one per kernel;
    - without the wrapper's size asserts (``size_asserts``): by default the wrapper checks each input's sizes and
      strides on every call, and each check builds a ``std::stringstream`` for a message it never prints. A
      learner's gradient graph takes every parameter it reads as an input (over a hundred), so the checks add up. What
      they check is checked before the graph runs: TorchDynamo's guards compare each input tensor's sizes and
      strides with the graph's (also under :class:`WarmCompiled`'s ``skip_guard_eval_unsafe``), and a mismatch
      compiles a new graph rather than running this one.

    The kernels are the same either way, so are the results (bit for bit: tested); what each option earns is
    measured by ``benchmarks/update_speed.py`` (``cpp_wrapper_gain``, ``size_asserts_gain``). On CUDA, the
    defaults (a CUDA-graphed update's replay skips the wrapper anyway)."""
    return {"cpp_wrapper": True, "size_asserts": False} if torch.device(device).type == "cpu" else {}


def tracing_gradients():
    """The context in which a learner's gradient function (:meth:`kddrl_trl.training.Learner._gradients`) is
    compiled: TorchDynamo traces ``torch.autograd.grad`` (``torch._dynamo.config.trace_autograd_ops``; left off,
    the call is a graph break), so that a step's loss and its gradients are one graph with the gradients as
    outputs. AOTAutograd then compiles no backward: no saved tensors, no autograd wrapper around the graph, no
    ``AccumulateGrad``, and TorchInductor fuses the forward's and the backward's kernels together. The setting is
    read when tracing; the graph's gradients are those of ``backward`` (tested)."""
    return dynamo_config.patch(trace_autograd_ops=True)


def specializing_floats():
    """A context in which TorchDynamo traces Python floats as constants (``torch._dynamo.config.specialize_float``),
    for the fused transform stack (:func:`kddrl_trl.transforms.stack.compiled_frames`): left symbolic, the members'
    float constants made Dynamo trace the whole stack twice (a ``TensorifyScalarRestartAnalysis`` restart) into a
    graph with more inputs; specialized, a process's first frame compiles in about half the time. A stack whose
    constants differ gets a graph of its own. The setting is read when tracing; entering the context is cheap (it
    is entered on every frame)."""
    return dynamo_config.patch(specialize_float=True)


def _signature(value) -> object:
    """What a compiled graph assumes of one argument of its function: a tensor's type, shape, strides, dtype, device
    and ``requires_grad``; a TensorDict's type, batch size, device and each leaf's key, shape, strides and dtype
    (and device, where the TensorDict has none); a tuple's or list's type and its items' signatures, a dict's keys
    and its values' signatures, in order; any other argument itself (None, a loss name). Hashable, or
    ``TypeError`` (an argument that cannot be told apart cheaply)."""
    if isinstance(value, torch.Tensor):
        return (type(value), value.shape, value.stride(), value.dtype, value.device, value.requires_grad)
    if isinstance(value, (list, tuple)):
        return (type(value), *map(_signature, value))
    if isinstance(value, dict):
        return (dict, *((k, _signature(v)) for k, v in value.items()))
    if isinstance(value, TensorDictBase):
        leaves: list = []
        if type(value) is TensorDict:
            _leaves(value, leaves, value.device is None)
        else:
            leaves.extend((k, _signature(v)) for k, v in value.items(True, True))
        return (type(value), value.batch_size, value.device, tuple(leaves))
    hash(value)
    return value


def _leaves(td: TensorDict, out: list, devices: bool) -> None:
    """Appends the key, shape, strides and dtype (and device, with ``devices``) of every leaf of ``td`` to ``out``,
    depth first, a nested TensorDict's key before its leaves and None after them: :func:`_signature` 's walk of a
    plain ``TensorDict`` (its own dict of entries: several times faster than ``items(True, True)``)."""
    for k, v in td._tensordict.items():
        if isinstance(v, torch.Tensor):
            out.append((k, v.shape, v.stride(), v.dtype, v.device) if devices else (k, v.shape, v.stride(), v.dtype))
        elif type(v) is TensorDict:
            out.append(k)
            _leaves(v, out, devices)
            out.append(None)
        else:
            out.append((k, _signature(v)))


#: :attr:`WarmCompiled.direct` 's answer for a signature it has not looked up yet
_UNSEEN = object()


class WarmCompiled:
    """A ``torch.compile`` d function ``fn(name, *args)`` whose warm graphs are called directly, without TorchDynamo's
    frame evaluation: a learner's gradient function ``fn(name, batch)``, or the fused transform stack's
    ``fn(members, values, noises)`` (:func:`kddrl_trl.transforms.stack.warm_frames`).

    TorchDynamo checks a compiled frame's guards on every call before it runs the graph. On a learner's gradient
    function they cover every leaf of the losses' ``TensorDictParams`` and of the sampled batch (4,365 guard lines
    for the KDDRL learner's TD3 critic loss), and even with most of them skipped
    (``torch.compiler.set_stance(skip_guard_eval_unsafe=True)``) the cache lookup and the frame evaluation around
    a graph are a sizeable share of a compiled update on a CPU (``benchmarks/update_speed.py`` measures it: arm
    ``compiled_dynamo_frames``).

    Calls are told apart by ``name`` (hashable: a loss name, a tuple of modules) and the signature of the other
    arguments (every tensor's shape, strides, dtype and device, a TensorDict's keys, the items of a tuple, list or
    dict: :func:`_signature`). A signature's first ``warmup`` calls run with every guard
    (they compile its graph). The next call looks up, among TorchDynamo's cache entries of ``fn`` 's code, the one
    whose guards all pass on its arguments, as TorchDynamo would, and keeps its transformed bytecode as a plain
    function (the entry's own code, reading its graph from ``fn`` 's globals, where TorchDynamo installed it): that
    and every later call of the signature run it directly, so the graph and its results are TorchDynamo's own, bit
    for bit. A signature without such an entry, or whose entry would resume after a graph break (a resumed frame
    is compiled only under TorchDynamo), keeps calling ``fn`` with every guard, compiling what it needs. What is not
    checked any more is what a caller never changes between calls: which modules and parameters the function reads,
    their shapes, the grad mode; a graph dropped by ``torch._dynamo.reset`` is compiled again on the next call.

    Its compiling calls run in ``context()``: by default :func:`tracing_gradients` (they trace
    ``torch.autograd.grad``)."""

    def __init__(self, fn: Callable, warmup: int = 2, context: Callable = tracing_gradients):
        self.fn, self.warmup, self.context = fn, int(warmup), context
        inner = torch._dynamo.eval_frame.innermost_fn(fn)
        self._func = getattr(inner, "__func__", inner)  # the Python function TorchDynamo compiles frames of
        self._self = getattr(inner, "__self__", None)  # the object a compiled bound method is called on
        self.calls: dict = {}  # signature -> calls made with every guard
        self.direct: dict = {}  # signature -> the warm graph's function, called without TorchDynamo, or None

    def guard_every_call(self) -> WarmCompiled:
        """From now on every call runs under TorchDynamo's guards, none directly: what a benchmark or a test compares
        the direct calls with. Returns ``self``."""
        self.warmup = float("inf")
        self.direct.clear()
        return self

    def __call__(self, name: str, *args):
        try:
            key = (name, *map(_signature, args))
            hash(key)
        except TypeError:  # an argument without a cheap signature: TorchDynamo's guards decide every call
            key = None
        direct = self.direct.get(key, _UNSEEN) if key is not None else None
        if direct is _UNSEEN:  # not looked up yet: once the signature is warm, look its graph up
            direct = None
            if self.calls.get(key, 0) >= self.warmup:
                direct = self.direct[key] = self._warm_function(name, *args)
                label = name if isinstance(name, str) else type(name).__name__  # a loss name, not a members' repr
                if direct is not None:
                    log.debug("the warm compiled %s (%s): a signature called directly", self._func.__qualname__, label)
                else:
                    log.info(
                        "the warm compiled %s (%s) has no graph to call directly (a graph break, or TorchDynamo's "
                        "recompile limit reached): its calls stay under TorchDynamo",
                        self._func.__qualname__,
                        label,
                    )
        if direct is not None:
            try:
                return direct(name, *args)
            except NameError:  # torch._dynamo.reset() dropped the graph this bytecode calls: compile it again
                self.direct.clear()
                self.calls.clear()
        if key is not None:
            self.calls[key] = self.calls.get(key, 0) + 1
        with self.context():
            return self.fn(name, *args)

    def _warm_function(self, *args) -> Callable | None:
        """The transformed bytecode of the cache entry whose guards pass on ``args``, as a function of ``args``
        (None: no such entry, or one that would resume after a graph break)."""
        from torch._dynamo.eval_frame import _debug_get_cache_entry_list

        func = self._func
        bound = (self._self, *args) if self._self is not None else args
        frame_locals = dict(zip(func.__code__.co_freevars, (c.cell_contents for c in func.__closure__ or ())))
        frame_locals.update(inspect.signature(func).bind(*bound).arguments)  # the frame's locals, as guards read them
        for entry in _debug_get_cache_entry_list(func.__code__):
            if not entry.guard_manager.check(frame_locals):
                continue
            code = entry.code
            if any(n.startswith("__resume_at") for n in code.co_names) or code.co_freevars != func.__code__.co_freevars:
                return None
            direct = types.FunctionType(code, func.__globals__, func.__name__, func.__defaults__, func.__closure__)
            return types.MethodType(direct, self._self) if self._self is not None else direct
        return None


class GraphedUpdate:
    """An update function ``fn(batch) -> (losses, priority)`` replayed as a CUDA graph: tensordict's
    ``CudaGraphModule`` around ``fn`` applied to one static TensorDict, into which each call copies the sampled
    batch with one ``torch._foreach_copy_`` per dtype.

    Why not ``CudaGraphModule`` 's own TensorDict inputs: it copies an input TensorDict leaf by leaf
    (``TensorDict.update_``: one ``copy_`` launch per leaf, 26 for a KDDRL buffer-L sample), CPU time that a
    CUDA graph's replay is meant to save; here the copies are one ``_foreach_copy_`` per dtype (its one-kernel
    path takes a list of floating-point tensors of one dtype; the 10 ``bool`` / integer leaves of a buffer-L sample
    are copied one by one either way); ``gpu.final_code`` of ``benchmarks/results/gpu_update.json`` measures
    both. The graph reads the static
    TensorDict's tensors (made from the first batch, on ``device``), so every later batch must have the first
    one's batch size and keys (a sampled minibatch does; anything else is refused, naming what differs). The
    copy is queued on the stream the graph replays on, behind the previous replay: no batch is overwritten while
    a graph still reads it. ``CudaGraphModule`` runs ``warmup`` calls eagerly before it captures. ``written``: keys
    the caller sets in a batch after its update (its ``|δ|``), left out of the inputs."""

    def __init__(self, fn: Callable, device: torch.device, warmup: int = 3, written=()):
        self.fn, self.device, self.warmup = fn, torch.device(device), int(warmup)
        self.written = set(written)  # keys the caller writes into a batch after the update: never inputs
        self.static = self.keys = self.leaves = self.groups = self.graph = None

    def _capture_inputs(self, batch) -> None:
        from tensordict.nn import CudaGraphModule

        keys = sorted((k for k in batch.keys(True, True) if k not in self.written), key=str)
        self.static = batch.to(self.device).clone()
        by_dtype: dict[torch.dtype, list] = {}
        for k in keys:
            by_dtype.setdefault(self.static.get(k).dtype, []).append(k)
        self.keys = [k for ks in by_dtype.values() for k in ks]  # grouped by dtype: each group one copy call
        self.leaves = [self.static.get(k) for k in self.keys]
        ends = list(itertools.accumulate(len(ks) for ks in by_dtype.values()))
        self.groups = list(zip([0, *ends[:-1]], ends))
        self.graph = CudaGraphModule(lambda: self.fn(self.static), warmup=self.warmup, device=self.device)

    def __call__(self, batch):
        if self.static is None:
            self._capture_inputs(batch)
        elif batch.batch_size != self.static.batch_size:
            raise ValueError(
                f"a CUDA-graphed update was captured for minibatches of {tuple(self.static.batch_size)} "
                f"rows and got {tuple(batch.batch_size)}; its buffer's batch_size must not change"
            )
        sources = [batch.get(k) for k in self.keys]
        try:
            for i, j in self.groups:
                torch._foreach_copy_(self.leaves[i:j], sources[i:j], non_blocking=True)
        except TypeError:  # a key missing from the batch: its get gave None
            missing = [k for k, v in zip(self.keys, sources, strict=True) if v is None]
            if not missing:
                raise
            raise KeyError(
                f"a CUDA-graphed update was captured with the keys {self.keys}; this batch lacks {missing}"
            ) from None
        return self.graph()
