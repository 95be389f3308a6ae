"""Soak test: does a long run stay flat? Evaluation episodes of the IDM+MOBIL policy, then KDDRL training episodes,
on the SUMO env, in one process (not part of the test suite: the defaults take hours).

Measures, per phase: resident memory (RSS) every ``--every`` finished episodes, its growth after warm-up as a ratio
(the last sample / the first, taken after ``--every`` episodes: imports, SUMO's network and the compiled kernels are
in by then; during training the replay buffers fill until they hold ``train.buffer_cf`` frames, so some growth
there is expected), the episodes truncated by SUMO faults (outcome ``lost``, and the env's ``sumo_errors``); at the
end, the processes still running below this one (periodic-evaluation workers, each with its own libsumo; those
whose command line names SUMO) and this process's open file descriptors. Also the cost of the env's NaN check
(:class:`~kddrl_trl.envs.observe.FiniteCheck`) against a frame. Prints a table and writes
``benchmarks/results/soak.json``.

    python -m benchmarks.soak                                          # 10,000 evaluation + 1,000 training episodes
    python -m benchmarks.soak --eval-episodes 200 --train-episodes 20 --every 50 --out /tmp/soak.json  # a smoke run

Training uses the package's config (``conf/config.yaml``: KDDRL, periodic evaluation in a worker process,
checkpoints with both buffers into a temporary run folder); ``--set key=value`` overrides it (e.g.
``--set compile=false env.num_roads=4``).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import torch

from kddrl_trl.atomic_files import write_json_atomic
from kddrl_trl.baselines import IDMMobilPolicy
from kddrl_trl.envs import SumoHighwayEnv
from kddrl_trl.eval import evaluate_policy

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "soak.json"


def rss_mib() -> float:
    """Resident memory of this process (``/proc/self/status`` VmRSS), MiB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def descendants() -> list[tuple[int, str]]:
    """(pid, command line) of every live process below this one."""
    children: dict[int, list[int]] = {}
    cmdlines: dict[int, str] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            cmdlines[int(entry.name)] = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], list(children.get(os.getpid(), []))
    while todo:
        pid = todo.pop()
        out.append((pid, cmdlines.get(pid, "")))
        todo += children.get(pid, [])
    return out


class MemoryProbe:
    """Samples RSS and open file descriptors every ``every`` finished episodes of a phase: ``samples`` =
    [(episodes, MiB)], ``fds`` = [(episodes, open fds)]."""

    def __init__(self, every: int):
        self.every, self.samples, self.fds, self.finished = every, [(0, rss_mib())], [(0, open_fds())], 0

    def episode_done(self) -> None:
        self.finished += 1
        if self.finished % self.every == 0:
            self.samples.append((self.finished, rss_mib()))
            self.fds.append((self.finished, open_fds()))

    def growth_after_warmup(self) -> float | None:
        """Last sample / the first taken after warm-up (``every`` episodes); None with fewer than two."""
        after = self.samples[1:]
        return after[-1][1] / after[0][1] if len(after) >= 2 else None


class TrainingProbe:
    """A logger for :class:`~kddrl_trl.training.Trainer`: counts the training episodes it logs (one
    ``train/frames`` scalar each) into a :class:`MemoryProbe`, and keeps nothing else."""

    def __init__(self, probe: MemoryProbe):
        self.probe = probe

    def log_scalar(self, name: str, value, step: int = 0) -> None:
        if name == "train/frames":
            self.probe.episode_done()


def finite_check_cost(env: SumoHighwayEnv, frames: int = 200) -> dict:
    """Mean seconds of one env frame (IDM+MOBIL) and of one :class:`FiniteCheck` call, and their ratio."""
    policy, td = IDMMobilPolicy(), env.reset()
    t0 = time.perf_counter()
    for _ in range(frames):
        _, td = env.step_and_maybe_reset(policy(td))
    frame = (time.perf_counter() - t0) / frames
    t0 = time.perf_counter()
    for _ in range(frames * 10):
        env._check_finite()
    check = (time.perf_counter() - t0) / (frames * 10)
    return {"frame_us": frame * 1e6, "check_us": check * 1e6, "share": check / frame}


def soak_evaluation(args) -> dict:
    probe, lost = MemoryProbe(args.every), 0
    env = SumoHighwayEnv(args.scenario, num_roads=args.roads, seed=args.seed)
    t0 = time.perf_counter()
    try:

        def on_episode(ep):
            nonlocal lost
            lost += ep["outcome"] == "lost"
            probe.episode_done()

        evaluate_policy(
            env, IDMMobilPolicy(), args.eval_episodes, seed=args.seed, progress=args.progress, on_episode=on_episode
        )
        wall = time.perf_counter() - t0
        stats = dict(env.stats)
        cost = finite_check_cost(env)
    finally:
        env.close()
    return {
        "episodes": args.eval_episodes,
        "wall_s": wall,
        "rss_mib": probe.samples,
        "open_fds": probe.fds,
        "growth_after_warmup": probe.growth_after_warmup(),
        "lost": lost,
        "sumo_errors": stats["sumo_errors"],
        "env_stats": stats,
        "finite_check": cost,
    }


