"""Helpers shared by the tests: import them with ``from testkit import ...`` (the suite's ``conftest.py`` sits in
this folder, which pytest puts on ``sys.path``; the fixtures live in ``conftest.py``). No test imports another test
module or ``conftest``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import torch
import torch.nn.functional as F
from hydra import compose, initialize_config_module
from tensordict import TensorDict

from kddrl_trl import keys as K


def command(env, lc=K.KEEP, accel=0.0) -> TensorDict:
    """An action tensordict for every road of ``env``: lane-change index (or [K] tensor) and acceleration."""
    k = env.batch_size[0]
    lc = torch.as_tensor(lc).expand(k) if torch.as_tensor(lc).dim() == 0 else torch.as_tensor(lc)
    accel = torch.as_tensor(accel, dtype=torch.float32)
    accel = accel.expand(k) if accel.dim() == 0 else accel
    return TensorDict(
        {K.LC_ACTION: F.one_hot(lc.long(), 3).float(), K.CF_ACTION: accel.reshape(k, 1).float()}, batch_size=[k]
    )


#: a small hierarchical learner for the learner tests (test_learner.py, test_learner_update.py)
SMALL = {
    "embed_dim": 8,
    "embed_hidden": 16,
    "d3qn": {"hidden": [32, 32], "eps_decisions": 50},
    "td3": {"hidden": [32, 32]},
}


def fake_samples(n_frames: int, n_macros: int) -> tuple[list, list]:
    """``n_frames`` buffer-L and ``n_macros`` buffer-H samples collected (one batch of 40 frames on 4 roads) from
    the fake env with the full transform stack and a :data:`SMALL` learner's exploring policy."""
    from torchrl.envs import Compose, TransformedEnv

    from kddrl_trl.collectors import MultiTimescaleCollector
    from kddrl_trl.envs import FakeHighwayEnv
    from kddrl_trl.training import HierarchicalLearner, make_buffer
    from kddrl_trl.transforms import DecisionClock, make_kddrl_transforms

    torch.manual_seed(0)
    env = TransformedEnv(FakeHighwayEnv(num_roads=4, seed=0), Compose(make_kddrl_transforms(), DecisionClock(5)))
    learner = HierarchicalLearner(**SMALL)
    rb_l, rb_h = make_buffer(5000, 32, 0), make_buffer(5000, 16, 0)
    mtc = MultiTimescaleCollector.from_env(
        env, learner.policy(), frames_per_env=40, frame_buffer=rb_l, macro_buffer=rb_h, frame_keys=learner.buffer_keys()
    )
    next(iter(mtc))
    mtc.shutdown()
    return [rb_l.sample() for _ in range(n_frames)], [rb_h.sample() for _ in range(n_macros)]


def compose_job(*overrides: str):
    """The typed ``train.py`` job (:class:`kddrl_trl.conf.schema.TrainJob`) of the package's config."""
    from omegaconf import OmegaConf

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        return OmegaConf.to_object(compose(config_name="config", overrides=list(overrides)))


def fake_trainer(job, tmp_path, **train):
    """(env, learner, trainer, collector) of ``job`` on the fake env, with ``train`` overrides, as train.py wires
    them."""
    from dataclasses import replace

    from kddrl_trl.conf.schema import LoggerConfig
    from kddrl_trl.factories import make_buffers, make_collector, make_env, make_learner, make_logger
    from kddrl_trl.training import Trainer

    env = make_env(job.env, job.algo, seed=0, compile=False, fake=True)
    learner = make_learner(job.algo, compile=False)
    train_cfg = replace(job.train, **train)
    buffers = make_buffers(train_cfg, seed=0)
    trainer = Trainer(
        learner,
        buffers,
        train_cfg,
        tmp_path,
        make_logger(LoggerConfig(csv=True, tensorboard=False), tmp_path),
        episodes=3,
        progress=False,
    )
    return (
        env,
        learner,
        trainer,
        make_collector(env, learner, buffers, train_cfg, job.algo.lc_reward),
    )


#: small networks of every learning algo (each override names a node the algo has)
SMALL_NETS = {
    "peng": ["algo.learner.d3qn.hidden=[16]", "algo.learner.ddpg.hidden=[16]"],
    "d3qn_unified": ["algo.learner.d3qn.hidden=[16]"],
    "pasac_unified": ["algo.learner.pasac.hidden=[16]"],
}


