"""Whether fewer gradient graphs would cut a process's compile bill: the KDDRL learner's three gradient graphs as
training compiles them (``Learner._gradients`` per loss: the TD3 critic, the TD3 actor and the D3QN, one graph
each), against one graph that computes all three gradient sets in one call.

    python -m benchmarks.compile_graphs [--rounds 2]

The merged graph is a bound, not an update training could use: TD3's actor step reads the critic *after* the
critic's optimiser step, and the D3QN step reads the embedding after the critic step moved it (Algorithm 1), so the
three gradients of one training step cannot be computed from one parameter state; merging them keeps the losses of
TorchRL as they are and only removes the graph boundaries between them. If even this bound saves little, no
reorganisation of the graphs that keeps the update can save more, since it traces the same losses.

Each arm runs in a fresh process, one torch thread, first with an empty TorchInductor cache (cold: tracing, lowering
and code generation), then again with the cache it filled (warm: what a sweep's later jobs pay; TorchDynamo traces
again, the FX-graph and AOTAutograd caches serve the rest). The arms alternate (three, one, three, one, ...). Each
records the compile seconds of the process (``kddrl_trl.compiling.compile_seconds``), what it compiled and what the
caches served (``compile_counts``), and the largest difference of its actor and D3QN losses and gradients from the
eager ones, relative to each tensor's largest magnitude (both arms compute the same numbers up to the fused kernels'
rounding; the critic's loss draws TD3's target noise afresh on every call, so it is left out of the comparison).
Alone on the machine: pause other work (``kill -STOP``) for the window.

Prints a table and writes ``benchmarks/results/compile_graphs.json`` with the ratios one / three of the compile
seconds, cold and warm.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.kddrl_parts import RESULTS, buffer_keys, learner_kwargs, sample_batches
from kddrl_trl.compiling import compile_counts, compile_seconds, fresh_compiler, inductor_options, tracing_gradients
from kddrl_trl.training import HierarchicalLearner

ARMS = ("three", "one")
NAMES = ("cf_value", "cf_actor", "lc")  # the learner's gradient graphs (HierarchicalLearner.loss)


def child(arm: str) -> dict:
    """In this process: the learner of ``conf/algo/kddrl.yaml``, eager, with one sample of each buffer; the arm's
    compiled gradients of the three losses; its compile seconds and counts, and its largest deviation from eager."""
    torch.manual_seed(0)
    rb_cf, rb_lc = sample_batches(2_000, 0, buffer_keys())
    learner = HierarchicalLearner(**learner_kwargs(False)[0])
    learner.update_cf(rb_cf.sample())  # eager steps: each loss's trained parameters are known (Learner._descend)
    learner.update_cf(rb_cf.sample())
    learner.update_lc(rb_lc.sample())
    cf, lc = rb_cf.sample(), rb_lc.sample()
    batches = {"cf_value": cf, "cf_actor": cf, "lc": lc}

    def all_gradients(cf, lc):
        return tuple(learner._gradients(name, cf if name != "lc" else lc) for name in NAMES)

    eager = all_gradients(cf, lc)
    fresh_compiler()
    options = inductor_options("cpu")
    with tracing_gradients():
        if arm == "three":
            fn = torch.compile(learner._gradients, dynamic=False, options=options)
            compiled = tuple(fn(name, batches[name]) for name in NAMES)
        else:
            compiled = torch.compile(all_gradients, dynamic=False, options=options)(cf, lc)

    def leaves(out):  # the deterministic losses' outputs: the TD3 critic's target noise is a fresh draw per call
        return [t for name, (loss, prio, grads) in zip(NAMES, out) if name != "cf_value" for t in (loss, prio, *grads)]

    pairs = [(a, b) for a, b in zip(leaves(eager), leaves(compiled), strict=True) if a is not None]
    deviation = max(float(((a - b).abs() / a.abs().max().clamp_min(1e-12)).max()) for a, b in pairs)
    return {"compile_s": compile_seconds(), "compile_counts": compile_counts(), "max_rel_deviation": deviation}


def run_arm(arm: str, cache: Path) -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "TORCHINDUCTOR_CACHE_DIR": str(cache)}
    cmd = [sys.executable, "-m", "benchmarks.compile_graphs", "--child", arm]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> dict | None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=2, help="rounds of the two arms, each cold then warm")
    parser.add_argument("--out", type=Path, default=RESULTS / "compile_graphs.json")
    parser.add_argument("--note", default="", help="what the machine was doing, in words")
    parser.add_argument("--child", choices=ARMS, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child)))
        return None
    if args.rounds < 1:
        parser.error(f"--rounds must be >= 1, got {args.rounds}")
    work = Path(tempfile.mkdtemp(prefix="kddrl_trl_compile_graphs_"))
    runs = []
    try:
        for round_ in range(args.rounds):
            for arm in ARMS:
                cache = work / f"{arm}{round_}"
                for state in ("cold", "warm"):  # cold empties nothing: each arm and round has a cache of its own
                    runs.append({"arm": arm, "round": round_, "cache": state, **run_arm(arm, cache)})
                    print(f"  {arm:5s} round {round_} {state}: {runs[-1]['compile_s']:.1f} s", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)

    def median(arm: str, state: str) -> float:
        return statistics.median(r["compile_s"] for r in runs if r["arm"] == arm and r["cache"] == state)

    summary = {f"{arm}_{state}_s": median(arm, state) for arm in ARMS for state in ("cold", "warm")} | {
        f"one_over_three_{state}": median("one", state) / median("three", state) for state in ("cold", "warm")
    }
    payload = {
        "command": " ".join(["python -m benchmarks.compile_graphs", *(argv or sys.argv[1:])]),
        "machine": machine_info(),
        "note": args.note,
        "runs": runs,
        "summary": summary,
    }
    print(f"{'arm':6s} {'cold s':>8s} {'warm s':>8s}")
    for arm in ARMS:
        print(f"{arm:6s} {summary[f'{arm}_cold_s']:8.1f} {summary[f'{arm}_warm_s']:8.1f}")
    print(f"one / three: cold {summary['one_over_three_cold']:.2f}, warm {summary['one_over_three_warm']:.2f}")
    write_json(args.out, payload)
    return payload


if __name__ == "__main__":
    main()
