"""What prioritized replay (``train.prioritized``) costs per update: one minibatch drawn from buffer L, uniform
against prioritized (sampling, importance weights and the priority write-back of
:meth:`kddrl_trl.training.Trainer._update`), at training's capacity and batch size.

    python benchmarks/replay_sampling.py [--capacity 100000] [--batch-size 128] [--calls 500] [--repeats 3]

Both arms run in one process, taking turns ``repeats`` times (a shared machine's drifts hit both alike); the table
gives the medians and ``prioritized_ratio`` = prioritized / uniform seconds per call. Where TorchRL's C++ segment
trees do not load (TorchRL 0.14.1 with torch 2.13), the prioritized arm runs on the tensor trees of
``kddrl_trl/training/priority_trees.py`` (``trees`` in the JSON). Writes ``benchmarks/results/replay_sampling.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import torch
from tensordict import TensorDict

from kddrl_trl import keys as K
from kddrl_trl.training import make_buffer
from kddrl_trl.training.priority_trees import native_trees_available
from kddrl_trl.training.trainer import is_prioritized

#: a stored frame's size: ~40 floats of state per side, as buffer L's rows (only the copy cost matters here)
ROW = 40


def filled(capacity: int, batch_size: int, prioritized: bool, seed: int):
    rb = make_buffer(capacity, batch_size, seed, prioritized=(0.6, 0.4) if prioritized else None)
    rb.extend(TensorDict({"obs": torch.randn(capacity, ROW), "next": {"obs": torch.randn(capacity, ROW)}},
                         [capacity]))
    return rb


def seconds_per_call(rb, calls: int, gen: torch.Generator) -> float:
    t0 = time.perf_counter()
    for _ in range(calls):
        batch = rb.sample()
        if is_prioritized(rb):  # what the trainer does after each update
            batch.set(K.PRIORITY, torch.rand(batch.shape, generator=gen))
            rb.update_tensordict_priority(batch)
    return (time.perf_counter() - t0) / calls


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--capacity", type=int, default=100_000)
    ap.add_argument("--batch-size", type=int, default=128)
    ap.add_argument("--calls", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "replay_sampling.json"))
    args = ap.parse_args()
    torch.set_num_threads(1)
    gen = torch.Generator().manual_seed(args.seed)
    buffers = {name: filled(args.capacity, args.batch_size, name == "prioritized", args.seed)
               for name in ("uniform", "prioritized")}
    for rb in buffers.values():
        seconds_per_call(rb, 20, gen)  # warm-up
    turns = {name: [] for name in buffers}
    for _ in range(args.repeats):
        for name, rb in buffers.items():
            turns[name].append(seconds_per_call(rb, args.calls, gen))
    med = {name: statistics.median(v) for name, v in turns.items()}
    result = {"args": vars(args), "trees": "torchrl" if native_trees_available() else "tensor",
              "machine": {"platform": platform.platform(), "python": platform.python_version(),
                          "torch": torch.__version__, "cpu_count": os.cpu_count()},
              "ms_per_call": {k: 1e3 * v for k, v in med.items()}, "turns_ms": {k: [1e3 * x for x in v]
                                                                            for k, v in turns.items()},
              "prioritized_ratio": med["prioritized"] / med["uniform"]}
    print(f"{'arm':<14}{'ms per call':>12}")
    for name, v in med.items():
        print(f"{name:<14}{1e3 * v:>12.3f}")
    print(f"prioritized / uniform: {result['prioritized_ratio']:.2f}  (trees: {result['trees']})")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