def soak_training(args) -> dict:
    from hydra import compose, initialize_config_module

    from kddrl_trl.factories import make_job
    from kddrl_trl.run_folder import RunFolder
    from kddrl_trl.train import finish_validations, train

    overrides = [
        f"episodes={args.train_episodes}",
        f"seed={args.seed}",
        f"progress={str(args.progress).lower()}",
        *args.set,
    ]
    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        job = make_job(compose(config_name="config", overrides=overrides))
    probe = MemoryProbe(args.every)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as run_dir:
        run = RunFolder(run_dir)
        _, summary, trainer = train(job, run, TrainingProbe(probe), resuming=False)
        try:
            finish_validations(trainer, run)
        finally:
            trainer.close()
        history = pd.read_csv(run.train_episodes)
    lost = int((history["outcome"] == "lost").sum())
    return {
        "episodes": args.train_episodes,
        "overrides": overrides,
        "wall_s": time.perf_counter() - t0,
        "rss_mib": probe.samples,
        "open_fds": probe.fds,
        "growth_after_warmup": probe.growth_after_warmup(),
        "lost": lost,
        "frames": summary.get("frames"),
    }


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--eval-episodes", type=int, default=10_000, help="IDM+MOBIL evaluation episodes (0: skip)")
    p.add_argument("--train-episodes", type=int, default=1_000, help="KDDRL training episodes (0: skip)")
    p.add_argument("--every", type=int, default=500, help="episodes between memory samples")
    p.add_argument("--roads", type=int, default=8, help="roads K of the evaluation env")
    p.add_argument("--scenario", default="baseline")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="training config overrides")
    p.add_argument("--progress", action="store_true", help="progress bars")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"JSON output (default: {DEFAULT_OUT})")
    args = p.parse_args(argv)
    if args.every < 1:
        p.error("--every must be >= 1")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    torch.set_num_threads(1)
    fds_start = open_fds()
    phases = {}
    if args.eval_episodes > 0:
        phases["evaluation"] = soak_evaluation(args)
    if args.train_episodes > 0:
        phases["training"] = soak_training(args)
    procs = descendants()  # multiprocessing's resource tracker lives as long as this process: not a leak
    leftover = [(pid, cmd) for pid, cmd in procs if "resource_tracker" not in cmd]
    end = {
        "open_fds_start": fds_start,
        "open_fds_end": open_fds(),
        "child_processes": len(leftover),
        "sumo_processes": sum("sumo" in cmd.lower() for _, cmd in leftover),
        "processes": procs,
    }

    print(f"\nsoak, {args.scenario}, seed {args.seed}, memory sampled every {args.every} episodes")
    print(f"{'phase':11s} {'episodes':>9s} {'wall s':>8s} {'RSS MiB first -> last':>24s} {'growth':>7s} {'lost':>5s}")
    for name, ph in phases.items():
        samples = ph["rss_mib"]
        growth = "n/a" if ph["growth_after_warmup"] is None else f"{ph['growth_after_warmup']:.3f}"
        print(
            f"{name:11s} {ph['episodes']:>9,d} {ph['wall_s']:8.0f} "
            f"{f'{samples[0][1]:.0f} -> {samples[-1][1]:.0f}':>24s} {growth:>7s} {str(ph['lost']):>5s}"
        )
        print(f"{'':11s} RSS (episodes: MiB): " + ", ".join(f"{n}: {m:.0f}" for n, m in samples))
        print(f"{'':11s} open fds (episodes: fds): " + ", ".join(f"{n}: {f}" for n, f in ph["open_fds"]))
    if "evaluation" in phases:
        c = phases["evaluation"]["finite_check"]
        print(f"NaN check: {c['check_us']:.1f} us per call, {100 * c['share']:.2f} % of a {c['frame_us']:.0f} us frame")
    print(
        f"end: {end['child_processes']} child processes left (besides multiprocessing's resource tracker; "
        f"{end['sumo_processes']} naming SUMO), open fds "
        f"{end['open_fds_start']} -> {end['open_fds_end']}"
    )
    result = {
        "machine": {
            "platform": platform.platform(),
            "python": sys.version.split()[0],
            "torch": torch.__version__,
            "cpus": os.cpu_count(),
        },
        "arguments": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "phases": phases,
        "end": end,
    }
    write_json_atomic(args.out, result)
    print(f"results written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
