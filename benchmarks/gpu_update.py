"""The learner's updates on a GPU, against TorchRL's own: our compiled, CUDA-graphed TD3 and D3QN updates
(:func:`benchmarks.update_speed.measure_update` on ``--device cuda``: the batches on the device as the learner's
buffers sample them there, and ``compiled_cpu_batches`` moved there update by update), and (r), the reference the GPU
goal names: TorchRL's own compiled, CUDA-graphed TD3 on a MuJoCo-sized task as its ``sota-implementations`` run it.
``td3_ratio_vs_torchrl_reference`` = its time / ours, both measured in this run. ``--gpu-batches``: both again at
each of these TD3 minibatches (``by_batch``). ``--acting-calls N``: the acting policy timed with the learner on the
CPU and on the GPU (``acting``: where acting is fastest). ``--device cpu`` runs (r) on the CPU, for a comparison
on a machine without a GPU.

    python -m benchmarks.gpu_update [--device cuda] [--gpu-batches 128 256] [--acting-calls 2000]

Prints a table and writes ``benchmarks/results/gpu_update.json``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from benchmarks.env_throughput import machine_info, write_json
from benchmarks.kddrl_parts import (
    RESULTS,
    learner_kwargs,
    sync,
)
from benchmarks.update_speed import measure_update
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.process_settings import apply_flush_denormal
from kddrl_trl.training import HierarchicalLearner
from kddrl_trl.transforms import (
    DecisionClock,
    make_kddrl_transforms,
)


def measure_torchrl_td3(
    updates: int,
    repeats: int,
    device: torch.device,
    batch_size: int = 256,
    obs: int = 17,
    act: int = 6,
    hidden: tuple[int, ...] = (256, 256),
    probe=None,
) -> dict:
    """(r): the reference the issue's GPU goal names, TorchRL's own TD3 as its ``sota-implementations`` run it:
    ``TD3Loss`` (twin critics) on a MuJoCo-sized task (by default 17-dim observations, 6 actions, 2 x 256 MLPs),
    batch ``batch_size``, each update ``torch.compile`` d and (on CUDA) wrapped in ``CudaGraphModule`` with
    capturable Adam; the critic step and, every second update (``policy_delay`` 2), the critic + actor +
    ``SoftUpdate`` step, as two functions. Updates per second on random batches already on ``device``, median over
    ``repeats``. ``probe(call, graphs)``, if given, is called after the timing with ``call(i)`` (the ``i``-th update
    as timed) and, on CUDA, the two CUDA graphs in the order the updates replay them; what it returns is added."""
    from tensordict import TensorDict
    from tensordict.nn import CudaGraphModule, TensorDictModule
    from torchrl.data import Bounded
    from torchrl.modules import MLP, ValueOperator
    from torchrl.objectives import SoftUpdate, TD3Loss

    b, cells = batch_size, list(hidden)
    torch.manual_seed(0)
    actor = TensorDictModule(
        torch.nn.Sequential(MLP(obs, act, num_cells=cells), torch.nn.Tanh()), ["observation"], ["action"]
    ).to(device)
    critic = ValueOperator(MLP(obs + act, 1, num_cells=cells), in_keys=["observation", "action"]).to(device)
    loss = TD3Loss(
        actor,
        critic,
        action_spec=Bounded(-torch.ones(act), torch.ones(act), device=device),
        num_qvalue_nets=2,
        loss_function="l2",
        delay_actor=True,
        delay_qvalue=True,
    )
    loss.make_value_estimator(gamma=0.99)
    target = SoftUpdate(loss, tau=0.005)
    graphs = device.type == "cuda"
    opt_a = torch.optim.Adam(loss.actor_network_params.flatten_keys().values(), lr=3e-4, capturable=graphs)
    opt_c = torch.optim.Adam(loss.qvalue_network_params.flatten_keys().values(), lr=3e-4, capturable=graphs)

    def value(td):
        q, _ = loss.value_loss(td)
        q.backward()
        opt_c.step()
        opt_c.zero_grad(set_to_none=True)
        return TensorDict({"q": q.detach()})

    def full(td):
        out = value(td)
        a, _ = loss.actor_loss(td)
        a.backward()
        opt_a.step()
        opt_a.zero_grad(set_to_none=True)
        target.step()
        return out.set("a", a.detach())

    steps = [torch.compile(f) for f in (value, full)]
    if graphs:
        steps = [CudaGraphModule(f, in_keys=[], out_keys=[], warmup=5) for f in steps]

    def batch():
        flags = {k: torch.zeros(b, 1, dtype=torch.bool, device=device) for k in ("done", "terminated")}
        return TensorDict(
            {
                "observation": torch.randn(b, obs, device=device),
                "action": torch.rand(b, act, device=device) * 2 - 1,
                "next": {
                    "observation": torch.randn(b, obs, device=device),
                    "reward": torch.randn(b, 1, device=device),
                    **flags,
                },
            },
            [b],
        )

    batches = [batch() for _ in range(updates)]
    for i, td in enumerate(batches[:12]):
        steps[i % 2](td)
    runs = []
    for _ in range(repeats):
        sync(device)
        t0 = time.perf_counter()
        for i, td in enumerate(batches):
            steps[i % 2](td)
        sync(device)
        runs.append((time.perf_counter() - t0) / len(batches))
    per_update = statistics.median(runs)
    print(
        f"  TorchRL's own TD3 (batch {b}, {obs}-dim obs, {act} actions, {cells}): {1 / per_update:.0f} updates/s",
        flush=True,
    )
    out = {"batch_size": b, "td3_update_s": per_update, "td3_updates_per_s": 1.0 / per_update}
    if probe is not None:
        out.update(probe(lambda i: steps[i % 2](batches[i % len(batches)]), [s.graph for s in steps] if graphs else []))
    return out


class _OnDevice(torch.nn.Module):
    """A policy run on ``device``: inputs moved there, actions moved back to the env's CPU TensorDict."""

    def __init__(self, policy, device: torch.device):
        super().__init__()
        self.policy, self.device = policy, device

    def forward(self, td):
        out = self.policy(td.select(*self.policy.in_keys, strict=False).to(self.device, non_blocking=True))
        for key in self.policy.out_keys:
            td.set(key, out.get(key).cpu())
        return td


