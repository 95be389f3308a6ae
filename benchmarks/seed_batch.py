"""Per-seed cost of the learner's update when N seeds train as one batch (``seeds=N``,
:mod:`kddrl_trl.modules.seed_batch`), against one seed's learner alone and against the GEMM floor, measured in one
run: for each N, the TD3 and D3QN updates of the default KDDRL learner on N independent minibatches at once, eager
and compiled, the arms taking turns ``repeats`` times (medians over the turns).

    python -m benchmarks.seed_batch [--seeds 1 2 4 8 16] [--updates 200] [--repeats 3] [--threads 2]
    python -m benchmarks.seed_batch --device cuda --seeds 1 4 16 64 256   # a GPU: compiled arms CUDA-graphed
    python -m benchmarks.seed_batch --seeds 1 16 --split 1 16             # and where a compiled update's time goes

Prints a table and writes ``benchmarks/results/seed_batch.json``. ``per_seed_over_single``: seconds per update per
seed over the single learner's (``seeds`` unset) in the same arm; ``per_seed_over_floor``: over one seed's update
FLOPs at the machine's GEMM rate (:mod:`benchmarks.update_floor`). ``--split``: for those N (1: the single learner),
the compiled TD3 update's time per seed in its parts, over the same floor (``split``): its matrix products as they
run inside it (``gemm_in_update``), the loss-and-gradients graph, the optimiser steps, the soft target updates and
the rest (``update_parts``); what stands between the batch and the floor.
"""

from __future__ import annotations

import argparse
import os
import statistics
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
    time_updates,
)
from benchmarks.update_floor import gemm_in_update, gemm_rate, update_flops, update_parts
from kddrl_trl.process_settings import apply_flush_denormal