# -------------------------------------------------------------------------------------------- records
def fake_run(
    folder, algo="kddrl", seed=0, speeds=(100.0, 110.0), collisions=(False, True), scenario="baseline", **fields
):
    """A run folder of records a report reads: ``eval_episodes.csv`` with one episode per speed, ``summary.json``
    with their count and ``fields``."""
    folder.mkdir(parents=True)
    n = len(speeds)
    pd.DataFrame(
        {
            "mean_speed_kmh": speeds,
            "mean_speed": np.asarray(speeds) / 3.6,
            "mean_sq_speed": (np.asarray(speeds) / 3.6) ** 2,
            "mean_accel": [0.1] * n,
            "mean_sq_accel": [0.01] * n,
            "mean_abs_accel": [0.1] * n,
            "lane_changes": [1] * n,
            "frames": [100] * n,
            "return_lc": [1.0] * n,
            "return_cf": [2.0] * n,
            "collision": list(collisions),
            "outcome": ["collision" if c else "left_section" for c in collisions],
            "collision_kind": ["rear_end" if c else "none" for c in collisions],
            "collision_with": ["b" if c else "" for c in collisions],
        }
    ).to_csv(folder / "eval_episodes.csv", index=False)
    summary = {"algo": algo, "scenario": scenario, "seed": seed, "episodes": n, **fields}
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


#: the tiny training budget every algo shares: 2 roads, no progress bars, no compiling, updates from the first batches
TINY_BUDGET = [
    "env.num_roads=2",
    "progress=false",
    "train.warmup_frames=50",
    "train.batch_size_cf=32",
    "train.batch_size_lc=8",
    "compile=false",
]
#: a tiny, fast KDDRL budget: :data:`TINY_BUDGET` with small networks
TINY = [*TINY_BUDGET, "algo.learner.d3qn.hidden=[32,32]", "algo.learner.td3.hidden=[32,32]"]


def run_module(cmd, cwd, timeout=900):
    """``python -m <cmd...>`` in ``cwd``; asserts it succeeded (showing the end of its stderr) and returns it."""
    done = subprocess.run([sys.executable, "-m", *cmd], cwd=cwd, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stderr[-4000:]
    return done


def kill_when(cmd, cwd, ready, timeout: float = 600):
    """``python -m <cmd...>`` started in ``cwd`` and killed with SIGKILL as soon as ``ready()`` returns something
    (polled every 0.2 s), or at ``timeout`` seconds or its own end; returns what ``ready`` returned (None: never)
    and the end of the process's stderr."""
    import signal
    import time

    proc = subprocess.Popen(
        [sys.executable, "-m", *cmd], cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    deadline, found = time.monotonic() + timeout, None
    try:
        while time.monotonic() < deadline and proc.poll() is None and found is None:
            found = ready()
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    return found, proc.stderr.read()[-2000:]


def run_script(folder, body: str, timeout: int = 300) -> subprocess.CompletedProcess:
    """``body`` (dedented) written to ``folder/script.py`` and run as a script (``python script.py``): what a user's
    own script does, ``__main__`` included; returns the finished process (not checked)."""
    script = folder / "script.py"
    script.write_text(textwrap.dedent(body))
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=timeout)


def load_benchmark(name: str):
    """The module ``benchmarks.<name>`` (the repository's root is on ``sys.path``: pytest's ``pythonpath``); the
    torch thread count is kept (the benchmarks' shared module sets one thread when imported)."""
    import importlib

    threads = torch.get_num_threads()
    try:
        return importlib.import_module(f"benchmarks.{name}")
    finally:
        torch.set_num_threads(threads)


def study_records(dest, *prefixes: str):
    """The committed studies' run records under ``prefixes`` (e.g. ``studies/paper/runs/baseline__kddrl__0``),
    extracted from main's history (``studies/records.json``) into ``dest``; returns ``dest / "studies"``."""
    from pathlib import Path

    from kddrl_trl.devtools.records import extract, repo_root

    extract(repo_root(Path(__file__).parent), Path(dest), prefixes)
    return Path(dest) / "studies"


def rollout(env, policy, steps: int):
    """``steps`` frames [B, steps] with auto-reset of done rows (what evaluate_policy and collectors do)."""
    import torch

    td, out = env.reset(), []
    for _ in range(steps):
        full, td = env.step_and_maybe_reset(policy(td))
        out.append(full)
    return torch.stack(out, 1)