def measure_acting(k: int, calls: int, seed: int, devices: list[torch.device]) -> dict:
    """(p): milliseconds per call of the exploring acting policy (both agents, ``learner.policy()``) on a ``k``-row
    TensorDict of the env (fake env + KDDRL transform stack + decision clock, on the CPU as in training), with the
    learner on each of ``devices``: the policy run on that device, its inputs moved there and its actions back
    (for a CUDA learner what TorchRL's ``policy_device`` does). Tells where acting is fastest: training acts on the
    CPU (:class:`~kddrl_trl.collectors.PolicySnapshot`) because the CPU measured faster."""
    env = TransformedEnv(
        FakeHighwayEnv(num_roads=k, seed=seed),
        Compose(make_kddrl_transforms(seed=seed), DecisionClock(learner_kwargs(False)[1])),
    )
    td = env.reset()
    rows = {}
    for device in devices:
        learner = HierarchicalLearner(**learner_kwargs(False)[0], device=device)
        policy = learner._policy() if device.type == "cpu" else _OnDevice(learner._policy(), device)
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):  # exploring, as a collector acts
            for _ in range(20):
                policy(td.clone())
            sync(device)
            t0 = time.perf_counter()
            for _ in range(calls):
                policy(td.clone())
            sync(device)
        rows[str(device)] = 1e3 * (time.perf_counter() - t0) / calls
        print(f"  acting policy, learner on {device}, K={k}: {rows[str(device)]:.2f} ms per call", flush=True)
    env.close()
    return {"num_roads": k, "calls": calls, "ms_per_call": rows, "fastest": min(rows, key=rows.get)}


