"""What drawing a minibatch from buffer L costs per update, at training's capacity and batch size, on rows with
every key the KDDRL learner stores (frames of the fake env through the transform stack and the collector, tiled
to ``--capacity``), three arms:

- ``uniform``: one ``buffer.sample()`` per update (the paper's uniform replay, drawn one minibatch at a time);
- ``uniform_grouped``: the minibatches of one collection batch (``--per-batch``, 160 = 20 frames x 8 roads at one
  update per frame) drawn as the trainer draws them, :func:`kddrl_trl.training.trainer.minibatches` (one storage
  read split into views; the same indices as the ``uniform`` arm's calls);
- ``prioritized`` (``train.prioritized``): sampling, importance weights and the priority write-back of
  :meth:`kddrl_trl.training.Trainer._update`, one minibatch per update;
- ``seeds_per_step`` and ``seeds_stacked``: a seed batch's ``[N, B]`` minibatches (``--seeds`` N buffers, each its
  own generator, ``--per-batch`` steps a collection batch), each seed's grouped draws stacked step by step
  (``seeds_per_step``, the reference) or stacked once per storage read and split by step,
  :func:`kddrl_trl.training.seed_batch_trainer.seed_minibatches` (the trainer's); seconds per seed and minibatch.

    python -m benchmarks.replay_sampling [--capacity 100000] [--batch-size 128] [--calls 480] [--seeds 8] [--repeats 3]

The arms run in one process, taking turns ``repeats`` times (a shared machine's drifts hit all alike); the table
gives the medians, ``prioritized_ratio`` = prioritized / uniform and ``grouped_ratio`` = uniform_grouped / uniform
seconds per minibatch, ``seeds_ratio`` = seeds_stacked / seeds_per_step. Where TorchRL's C++ segment
trees do not load (TorchRL 0.14.1 with torch 2.13), the prioritized arm runs on the tensor trees of
``kddrl_trl/training/priority_trees.py`` (``trees`` in the JSON). Writes ``benchmarks/results/replay_sampling.json``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch
from tensordict import TensorDict

from benchmarks.env_throughput import machine_info
from benchmarks.kddrl_parts import learner_kwargs, sample_batches
from kddrl_trl import keys as K
from kddrl_trl.training import HierarchicalLearner, make_buffer
from kddrl_trl.training.priority_trees import native_trees_available
from kddrl_trl.training.seed_batch_trainer import seed_minibatches
from kddrl_trl.training.trainer import is_prioritized, minibatches


def frame_rows(capacity: int, seed: int) -> TensorDict:
    """``capacity`` buffer-L rows with the KDDRL learner's keys (values from the fake env: only the layout and the
    copy cost matter here)."""
    learner = HierarchicalLearner(**learner_kwargs(False)[0])
    rb, _ = sample_batches(2000, seed, learner.buffer_keys())
    frames = rb[: len(rb)]
    return frames[torch.arange(capacity) % len(rb)]


def filled(rows: TensorDict, batch_size: int, prioritized: bool, seed: int):
    rb = make_buffer(rows.shape[0], batch_size, seed, prioritized=(0.6, 0.4) if prioritized else None)
    rb.extend(rows)
    return rb


def seconds_per_call(rb, calls: int, gen: torch.Generator, per_batch: int = 0) -> float:
    """Seconds per minibatch over ``calls`` minibatches: one ``sample()`` each, or (``per_batch`` > 0) drawn
    ``per_batch`` at a time by the trainer's :func:`minibatches`."""
    t0 = time.perf_counter()
    if per_batch:
        for _ in range(calls // per_batch):
            for _batch in minibatches(rb, per_batch):
                pass
        return (time.perf_counter() - t0) / (calls // per_batch * per_batch)
    for _ in range(calls):
        batch = rb.sample()
        if is_prioritized(rb):  # what the trainer does after each update
            batch.set(K.PRIORITY, torch.rand(batch.shape, generator=gen))
            rb.update_tensordict_priority(batch)
    return (time.perf_counter() - t0) / calls


def seconds_per_seed_step(buffers: list, calls: int, per_batch: int, stacked: bool) -> float:
    """Seconds per seed and minibatch over ``calls`` steps of a seed batch on ``buffers`` (one per seed),
    ``per_batch`` steps a collection batch: :func:`seed_minibatches` (``stacked``) or each seed's
    :func:`minibatches` stacked at each step."""
    n, batches = len(buffers), calls // per_batch
    t0 = time.perf_counter()
    for _ in range(batches):
        if stacked:
            for _batch in seed_minibatches(buffers, [per_batch] * n):
                pass
            continue
        draws = [minibatches(rb, per_batch) for rb in buffers]
        for _ in range(per_batch):
            torch.stack([next(d) for d in draws])
    return (time.perf_counter() - t0) / (batches * per_batch * n)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--capacity", type=int, default=100_000)
    ap.add_argument("--batch-size", type=int, default=128)
    ap.add_argument("--calls", type=int, default=480)
    ap.add_argument("--per-batch", type=int, default=160, help="minibatches per collection batch (grouped arm)")
    ap.add_argument("--seeds", type=int, default=8, help="seeds N of the seed-batch arms (their N buffers)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--note", default="", help="what the machine was doing, in words")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "replay_sampling.json"))
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    gen = torch.Generator().manual_seed(args.seed)
    rows = frame_rows(args.capacity, args.seed)
    buffers = {
        name: filled(rows, args.batch_size, name == "prioritized", args.seed)
        for name in ("uniform", "uniform_grouped", "prioritized")
    }
    seeds = [filled(rows, args.batch_size, False, args.seed + 1 + i) for i in range(args.seeds)]
    per_batch = {"uniform_grouped": args.per_batch}
    arms = {
        **{
            name: lambda calls, rb=rb, name=name: seconds_per_call(rb, calls, gen, per_batch.get(name, 0))
            for name, rb in buffers.items()
        },
        "seeds_per_step": lambda calls: seconds_per_seed_step(seeds, calls, args.per_batch, stacked=False),
        "seeds_stacked": lambda calls: seconds_per_seed_step(seeds, calls, args.per_batch, stacked=True),
    }
    for arm in arms.values():
        arm(2 * args.per_batch)  # warm-up
    turns = {name: [] for name in arms}
    for _ in range(args.repeats):
        for name, arm in arms.items():
            turns[name].append(arm(args.calls))
    med = {name: statistics.median(v) for name, v in turns.items()}
    result = {
        "args": vars(args),
        "trees": "torchrl" if native_trees_available() else "tensor",
        "machine": machine_info(),
        "ms_per_call": {k: 1e3 * v for k, v in med.items()},
        "turns_ms": {k: [1e3 * x for x in v] for k, v in turns.items()},
        "prioritized_ratio": med["prioritized"] / med["uniform"],
        "grouped_ratio": med["uniform_grouped"] / med["uniform"],
        "seeds_ratio": med["seeds_stacked"] / med["seeds_per_step"],
        "row_leaves": len(rows.keys(True, True)),
    }
    print(f"{'arm':<18}{'ms per minibatch':>17}")
    for name, v in med.items():
        print(f"{name:<18}{1e3 * v:>17.3f}")
    print(f"prioritized / uniform: {result['prioritized_ratio']:.2f}  (trees: {result['trees']})")
    print(f"uniform_grouped / uniform: {result['grouped_ratio']:.2f}  ({result['row_leaves']} tensors a row)")
    print(f"seeds_stacked / seeds_per_step: {result['seeds_ratio']:.2f}  ({args.seeds} seeds, ms per seed)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
