"""How far the learner's update is from its compute floor: the update's FLOPs (``torch.utils.flop_counter``) over the
FP32 GEMM rate at its shapes, per thread count; our compiled update's and the plain reference's time per TD3 / D3QN
update over that floor (both measured in this run by :func:`benchmarks.update_speed.measure_update`); the update's
own GEMMs as they run inside it (their self time under ``torch.profiler``); and our update in parts (gradients,
optimiser, soft updates, the rest).

    python -m benchmarks.update_floor [--updates 200] [--repeats 3] [--floor-threads 1 2]

Prints a table and writes ``benchmarks/results/update_floor.json``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import torch

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.kddrl_parts import (
    RESULTS,
    arm_learner,
    buffer_keys,
    learner_kwargs,
    sample_batches,
    stacked,
    unprioritized,
)
from benchmarks.update_speed import measure_update, python_wrapper
from kddrl_trl.devtools.plain_kddrl import PlainKDDRL, tensors
from kddrl_trl.process_settings import apply_flush_denormal
from kddrl_trl.training import HierarchicalLearner


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


def gemm_in_update(seed: int, buffers: tuple, updates: int = 100, seeds: int | None = None) -> dict:
    """Seconds per TD3 / D3QN update spent in the update's own matrix products, as they run inside our compiled
    update: the self time of its GEMM calls (:data:`GEMM_OPS`) under ``torch.profiler`` over ``updates`` updates.
    The loss is compiled with TorchInductor's Python wrapper (:func:`python_wrapper`: the same kernels, and its
    GEMMs are ATen calls the profiler sees; the C++ wrapper calls them past the profiler), on samples of
    ``buffers`` (:func:`sample_batches`' two). Against the floor this says how much of the gap is the products
    themselves (the floor's loop runs one product back to back; inside the update each follows other work) and how
    much is everything else. ``seeds``: the same of a batch of that many seeds (:func:`~benchmarks.kddrl_parts.arm_learner`), each
    update on one independent sample per seed (:func:`~benchmarks.kddrl_parts.stacked`), the time the whole batch's.
    """
    from torch.profiler import ProfilerActivity, profile

    torch.manual_seed(seed)
    learner = arm_learner(seeds, compiled=True)
    python_wrapper(learner)
    rb_cf, rb_lc = buffers
    out = {}
    for agent, update, rb in (("td3", learner.update_cf, rb_cf), ("d3qn", learner.update_lc, rb_lc)):
        batches = stacked(rb, seeds, updates)
        for b in batches[:10]:
            update(b)
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            for b in batches:
                update(b)
        gemm_us = sum(e.self_cpu_time_total for e in prof.key_averages() if e.key in GEMM_OPS)
        out[f"{agent}_gemm_in_update_s"] = 1e-6 * gemm_us / updates
    return out


def update_parts(seed: int, buffers: tuple, updates: int = 400, passes: int = 3, seeds: int | None = None) -> dict:
    """Seconds per TD3 / D3QN update in each part of our compiled update as training runs it (the C++ wrapper, warm
    graphs called directly, ``flush_denormal`` on as every job sets it): the loss-and-gradients graph
    (``Learner._gradients``), the optimiser steps (``step_all``), the soft target updates, and the rest (Python,
    TensorDict, the priorities), each the median over ``passes`` passes of ``updates`` updates on samples of
    ``buffers``. With :func:`gemm_in_update` this bounds the update as it is built: the products at their speed inside
    it, the optimiser steps and the soft updates (each reads and writes all of its tensors) take
    ``*_bound_over_floor`` of the floor before the graphs' other kernels and the rest add anything. ``seeds``: the
    same of a batch of that many seeds, as :func:`gemm_in_update` takes it."""
    from kddrl_trl.training import learner as base  # the module whose step_all the learner calls

    torch.manual_seed(seed)
    learner = arm_learner(seeds, compiled=True)
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
            batches = stacked(rb, seeds, updates)
            for b in unprioritized(batches)[:20]:
                update(b)
            runs = []
            for _ in range(passes):
                acc.update(dict.fromkeys(acc, 0.0))
                t0 = time.perf_counter()
                for b in unprioritized(batches):
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


def print_floor(floor: dict) -> None:
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
    print(f"\n{'GEMMs inside our update':<34}{'ms':>8}{'÷ floor':>10}{'share of update':>17}")
    for agent in ("td3", "d3qn"):
        share = floor.get(f"{agent}_gemm_share_of_update")
        print(
            f"{agent:<34}{1e3 * floor[f'{agent}_gemm_in_update_s']:>8.3f}"
            f"{floor[f'{agent}_gemm_in_update_over_floor']:>10.2f}"
            + (f"{100 * share:>16.0f}%" if share is not None else "")
        )
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


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--updates", type=int, default=200, help="TD3 updates timed per repeat")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--floor-threads", type=int, nargs="+", default=[1, 2], help="GEMM rates at these thread counts")
    p.add_argument(
        "--update-threads", type=int, default=len(os.sched_getaffinity(0)), help="torch threads of the updates"
    )
    p.add_argument("--note", default=None, help="free text stored in the JSON")
    p.add_argument("--out", type=Path, default=RESULTS / "update_floor.json")
    args = p.parse_args(argv)
    apply_flush_denormal(True)
    torch.set_num_threads(args.update_threads)
    update = measure_update(args.updates, args.seed, args.repeats)
    update["torch_threads"] = torch.get_num_threads()
    floor = measure_floor(update, args.seed, args.floor_threads)
    result = {"args": {k: str(v) for k, v in vars(args).items()}, "machine": machine_info(), "update": update}
    result["floor"] = floor
    if args.note:
        result["note"] = args.note
    print_floor(floor)
    write_json(args.out, result)
    print(f"\nwritten {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
