"""How fast the learner updates, per collected frame: one TD3 update (critic every update; actor and soft target
updates every ``policy_delay``) plus 1/``lc_period`` of a D3QN update (one per decision) of
:class:`kddrl_trl.training.HierarchicalLearner` (TorchRL ``TD3Loss`` / ``DQNLoss`` / ``SoftUpdate``, TensorDict
states, shared embedding), eager and compiled (``compile=True``: the learner's one compile site), against a
**plain-PyTorch reference** with the same network modules, the same batches and the same arithmetic
(:class:`~kddrl_trl.devtools.plain_kddrl.PlainKDDRL`, proved equal by ``tests/training/test_learner_update.py``).
The arms take turns ``--repeats`` times on the same batches; replay sampling is outside the timed part.

- ``update_ratio_vs_plain`` = plain time / ours (>= 1.0: TorchRL costs nothing extra), and against the eager arm.
- What each compile choice earns, each against the compiled arm in the same run (> 1.0: a gain):
  ``cpp_wrapper_gain`` (TorchInductor's Python wrapper instead of the C++ one), ``size_asserts_gain`` (the size
  asserts :func:`kddrl_trl.compiling.inductor_options` drops), ``direct_call_gain`` (the graphs through TorchDynamo's
  frame evaluation instead of called directly, :class:`kddrl_trl.compiling.WarmCompiled`), ``lean_adam_gain``
  (``torch.optim.Adam(fused=True)`` stepped one by one instead of :func:`kddrl_trl.training.adam.step_all`).
- Each compiling arm records what TorchDynamo compiled in its first pass (``compiles``: per graph the seconds of the
  whole compile, of its backend and of TorchDynamo's tracing), a training process's fixed cost.

    python -m benchmarks.update_speed [--updates 200] [--repeats 3] [--update-threads N]

Prints a table and writes ``benchmarks/results/update_speed.json``. The GPU arm is ``benchmarks/gpu_update.py``, the
compute floor ``benchmarks/update_floor.py``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import torch
from torch._dynamo.utils import clear_compilation_metrics, get_compilation_metrics

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.kddrl_parts import (
    RESULTS,
    learner_kwargs,
    sample_batches,
    time_updates,
)
from kddrl_trl.compiling import inductor_options, tracing_gradients
from kddrl_trl.devtools.plain_kddrl import PlainKDDRL, tensors
from kddrl_trl.process_settings import apply_flush_denormal
from kddrl_trl.training import HierarchicalLearner
from kddrl_trl.training.learner import adam


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


def print_update(update: dict) -> None:
    print(
        f"\n{'learner (per collected frame)':<34}{'TD3 upd/s':>10}{'D3QN upd/s':>11}{'frame cost ms':>14}"
        f"{'ratio vs plain':>15}"
    )
    print(f"(device {update['device']})")
    arms = ("plain", "eager", "compiled", "compiled_python_wrapper", "compiled_size_asserts", "compiled_cpu_batches")
    for name in [n for n in arms if n in update]:
        r = update[name]
        print(
            f"{name:<34}{1 / r['td3_update_s']:>10.0f}{1 / r['d3qn_update_s']:>11.0f}"
            f"{1e3 * r['per_frame_s']:>14.2f}{update['plain']['per_frame_s'] / r['per_frame_s']:>15.2f}"
        )


#: arm -> the ratio it gives against the compiled arm (> 1.0: what the compiled arm's choice earns)
GAINS = {
    "compiled_python_wrapper": "cpp_wrapper_gain",
    "compiled_size_asserts": "size_asserts_gain",
    "compiled_torch_adam": "lean_adam_gain",
    "compiled_dynamo_frames": "direct_call_gain",
}


def ratios(update: dict) -> dict:
    """The ratios of one run's arms: ours against the plain reference, and what each compile choice earns."""
    per_frame = {
        name: arm["per_frame_s"] for name, arm in update.items() if isinstance(arm, dict) and "per_frame_s" in arm
    }
    out = {
        "update_ratio_vs_plain": per_frame["plain"] / per_frame["compiled"],
        "update_ratio_vs_plain_eager": per_frame["plain"] / per_frame["eager"],
    }
    out.update({gain: per_frame[arm] / per_frame["compiled"] for arm, gain in GAINS.items() if arm in per_frame})
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--updates", type=int, default=200, help="TD3 updates timed per repeat")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch-size-cf", type=int, default=None, help="TD3 minibatch (default: training's 128)")
    p.add_argument(
        "--update-threads",
        type=int,
        default=len(os.sched_getaffinity(0)),
        help="torch threads of the updates (default: the cores, torch's default and so training's)",
    )
    p.add_argument("--note", default=None, help="free text stored in the JSON")
    p.add_argument("--out", type=Path, default=RESULTS / "update_speed.json")
    args = p.parse_args(argv)
    apply_flush_denormal(True)  # as every job sets it by default (``flush_denormal``), for every arm alike
    torch.set_num_threads(args.update_threads)
    update = measure_update(args.updates, args.seed, args.repeats, torch.device("cpu"), args.batch_size_cf)
    update["torch_threads"] = torch.get_num_threads()
    result = {"args": {k: str(v) for k, v in vars(args).items()}, "machine": machine_info(), "update": update}
    result.update(ratios(update))
    if args.note:
        result["note"] = args.note
    print_update(update)
    print("\n" + "\n".join(f"{k:<34}{v:>10.3f}" for k, v in ratios(update).items()))
    write_json(args.out, result)
    print(f"\nwritten {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