def same_batch(batches: list[int], updates: int, seed: int, repeats: int, device: torch.device, update: dict) -> dict:
    """Our compiled, CUDA-graphed TD3 update and TorchRL's own (r) at the same TD3 minibatch, for each of
    ``batches`` (``update``: (a) already measured at training's batch, reused there). Per batch: both rates in
    updates/s and their ratio (ours / TorchRL's; above 1: ours is faster)."""
    out = {}
    for b in batches:
        ours = update if b == update["batch_size_cf"] else measure_update(updates, seed, repeats, device, b)
        ref = measure_torchrl_td3(updates, repeats, device, batch_size=b)
        out[str(b)] = {
            "td3_updates_per_s": 1.0 / ours["compiled"]["td3_update_s"],
            "d3qn_updates_per_s": 1.0 / ours["compiled"]["d3qn_update_s"],
            "torchrl_td3_updates_per_s": 1.0 / ref["td3_update_s"],
            "td3_ratio_vs_torchrl_same_batch": ref["td3_update_s"] / ours["compiled"]["td3_update_s"],
        }
        print(
            f"  batch {b}: ours {out[str(b)]['td3_updates_per_s']:.0f} TD3 updates/s, TorchRL's "
            f"{out[str(b)]['torchrl_td3_updates_per_s']:.0f}: ratio "
            f"{out[str(b)]['td3_ratio_vs_torchrl_same_batch']:.2f}",
            flush=True,
        )
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cuda")
    p.add_argument("--updates", type=int, default=200, help="TD3 updates timed per repeat")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--gpu-batches", type=int, nargs="*", default=[], help="both updates again at these TD3 minibatches")
    p.add_argument("--acting-calls", type=int, default=0, help="acting-policy calls timed per K of --roads (0: skip)")
    p.add_argument("--roads", type=int, nargs="+", default=[8, 32], help="--acting-calls: the env rows K")
    p.add_argument("--note", default=None, help="free text stored in the JSON")
    p.add_argument("--out", type=Path, default=RESULTS / "gpu_update.json")
    args = p.parse_args(argv)
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit(f"--device {args.device}: no CUDA device is available here")
    apply_flush_denormal(True)
    update = measure_update(args.updates, args.seed, args.repeats, device)
    reference = measure_torchrl_td3(args.updates, args.repeats, device)
    gpu = {
        "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu",
        **{
            f"{arm}_{agent}_updates_per_s": 1.0 / update[arm][f"{agent}_update_s"]
            for arm in ("compiled", "compiled_cpu_batches", "eager", "plain")
            if arm in update
            for agent in ("td3", "d3qn")
        },
        "td3_updates_per_s": 1.0 / update["compiled"]["td3_update_s"],
        "d3qn_updates_per_s": 1.0 / update["compiled"]["d3qn_update_s"],
        "batch_size_cf": update["batch_size_cf"],
        "ratio_vs_plain": update["plain"]["per_frame_s"] / update["compiled"]["per_frame_s"],
        "torchrl_td3_reference": reference,
        "td3_ratio_vs_torchrl_reference": reference["td3_update_s"] / update["compiled"]["td3_update_s"],
    }
    torch.set_num_threads(1)  # acting runs single-threaded, as in training
    if args.acting_calls:
        gpu["acting"] = [
            measure_acting(k, args.acting_calls, args.seed, list(dict.fromkeys([torch.device("cpu"), device])))
            for k in args.roads
        ]
    if args.gpu_batches:
        gpu["by_batch"] = same_batch(args.gpu_batches, args.updates, args.seed, args.repeats, device, update)
        if str(update["batch_size_cf"]) in gpu["by_batch"]:
            gpu["td3_ratio_vs_torchrl_same_batch"] = gpu["by_batch"][str(update["batch_size_cf"])][
                "td3_ratio_vs_torchrl_same_batch"
            ]
    result = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "machine": machine_info(),
        "update": update,
        "gpu": gpu,
    }
    if args.note:
        result["note"] = args.note
    print(f"\n{'updates per second on ' + gpu['device_name']:<44}{'TD3':>10}{'D3QN':>10}")
    print(f"{'ours (compiled, CUDA-graphed)':<44}{gpu['td3_updates_per_s']:>10.0f}{gpu['d3qn_updates_per_s']:>10.0f}")
    print(f"{'TorchRL TD3 (r)':<44}{1 / reference['td3_update_s']:>10.0f}")
    print(f"{'ours / TorchRL (r)':<44}{gpu['td3_ratio_vs_torchrl_reference']:>10.2f}")
    write_json(args.out, result)
    print(f"\nwritten {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
