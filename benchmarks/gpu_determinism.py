"""Whether the learner's updates repeat bit for bit: the same updates on the same batches from the same seed, in
separate processes, compared by a hash of every tensor the learner saves.

Training on a GPU keeps the env, SUMO, the transforms and the acting policy on the CPU (each repeats itself bit for
bit there: the training records of two CPU runs of one seed are the same). What a GPU adds is the learner: TD3
(Eq. 6-10) and D3QN (Eq. 4-5) updates, with the shared embedding (Eq. 23-24), compiled and replayed as CUDA graphs
(:class:`kddrl_trl.compiling.GraphedUpdate`), the target-smoothing noise drawn inside the graph. This script runs
``--updates`` TD3 updates and one D3QN update every ``lc_period`` of them (as training interleaves them) on
minibatches of the fake env's frames (:func:`benchmarks.kddrl_parts.sample_batches`, from ``--seed``), with the learner of
``conf/algo/kddrl.yaml`` built as training builds it (compiled; CUDA graphs on a GPU), and writes the SHA-256 of
every tensor of :meth:`~kddrl_trl.training.Learner.full_state_dict` (networks, targets, optimiser states) and of
the losses of every update. Two processes with the same arguments write the same hashes exactly when the updates
repeat bit for bit; ``--compare A B`` says which tensors differ.

    python -m benchmarks.gpu_determinism [--device cuda] [--updates 400] [--seed 0] [--matmul-precision highest]
                                         [--out PATH]
    python -m benchmarks.gpu_determinism --compare A.json B.json

Prints a line and writes ``benchmarks/results/gpu_determinism.json`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import torch

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.kddrl_parts import batch_sizes, buffer_keys, learner_kwargs, sample_batches
from kddrl_trl.compiling import fresh_compiler
from kddrl_trl.training import HierarchicalLearner


def tensor_hashes(state, prefix: str = "") -> dict[str, str]:
    """``name -> SHA-256`` of each tensor's dtype, shape and bytes (read on the CPU) in a nested state dict."""
    out = {}
    for key, value in state.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(tensor_hashes(value, f"{name}."))
        elif isinstance(value, list):
            out.update(tensor_hashes(dict(enumerate(value)), f"{name}."))
        elif isinstance(value, torch.Tensor):
            t = value.detach().cpu().contiguous()
            data = t.reshape(-1).view(torch.uint8)
            h = hashlib.sha256(f"{t.dtype}{tuple(t.shape)}".encode())
            h.update(data.numpy().tobytes())
            out[name] = h.hexdigest()
    return out


def run(args) -> dict:
    device = torch.device(args.device)
    fresh_compiler()  # as every job of an entry point: graphs cached by earlier runs in this process do not count
    torch.set_float32_matmul_precision(args.matmul_precision)
    kw, lc_period = learner_kwargs(True)
    torch.manual_seed(args.seed)  # the collecting policy's weights and exploration
    rb_cf, rb_lc = sample_batches(max(2000, 4 * batch_sizes()[0]), args.seed, buffer_keys())
    torch.manual_seed(args.seed)
    cf = [rb_cf.sample().to(device) for _ in range(args.updates)]
    lc = [rb_lc.sample().to(device) for _ in range(args.updates // lc_period + 1)]
    torch.manual_seed(args.seed)
    learner = HierarchicalLearner(**kw, device=device, cudagraphs=device.type == "cuda")
    losses = []
    t0 = time.perf_counter()
    for i in range(args.updates):
        losses.append(learner.update_cf(cf[i]))
        if i % lc_period == 0:
            losses.append(learner.update_lc(lc[i // lc_period]))
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    wall = time.perf_counter() - t0
    state = tensor_hashes(learner.full_state_dict())
    loss_hash = hashlib.sha256()
    for row in losses:
        for name in sorted(row):
            loss_hash.update(row[name].detach().cpu().reshape(-1).numpy().tobytes())
    whole = hashlib.sha256("".join(f"{k}{v}" for k, v in sorted(state.items())).encode()).hexdigest()
    return {
        "args": {k: str(v) for k, v in vars(args).items()},
        "machine": {
            **machine_info(),
            "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu",
        },
        "updates": {"td3": args.updates, "d3qn": len(range(0, args.updates, lc_period))},
        "wall_s_incl_compile": wall,
        "state_sha256": whole,
        "losses_sha256": loss_hash.hexdigest(),
        "tensors": state,
    }


def compare(a: dict, b: dict) -> dict:
    """Which tensors of two runs' hashes differ (and whether their losses did)."""
    differ = sorted(k for k in a["tensors"].keys() | b["tensors"].keys() if a["tensors"].get(k) != b["tensors"].get(k))
    return {
        "identical": not differ and a["losses_sha256"] == b["losses_sha256"],
        "tensors": len(a["tensors"]),
        "tensors_differing": differ,
        "losses_identical": a["losses_sha256"] == b["losses_sha256"],
    }


def main(argv=None) -> int:
    torch.set_num_threads(1)  # the CPU side of the measurement, on one torch thread as in its recorded results
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda")
    p.add_argument("--updates", type=int, default=400)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--matmul-precision", default="highest", choices=("highest", "high", "medium"))
    p.add_argument("--compare", nargs=2, type=Path, metavar=("A", "B"), help="compare two runs' JSON files")
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "gpu_determinism.json")
    args = p.parse_args(argv)
    if args.compare:
        a, b = (json.loads(f.read_text()) for f in args.compare)
        result = {"runs": [str(f) for f in args.compare], **compare(a, b)}
        print(
            f"{'identical' if result['identical'] else 'DIFFERENT'}: {len(result['tensors_differing'])} of "
            f"{result['tensors']} tensors differ; losses {'equal' if result['losses_identical'] else 'differ'}"
        )
    else:
        if args.device.startswith("cuda") and not torch.cuda.is_available():
            raise SystemExit(f"--device {args.device}: no CUDA device is available here")
        result = run(args)
        print(
            f"state {result['state_sha256'][:16]}  losses {result['losses_sha256'][:16]}  "
            f"({result['updates']['td3']} TD3 + {result['updates']['d3qn']} D3QN updates, "
            f"{result['wall_s_incl_compile']:.1f} s)"
        )
    write_json(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
