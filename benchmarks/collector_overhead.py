"""What TorchRL's own collector costs per env step, on a trivial env, beside our collection's ``torchrl`` part.

``benchmarks/collect_speed.py`` splits a collection step of the KDDRL env at K roads into the env, the
transform stack, the acting policy, the buffer writes and ``torchrl``: the rest, TorchRL's ``Collector`` and
``TransformedEnv`` plumbing. This script measures, in one run, how much of that rest is TorchRL's own: its
``Collector`` (the same options as training's, ``frames_per_batch`` = 20 frames x K, endless) over a
:class:`TrivialEnv` whose step does nothing but hand back precomputed tensors, with a policy that does nothing
but write precomputed actions. Two trivial envs:

- ``kddrl_keys``: the specs of the KDDRL training env (``SumoHighwayEnv`` + the transform stack + the decision
  clock, every key at its shape): TorchRL's cost for our TensorDicts;
- ``minimal``: one 8-feature observation, one action, a reward and the done flags: TorchRL's cost per step for
  the smallest env it can run.

The trivial env's and policy's own calls are timed and taken out, as (b) takes out the real ones; what stays is
TorchRL's per env step. ``kddrl_keys ÷ ours`` says how much of our ``torchrl`` part TorchRL's collector costs with
our keys; the rest is ``TransformedEnv`` 's plumbing around the transform stack.

    python -m benchmarks.collector_overhead [--roads 8] [--frames 4000] [--out benchmarks/results/collector_overhead.json]

Prints a table and writes the JSON (``--out``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data import Bounded, Composite, Unbounded
from torchrl.envs import EnvBase

from benchmarks.collect_speed import _Stopwatch, measure_collect
from benchmarks.env_throughput import machine_info, write_json
from benchmarks.kddrl_parts import FRAMES_PER_ENV, collect_env


class TrivialEnv(EnvBase):
    """An env with the given specs whose reset and step return precomputed zero TensorDicts (a shallow copy
    each call, as an env hands out fresh TensorDicts): nothing of its own to compute. Never done."""

    #: the spec attributes it takes from its ``specs`` (TorchRL's names)
    SPECS = ("full_observation_spec", "full_reward_spec", "full_done_spec", "full_action_spec", "full_state_spec")

    def __init__(self, batch_size: torch.Size, **specs: Composite):
        super().__init__(batch_size=batch_size)
        for name in self.SPECS:
            setattr(self, name, specs[name].clone())
        self._reset_out = self.full_observation_spec.zero().update(self.full_done_spec.zero())
        self._step_out = self._reset_out.clone().update(self.full_reward_spec.zero())

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        return self._reset_out.copy()

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self._step_out.copy()

    def _set_seed(self, seed: int | None) -> None:
        pass


class ZeroPolicy(TensorDictModuleBase):
    """Writes precomputed zero actions (the env's action keys) into the input: a policy that costs nothing."""

    def __init__(self, env: EnvBase):
        super().__init__()
        self.actions = env.full_action_spec.zero()
        self.in_keys, self.out_keys = [], list(self.actions.keys(True, True))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return tensordict.update(self.actions)


def minimal_env(k: int) -> TrivialEnv:
    """One 8-feature observation, one action in [-1, 1], a reward, and the done flags, for ``k`` rows."""
    batch = torch.Size([k])
    flag = Bounded(0, 1, (k, 1), dtype=torch.bool)
    return TrivialEnv(
        batch,
        full_observation_spec=Composite(observation=Unbounded((k, 8)), shape=batch),
        full_reward_spec=Composite(reward=Unbounded((k, 1)), shape=batch),
        full_done_spec=Composite(done=flag, terminated=flag.clone(), truncated=flag.clone(), shape=batch),
        full_action_spec=Composite(action=Bounded(-1.0, 1.0, (k, 1)), shape=batch),
        full_state_spec=Composite(shape=batch),
    )


def kddrl_keys_env(k: int, seed: int) -> TrivialEnv:
    """A trivial env with the specs of the KDDRL training env at ``k`` roads (as ``collect_env`` builds it)."""
    env = collect_env(k, seed=seed)
    try:
        return TrivialEnv(env.batch_size, **{name: getattr(env, name) for name in TrivialEnv.SPECS})
    finally:
        env.close()


def torchrl_ms_per_step(env: TrivialEnv, frames: int) -> dict:
    """TorchRL's ``Collector`` over ``env`` with :class:`ZeroPolicy` (training's options): milliseconds per env
    step in all, in the env's and the policy's calls, and in TorchRL (the rest)."""
    from torchrl.collectors import Collector

    k = env.batch_size.numel()
    policy = ZeroPolicy(env)
    collector = Collector(
        env,
        policy,
        frames_per_batch=FRAMES_PER_ENV * k,
        total_frames=-1,
        trust_policy=True,
        auto_register_policy_transforms=False,
    )
    watch = _Stopwatch(time.perf_counter)
    for obj, method, part in ((env, "_step", "env"), (env, "_reset", "env"), (policy, "forward", "policy")):
        watch.wrap(obj, method, part)
    try:
        it = iter(collector)
        for _ in range(3):  # warm-up batches, untimed
            next(it)
        watch.running = True
        t0, n = time.perf_counter(), 0
        while n < frames:
            n += next(it).numel()
        elapsed = time.perf_counter() - t0
    finally:
        collector.shutdown()
    steps = n / k
    parts = {**watch.seconds, "torchrl": elapsed - sum(watch.seconds.values())}
    return {"ms_per_env_step": {name: 1e3 * t / steps for name, t in parts.items()}, "total_ms": 1e3 * elapsed / steps}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--roads", type=int, default=8)
    p.add_argument("--frames", type=int, default=4000, help="ego-frames timed per arm")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--note", default="")
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "collector_overhead.json")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    k = args.roads
    trivial = {
        "minimal": torchrl_ms_per_step(minimal_env(k), args.frames),
        "kddrl_keys": torchrl_ms_per_step(kddrl_keys_env(k, args.seed), args.frames),
    }
    ours = measure_collect(k, args.frames, args.seed)
    ours_torchrl = ours["breakdown"]["ms_per_env_step"]["torchrl"]
    result = {
        "args": {key: str(v) for key, v in vars(args).items()},
        "machine": machine_info(),
        "num_roads": k,
        "trivial": trivial,
        "ours": {key: ours[key] for key in ("collect_fps", "sim_limit_fps", "collect_ratio_vs_sim", "breakdown")},
        "torchrl_ms_per_env_step": {
            "minimal": trivial["minimal"]["ms_per_env_step"]["torchrl"],
            "kddrl_keys": trivial["kddrl_keys"]["ms_per_env_step"]["torchrl"],
            "ours": ours_torchrl,
        },
        "kddrl_keys_over_ours": trivial["kddrl_keys"]["ms_per_env_step"]["torchrl"] / ours_torchrl,
        **({"note": args.note} if args.note else {}),
    }
    print(f"\n{'TorchRL per env step, K = ' + str(k):<52}{'ms':>8}{'÷ ours':>9}")
    for name, ms in result["torchrl_ms_per_env_step"].items():
        label = {
            "minimal": "Collector, trivial env, one observation",
            "kddrl_keys": "Collector, trivial env with the KDDRL env's keys",
            "ours": "our collection's torchrl part (Collector + TransformedEnv)",
        }[name]
        print(f"{label:<52}{ms:>8.3f}{ms / ours_torchrl:>9.2f}")
    write_json(args.out, result)
    print(f"\nwritten {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