def measure(
    seeds: list[int],
    updates: int,
    repeats: int,
    buffers: tuple,
    compiled_arms: bool = True,
    device: torch.device = torch.device("cpu"),
) -> dict:
    """Seconds per TD3 / D3QN update (whole batch) of each arm: ``single`` and ``seeds_<N>``, eager and (with
    ``compiled_arms``) compiled, on minibatches of ``buffers`` (:func:`~benchmarks.kddrl_parts.sample_batches`' two)
    moved to ``device`` beforehand, as the learner's buffers sample them."""
    rb_cf, rb_lc = buffers
    lc_period = learner_kwargs(False)[1]
    arms = {}
    for compiled in (False, True) if compiled_arms else (False,):
        for n in (None, *seeds):
            name = f"{'compiled' if compiled else 'eager'}/{'single' if n is None else f'seeds_{n}'}"
            learner = arm_learner(n, compiled, device)
            cf = [b.to(device) for b in stacked(rb_cf, n, updates)]
            lc = [b.to(device) for b in stacked(rb_lc, n, max(updates // 4, 10))]
            arms[name] = (n or 1, learner.update_cf, learner.update_lc, cf, lc)
    runs = {name: [] for name in arms}
    for _ in range(repeats):
        for name, (_, update_cf, update_lc, cf, lc) in arms.items():
            runs[name].append(time_updates(update_cf, update_lc, cf, lc, lc_period, device))
    rows = {}
    for name, (n, *_rest) in arms.items():
        td3 = statistics.median(r[0] for r in runs[name])
        d3qn = statistics.median(r[1] for r in runs[name])
        rows[name] = {"seeds": n, "td3_update_s": td3, "d3qn_update_s": d3qn, "td3_per_seed_s": td3 / n,
                      "d3qn_per_seed_s": d3qn / n}  # fmt: skip
    return rows


def ratios(rows: dict, floor: dict | None) -> None:
    """Adds to each row its per-seed time over the same arm's single learner and over the floor (in place)."""
    for name, row in rows.items():
        single = rows[name.split("/")[0] + "/single"]
        for agent in ("td3", "d3qn"):
            row[f"{agent}_per_seed_over_single"] = row[f"{agent}_per_seed_s"] / single[f"{agent}_per_seed_s"]
            if floor is not None:
                row[f"{agent}_per_seed_over_floor"] = row[f"{agent}_per_seed_s"] / floor[f"{agent}_floor_s"]


def print_table(rows: dict, floor: dict | None) -> None:
    said = (
        ""
        if floor is None
        else f"   floor: TD3 {1e3 * floor['td3_floor_s']:.3f} ms, D3QN {1e3 * floor['d3qn_floor_s']:.3f} ms"
    )
    print(f"\n{'arm':<22}{'TD3 ms/seed':>12}{'÷ single':>10}{'÷ floor':>9}{'D3QN ms/seed':>14}{'÷ single':>10}{said}")
    for name, r in rows.items():
        over = r.get("td3_per_seed_over_floor")
        print(
            f"{name:<22}{1e3 * r['td3_per_seed_s']:>12.3f}{r['td3_per_seed_over_single']:>10.2f}"
            f"{'-' if over is None else f'{over:.2f}':>9}{1e3 * r['d3qn_per_seed_s']:>14.3f}"
            f"{r['d3qn_per_seed_over_single']:>10.2f}"
        )


def split_update(n: int, seed: int, buffers: tuple, floor: dict, updates: int = 200) -> dict:
    """Seconds per seed of the compiled TD3 update of a batch of ``n`` seeds (1: the single learner) in its parts,
    each also over the floor (``*_over_floor``): ``gemm`` (its products' self time under the profiler) and the
    wall-clock parts ``gradients``, ``optimizer``, ``soft``, ``rest`` and ``total``."""
    seeds = None if n == 1 else n
    gemm = gemm_in_update(seed, buffers, max(updates // 2, 1), seeds=seeds)["td3_gemm_in_update_s"] / n
    parts = {k: v / n for k, v in update_parts(seed, buffers, updates, seeds=seeds)["td3_parts_s"].items()}
    row = {"gemm": gemm, **parts}
    return {**row, **{f"{k}_over_floor": v / floor["td3_floor_s"] for k, v in row.items()}}


def print_split(split: dict) -> None:
    names = ("gemm", "gradients", "optimizer", "soft", "rest", "total")
    print("\ncompiled TD3 update per seed, x floor: " + "  ".join(f"{k:>9}" for k in names))
    for n, row in split.items():
        print(f"{'N = ' + n:<40}" + "  ".join(f"{row[k + '_over_floor']:>9.2f}" for k in names))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 4, 8, 16], help="batch sizes N to measure")
    p.add_argument("--updates", type=int, default=200, help="TD3 updates timed per arm and repeat")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)), help="torch threads")
    p.add_argument("--eager-only", action="store_true", help="skip the compiled arms")
    p.add_argument(
        "--device", default="cpu", help="cpu or cuda (the floor is then the CPU's: read the per-seed ratios)"
    )
    p.add_argument("--split", type=int, nargs="*", default=[], help="N whose compiled TD3 update is split in parts")
    p.add_argument("--note", default=None, help="free text stored in the JSON")
    p.add_argument("--out", type=Path, default=RESULTS / "seed_batch.json")
    args = p.parse_args(argv)
    if args.split and args.device != "cpu":
        p.error(f"--split measures against the CPU's GEMM floor: it needs --device cpu, got --device {args.device}")
    apply_flush_denormal(True)
    torch.set_num_threads(args.threads)
    # every arm's learner compiles the same gradient function at its own shapes (3 graphs each), all kept warm to
    # take turns: past TorchDynamo's default of 8 graphs per code object the later arms would run eagerly
    torch._dynamo.config.recompile_limit = 8 * (len(args.seeds) + 1)
    device = torch.device(args.device)
    torch.manual_seed(args.seed)
    buffers = sample_batches(4000, args.seed, buffer_keys())
    rows = measure(args.seeds, args.updates, args.repeats, buffers, compiled_arms=not args.eager_only, device=device)
    floor = None  # the CPU's GEMM floor; a GPU's tiny products are launch-bound, its figure is the per-seed cost
    if device.type == "cpu":
        flops = update_flops(args.seed, buffers)
        rate = gemm_rate(args.threads)
        floor = {**flops, "gemm_flop_per_s": rate, **{f"{a}_floor_s": flops[f"{a}_flops_per_update"] / rate
                                                       for a in ("td3", "d3qn")}}  # fmt: skip
    ratios(rows, floor)
    print_table(rows, floor)
    split = {str(n): split_update(n, args.seed, buffers, floor, args.updates) for n in args.split}
    if split:
        print_split(split)
    result = {"args": {k: str(v) for k, v in vars(args).items()}, "machine": machine_info(), "floor": floor,
              "arms": rows, **({"split": split} if split else {}), **({"note": args.note} if args.note else {})}  # fmt: skip
    write_json(args.out, result)
    print(f"\nwritten {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
