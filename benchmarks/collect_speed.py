"""How fast training collects: frames/s of ``SumoHighwayEnv`` + the full transform stack (as configured for training
in ``conf/algo/kddrl.yaml`` and ``compile`` of ``conf/config.yaml``) + the decision clock + both exploring policies
through :class:`kddrl_trl.collectors.MultiTimescaleCollector` (writing both replay buffers), against the libsumo limit
of ``benchmarks/env_throughput.py`` measured in the same run at the same K: ``collect_ratio_vs_sim`` (goal >= 0.5).
The limit includes the env's own observation building, so making that cheaper raises both numbers and *lowers* the
ratio: compare ``collect_fps`` too. ``breakdown``: where a collection step's time goes.

- ``--collect-direct-gain N``: the same collection with the compiled stack's every call under TorchDynamo's guards
  instead of its warm graph called directly, N turns each: ``collect_direct_gain``, the median of fps(direct) /
  fps(guarded).
- ``--workers 1,2``: the collection at K = ``--workers-roads`` with N env processes (``collector.workers=N``), the
  learner's weights synced after every batch as in training: ``collect_scaling[N]`` = fps(N) / (N x fps(1)).
- ``--learner-gain``: also the learner's update (:func:`benchmarks.update_speed.measure_update`), and
  ``learner_compile_gain``: the share of the training wall time per ego-frame that compiling the learner saves.

    python -m benchmarks.collect_speed [--roads 8 32] [--frames 4000] [--clock wall|cpu] [--workers 1,2]

Prints a table and writes ``benchmarks/results/collect_speed.json``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from benchmarks.env_throughput import machine_info, measure_sim, write_json
from benchmarks.kddrl_parts import (
    FRAMES_PER_ENV,
    RESULTS,
    collect_env,
    learner_kwargs,
)
from benchmarks.update_speed import measure_update
from kddrl_trl.collectors import MultiTimescaleCollector
from kddrl_trl.collectors.workers import WorkerEnv
from kddrl_trl.compiling import resolve_compile
from kddrl_trl.process_settings import apply_flush_denormal
from kddrl_trl.protocol import worker_seed
from kddrl_trl.training import HierarchicalLearner, make_buffer
from kddrl_trl.transforms import (
    PredictiveStack,
)
from kddrl_trl.transforms.stack import warm_frames

CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


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


def learner_compile_gain(update: dict, collect_fps: float) -> float:
    """Share of the training wall time per ego-frame (collection + the eager learner's updates) that the
    compiled learner saves."""
    eager, compiled = update["eager"]["per_frame_s"], update["compiled"]["per_frame_s"]
    return (eager - compiled) / (1.0 / collect_fps + eager)


#: keys of the results file that describe a run rather than hold a measurement


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--roads", type=int, nargs="+", default=[8, 32])
    p.add_argument("--frames", type=int, default=4000, help="ego-frames timed for collection")
    p.add_argument(
        "--clock",
        choices=sorted(CLOCKS),
        default="wall",
        help="collection timing: wall seconds, or CPU seconds of this process (a shared machine)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--collect-direct-gain", type=int, default=0, metavar="N", help="turns of the guarded-call arm")
    p.add_argument("--workers", default="", help="comma-separated worker counts, e.g. 1,2 (1 must be in)")
    p.add_argument("--workers-roads", type=int, default=8, help="--workers: roads per worker")
    p.add_argument("--skip-collect", action="store_true", help="only --workers")
    p.add_argument("--learner-gain", action="store_true", help="also time the learner: learner_compile_gain")
    p.add_argument(
        "--compile", default=None, choices=["auto", "true", "false"], help="the stack's compile (default: conf's)"
    )
    p.add_argument("--note", default=None, help="free text stored in the JSON")
    p.add_argument("--out", type=Path, default=RESULTS / "collect_speed.json")
    args = p.parse_args(argv)
    compile = None if args.compile is None else resolve_compile(args.compile)
    apply_flush_denormal(True)
    update = measure_update(200, args.seed, 3, torch.device("cpu")) if args.learner_gain else None
    torch.set_num_threads(1)  # the env and the acting policy: single-threaded, as in training
    collect = (
        []
        if args.skip_collect
        else [measure_collect(k, args.frames, args.seed, args.clock, compile) for k in args.roads]
    )
    for c in collect:
        if args.collect_direct_gain:  # the same collection without the direct calls, in turns
            turns = []
            for _ in range(args.collect_direct_gain):
                on = measure_collect(c["num_roads"], args.frames, args.seed, args.clock, compile)["collect_fps"]
                off = measure_collect(c["num_roads"], args.frames, args.seed, args.clock, compile, False)
                turns.append((on, off))
            c["collect_fps_direct"] = [on for on, _ in turns]
            c["collect_fps_not_direct"] = [off["collect_fps"] for _, off in turns]
            c["breakdown_not_direct"] = turns[-1][1]["breakdown"]
            c["collect_direct_gain"] = statistics.median(on / off["collect_fps"] for on, off in turns)
        if update is not None:
            c["learner_compile_gain"] = learner_compile_gain(update, c["collect_fps"])
    result = {"args": {k: str(v) for k, v in vars(args).items()}, "machine": machine_info(), "collect": collect}
    if collect:
        result["collect_ratio_vs_sim"] = min(c["collect_ratio_vs_sim"] for c in collect)
    if args.workers:
        workers = measure_collect_workers(
            args.workers_roads, [int(n) for n in args.workers.split(",")], args.frames, args.seed, compile
        )
        result["collect_workers"], result["collect_scaling"] = workers["runs"], workers["collect_scaling"]
    if args.note:
        result["note"] = args.note
    if collect:
        print(
            f"\n{'collection (SUMO + stack + policies)':<38}{'K':>3}{'sim limit fps':>15}{'collect fps':>13}"
            f"{'ratio':>8}{'compiled learner saves':>24}"
        )
    for c in collect:
        gain = f"{100 * c['learner_compile_gain']:>17.1f}% of wall" if "learner_compile_gain" in c else ""
        print(
            f"{'':<38}{c['num_roads']:>3}{c['sim_limit_fps']:>15.0f}{c['collect_fps']:>13.0f}"
            f"{c['collect_ratio_vs_sim']:>8.2f}{gain}"
        )
    for c in collect:
        print(f"\n{'collection, per env step, K = ' + str(c['num_roads']):<38}{'ms':>8}{'share':>8}")
        for name, ms in c["breakdown"]["ms_per_env_step"].items():
            print(f"{'  ' + name:<38}{ms:>8.2f}{100 * c['breakdown']['share'][name]:>7.1f}%")
    for r in result.get("collect_workers", []):
        print(
            f"workers {r['workers']}, K {r['num_roads']}: {r['collect_fps']:.0f} fps, scaling "
            f"{result['collect_scaling'][str(r['workers'])]:.2f}"
        )
    write_json(args.out, result)
    print(f"\nwritten {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
