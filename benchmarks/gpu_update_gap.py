"""What separates our CUDA-graphed TD3 update from TorchRL's own on a GPU, measured in one run.

The GPU goal compares the learner's TD3 update (``gpu_update.py``: compiled update functions replayed
as CUDA graphs) with TorchRL's own compiled, CUDA-graphed ``TD3Loss`` on a MuJoCo-sized task at the same
minibatch (``gpu_update.py`` (r)). The two do different work. Ours is TD3 (Eq. 6-10) on the car-following
state (Eq. 30) with 2 x 128 networks, plus the shared embedding, online and target (Eq. 23-24), and the D3QN's
greedy next lane-change action in the TD3 target; TorchRL's is TD3 alone on 17 features with 2 x 256 networks.
The arms, at each minibatch of ``--batches``, tell the parts apart:

- ``ours``: the KDDRL learner's TD3 update (``conf/algo/kddrl.yaml``);
- ``ours_no_embedding``: the same learner without the shared embedding (``priors`` and ``key_gaps`` off, the
  learner of ``d3qn_td3``);
- ``torchrl_mujoco``: (r), the reference the goal names;
- ``torchrl_our_shapes``: TorchRL's TD3 with our networks' sizes (the car-following state without s_e, one
  action, 2 x 128): the same TD3 without KDDRL's other parts.

TD3 updates per second (the critic step every update, the actor and target step every second one), median of
``--repeats`` timed passes over ``--updates`` batches already on the GPU. ``--mode`` is ``torch.compile`` 's
mode for every arm (``default``; ``max-autotune-no-cudagraphs`` lets TorchInductor pick Triton GEMMs with the
bias and activation fused into them). The JSON is written after every arm, so a run cut short keeps what it
measured.

    python -m benchmarks.gpu_update_gap [--batches 128 256] [--updates 300] [--repeats 3]
                                        [--mode default] [--arms ours ...] [--out PATH]

Prints a table and writes ``benchmarks/results/gpu_update_gap.json``.
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time
from pathlib import Path

import torch
import torch._inductor.config

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.gpu_update import measure_torchrl_td3
from benchmarks.kddrl_parts import buffer_keys, learner_kwargs, sample_batches, sync
from kddrl_trl.modules import cf_obs_dim
from kddrl_trl.training import HierarchicalLearner

ARMS = ("ours", "ours_no_embedding", "torchrl_mujoco", "torchrl_our_shapes")
#: the ratios written per minibatch: name -> (arm, reference arm), rate over rate (above 1: the arm is faster)
RATIOS = {
    "ours_vs_torchrl_mujoco": ("ours", "torchrl_mujoco"),
    "ours_vs_torchrl_our_shapes": ("ours", "torchrl_our_shapes"),
    "ours_no_embedding_vs_torchrl_our_shapes": ("ours_no_embedding", "torchrl_our_shapes"),
    "ours_vs_ours_no_embedding": ("ours", "ours_no_embedding"),
}


def breakdown(call, graphs: list, n: int, device: torch.device) -> dict:
    """Where an update's time goes, for ``call(i)`` (the ``i``-th update as timed) and ``graphs`` (the CUDA graphs
    the updates replay, in turn):

    - ``replay_s``: the graphs replayed back to back, nothing else: the GPU's time for an update's kernels, with
      the launch of one graph each;
    - ``no_sync_s``: the update as timed, without the ``torch.cuda.synchronize`` that ``CudaGraphModule`` runs
      before every replay (the graphs replay on the stream their inputs were copied on, so their order holds);
    - ``host_s``: the update as timed with the replays and that synchronisation made no-ops: the CPU's time;
    - ``kernels_per_update`` and ``gpu_busy_s``: CUDA kernels (and copies) per update in the profiler's trace of
      the replays, and the sum of their durations."""
    if device.type != "cuda" or not graphs:
        return {}
    try:
        return _breakdown(call, graphs, n, device)
    except Exception as e:  # a diagnosis: its failure must not lose the arm's timing
        return {"breakdown_error": repr(e)}


def _breakdown(call, graphs: list, n: int, device: torch.device) -> dict:
    stream = torch.cuda.current_stream(device)

    def per_update(fn) -> float:
        stream.synchronize()
        t0 = time.perf_counter()
        for i in range(n):
            fn(i)
        stream.synchronize()
        return (time.perf_counter() - t0) / n

    out = {"replay_s": per_update(lambda i: graphs[i % len(graphs)].replay())}
    sync = torch.cuda.synchronize
    torch.cuda.synchronize = lambda *a, **k: None
    try:
        out["no_sync_s"] = per_update(call)
        for g in graphs:
            g.replay = lambda: None
        out["host_s"] = per_update(call)
    finally:
        torch.cuda.synchronize = sync
        for g in graphs:
            g.__dict__.pop("replay", None)
    try:
        from torch.autograd import DeviceType
        from torch.profiler import ProfilerActivity, profile

        k = 2 * len(graphs) * 10
        with profile(activities=[ProfilerActivity.CUDA]) as prof:
            for i in range(k):
                graphs[i % len(graphs)].replay()
            stream.synchronize()
        ev = [e for e in prof.events() if e.device_type == DeviceType.CUDA]
        out["kernels_per_update"] = len(ev) / k
        out["gpu_busy_s"] = sum(e.time_range.elapsed_us() for e in ev) / 1e6 / k
    except Exception as e:  # the profiler is a diagnosis: its failure must not lose the timings
        out["profiler_error"] = repr(e)
    return out


def measure_ours(batches: list, updates: int, repeats: int, device: torch.device, probe=None, **overrides) -> dict:
    """TD3 updates per second of the compiled learner (``learner_kwargs`` with ``overrides``), CUDA-graphed on a
    GPU; ``probe`` as :func:`benchmarks.gpu_update.measure_torchrl_td3` 's."""
    kw, _ = learner_kwargs(True)
    learner = HierarchicalLearner(**{**kw, **overrides}, device=device, cudagraphs=device.type == "cuda")
    t0 = time.perf_counter()
    for b in batches[:12]:
        learner.update_cf(b)
    sync(device)
    compile_s = time.perf_counter() - t0
    for b in batches[:updates]:  # one untimed pass: each batch now holds the |δ| an update writes (one more key)
        learner.update_cf(b)
    runs = []
    for _ in range(repeats):
        sync(device)
        t0 = time.perf_counter()
        for b in batches[:updates]:
            learner.update_cf(b)
        sync(device)
        runs.append((time.perf_counter() - t0) / updates)
    per_update = statistics.median(runs)
    out = {"td3_update_s": per_update, "td3_updates_per_s": 1.0 / per_update, "compile_s": compile_s}
    if probe is not None and learner.cudagraphs:
        fns = learner._update_fns  # the TD3 steps in the order update_cf runs them (policy delay 2)
        graphs = [fns["cf_value"].graph.graph, fns["cf_full"].graph.graph]
        out.update(probe(lambda i: learner.update_cf(batches[i % updates]), graphs))
    return out


def main(argv=None) -> int:
    torch.set_num_threads(1)  # the CPU side of the measurement, on one torch thread as in its recorded results
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--batches", type=int, nargs="+", default=[128, 256])
    p.add_argument("--updates", type=int, default=300)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--mode", default="default", help="torch.compile's mode for every arm")
    p.add_argument("--arms", nargs="+", choices=ARMS, default=list(ARMS))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cuda", help="cuda; cpu only to try the script (nothing is graphed there)")
    p.add_argument("--breakdown", action="store_true", help="also time the parts of each update (breakdown())")
    p.add_argument("--inductor", nargs="*", default=[], metavar="KEY=VALUE", help="TorchInductor config for every arm")
    p.add_argument("--note", default=None)
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "gpu_update_gap.json")
    args = p.parse_args(argv)
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit(f"--device {args.device}: no CUDA device is available here")
    if args.mode != "default":
        torch.compile = functools.partial(torch.compile, mode=args.mode)  # every arm's compile site
    for item in args.inductor:
        key, _, value = item.partition("=")
        setattr(torch._inductor.config, key, {"True": True, "False": False}.get(value, value))
    probe = functools.partial(breakdown, n=args.updates, device=device) if args.breakdown else None
    kw, _ = learner_kwargs(True)
    keys = buffer_keys()
    state = cf_obs_dim(0)
    result = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "machine": {
            **machine_info(),
            "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu",
        },
        "by_batch": {},
    }
    for b in args.batches:
        rb_cf, _ = sample_batches(max(4000, 4 * b), args.seed, keys, b)
        batches = [rb_cf.sample().to(device) for _ in range(args.updates)]
        row = result["by_batch"].setdefault(str(b), {})
        for arm in args.arms:
            if arm == "ours":
                row[arm] = measure_ours(batches, args.updates, args.repeats, device, probe)
            elif arm == "ours_no_embedding":
                row[arm] = measure_ours(
                    batches, args.updates, args.repeats, device, probe, priors=False, key_gaps=False
                )
            elif arm == "torchrl_mujoco":
                row[arm] = measure_torchrl_td3(args.updates, args.repeats, device, batch_size=b, probe=probe)
            else:
                hidden = tuple(kw["td3"]["hidden"])
                row[arm] = measure_torchrl_td3(
                    args.updates, args.repeats, device, batch_size=b, obs=state, act=1, hidden=hidden, probe=probe
                )
            parts = "  ".join(
                f"{k}={row[arm][k] * 1e6:.0f}us" if k.endswith("_s") else f"{k}={row[arm][k]:.1f}"
                for k in ("replay_s", "no_sync_s", "host_s", "gpu_busy_s", "kernels_per_update")
                if k in row[arm]
            )
            print(f"batch {b:4d}  {arm:20s} {row[arm]['td3_updates_per_s']:8.0f} TD3 updates/s  {parts}", flush=True)
            row["ratios"] = {
                name: row[a]["td3_updates_per_s"] / row[r]["td3_updates_per_s"]
                for name, (a, r) in RATIOS.items()
                if a in row and r in row
            }
            write_json(args.out, result)
    print(f"\n{'batch':>5}  " + "  ".join(f"{a:>20s}" for a in args.arms) + "   (TD3 updates/s)")
    for b, row in result["by_batch"].items():
        print(f"{b:>5}  " + "  ".join(f"{row[a]['td3_updates_per_s']:20.0f}" for a in args.arms if a in row))
        for name, value in row.get("ratios", {}).items():
            print(f"       {name}: {value:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
