"""Sweeps on Ray (``hydra/launcher=ray``, ``src/hydra_plugins/kddrl_trl_ray_launcher``): a 2-run sweep on a local
Ray, as typed, read by the report and resumed; and the launcher's refusals, which need no Ray.

The sweep needs the optional extra ``.[ray]``: it is marked ``ray`` and skipped without Ray
(``python -m pytest -m ray -n0 tests/test_ray.py``, as ``.ci/run`` does after installing the extra)."""

from __future__ import annotations

import json
import sys

import pandas as pd
import pytest
from testkit import TINY_BUDGET, run_module

#: one run of each kind: a rule-based one and a KDDRL one that trains, checkpoints and validates (in a process of
#: its own, inside the Ray worker) with a tiny budget
TINY = [
    "episodes=3",
    "eval_episodes=2",
    *TINY_BUDGET,
    "train.eval_every=2",
    "train.eval_episodes=1",
    "train.checkpoint_every=2",
    "env.max_steps=120",
]


@pytest.mark.ray
def test_a_sweep_on_local_ray_writes_its_runs_the_report_reads_and_resumes(tmp_path):
    """On a local Ray of one CPU, so the second run takes the worker process (and libsumo) the first one left."""
    pytest.importorskip("ray")
    sweep = tmp_path / "sweep"
    cmd = [
        "kddrl_trl.train",
        "-m",
        "algo=idm_mobil,kddrl",
        "+scenario=braking",
        "hydra/launcher=ray",
        "+hydra.launcher.init.num_cpus=1",
        f"hydra.sweep.dir={sweep}",
        *TINY,
    ]
    done = run_module(cmd, tmp_path)
    assert "Ray launcher (local Ray; 1 CPUs and 0 GPUs per run) is launching 2 jobs" in done.stdout + done.stderr
    jobs = sorted(p.name for p in sweep.iterdir() if p.is_dir())
    assert jobs == ["braking__idm_mobil__0", "braking__kddrl__0"]
    for job in jobs:
        summary = json.loads((sweep / job / "summary.json").read_text())
        assert summary["scenario"] == "braking" and summary["seed"] == 0 and summary["episodes"] == 2
        assert summary["run_dir"] == str(sweep / job)
        assert len(pd.read_csv(sweep / job / "eval_episodes.csv")) == 2
    kddrl = sweep / "braking__kddrl__0"
    assert json.loads((kddrl / "summary.json").read_text())["training"]["episodes"] == 3
    assert (kddrl / "checkpoints" / "latest").read_text().strip() == "ep000003.pt"
    assert len(pd.read_csv(kddrl / "validation.csv")) >= 1  # the periodic evaluation's process ran in the worker

    # the report reads the runs' folders unchanged
    run_module(["kddrl_trl.report", str(sweep), f"out={tmp_path / 'rep'}"], tmp_path)
    rows = json.loads((tmp_path / "rep" / "report.json").read_text())["rows"]
    assert sorted((r["algo"], r["seeds"], r["episodes"]) for r in rows) == [("idm_mobil", [0], 2), ("kddrl", [0], 2)]

    # resume=true on Ray as on any launcher: finished jobs are skipped, their records untouched
    before = (kddrl / "eval_episodes.csv").stat().st_mtime_ns
    # (each job's own log, Hydra's ``train.log`` in its folder: Ray forwards a worker's output to the driver
    # asynchronously, and lines of a worker that ends just before ``ray.shutdown`` may never reach it)
    run_module(cmd + ["resume=true"], tmp_path)
    for job in jobs:
        log = (sweep / job / "train.log").read_text()
        assert log.count("is finished (summary.json): skipped") == 1, f"{job}: {log[-2000:]}"
    assert (kddrl / "eval_episodes.csv").stat().st_mtime_ns == before


@pytest.mark.ray
def test_a_sweep_over_seed_batches_on_local_ray(tmp_path):
    """``-m 'seeds=[0,1],[2,3]'`` on Ray: a job per batch, each writing its batch folder and its seeds' run folders
    as a batch run alone does, and the report reads the four seeds as one system's."""
    pytest.importorskip("ray")
    sweep = tmp_path / "sweep"
    cmd = [
        "kddrl_trl.train",
        "-m",
        "seeds=[0,1],[2,3]",
        "+scenario=braking",
        "hydra/launcher=ray",
        "+hydra.launcher.init.num_cpus=1",
        f"hydra.sweep.dir={sweep}",
        *TINY,
    ]
    done = run_module(cmd, tmp_path)
    assert "is launching 2 jobs" in done.stdout + done.stderr
    batches = sorted(p.name for p in sweep.iterdir() if p.is_dir())
    assert batches == ["braking__kddrl__seeds0-1", "braking__kddrl__seeds2-3"]
    for batch, seeds in zip(batches, ([0, 1], [2, 3])):
        assert json.loads((sweep / batch / "seed_batch.json").read_text())["seeds"] == seeds
        for seed in seeds:
            summary = json.loads((sweep / batch / f"braking__kddrl__{seed}" / "summary.json").read_text())
            assert summary["seed"] == seed and summary["training"]["episodes"] == 3 and summary["episodes"] == 2
    run_module(["kddrl_trl.report", str(sweep), f"out={tmp_path / 'rep'}"], tmp_path)
    rows = json.loads((tmp_path / "rep" / "report.json").read_text())["rows"]
    assert [(r["algo"], r["seeds"]) for r in rows] == [("kddrl", [0, 1, 2, 3])]


@pytest.mark.ray
def test_training_collects_on_two_ray_actors(tmp_path):
    """``collector.backend=ray collector.workers=2``: TorchRL's Ray collector, one SUMO per actor, both buffers and
    the macro-transition writer in the learner process; the run trains, checkpoints and evaluates as any other."""
    pytest.importorskip("ray")
    tiny = [t for t in TINY if not t.startswith(("train.eval_every", "train.eval_episodes"))]
    run_module(
        [
            "kddrl_trl.train",
            "collector.backend=ray",
            "collector.workers=2",
            "train.eval_every=0",
            "hydra.run.dir=run",
            *tiny,
        ],
        tmp_path,
    )
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["training"]["episodes"] == 3 and summary["training"]["frames"] > 0
    assert summary["training"]["decisions"] > 0 and summary["training"]["lc_updates"] > 0
    assert len(summary["protocol"]["worker_seeds"]) == 2
    assert len(pd.read_csv(tmp_path / "run" / "train_episodes.csv")) == 3
    assert (tmp_path / "run" / "checkpoints" / "latest").read_text().strip() == "ep000003.pt"


# ------------------------------------------------------------------------- refusals (no Ray needed: default run)
def _launcher(**kwargs):
    from hydra_plugins.kddrl_trl_ray_launcher.ray_launcher import RayLauncher

    return RayLauncher(**kwargs)


def test_without_ray_the_launcher_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails, as where the extra is not installed
    with pytest.raises(ImportError, match=r"\.\[ray\]"):
        _launcher().setup(hydra_context=None, task_function=None, config=None)


@pytest.mark.parametrize(
    "kwargs, key",
    [
        ({"num_cpus": 0}, "hydra.launcher.num_cpus=0"),
        ({"num_gpus": -1}, "hydra.launcher.num_gpus=-1"),
        ({"num_cpus": "two"}, "hydra.launcher.num_cpus='two'"),
        ({"init": {"address": "auto"}}, "hydra.launcher.init.address='auto'"),
    ],
)
def test_bad_launcher_values_are_refused_naming_the_key(kwargs, key):
    from hydra_plugins.kddrl_trl_ray_launcher._core import init_kwargs

    with pytest.raises(ValueError, match=key.replace(".", r"\.").replace("[", r"\[")):
        init_kwargs(_launcher(**kwargs))


def test_launcher_config_is_registered_and_reaches_ray_init():
    from hydra import compose, initialize_config_module

    from hydra_plugins.kddrl_trl_ray_launcher._core import init_kwargs

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        cfg = compose(
            config_name="config",
            overrides=[
                "hydra/launcher=ray",
                "hydra.launcher.address=auto",
                "hydra.launcher.num_cpus=2",
                "+hydra.launcher.init.log_to_driver=false",
            ],
            return_hydra_config=True,
        )
    launcher = cfg.hydra.launcher
    assert launcher._target_ == "hydra_plugins.kddrl_trl_ray_launcher.ray_launcher.RayLauncher"
    assert (launcher.num_cpus, launcher.num_gpus) == (2, 0)
    ray_init = init_kwargs(_launcher(address=launcher.address, num_cpus=launcher.num_cpus, init=launcher.init))
    assert ray_init == {"address": "auto", "log_to_driver": False}
    assert init_kwargs(_launcher()) == {"include_dashboard": False}  # no address: a local Ray, no dashboard
    assert init_kwargs(_launcher(init={"include_dashboard": True})) == {"include_dashboard": True}


@pytest.mark.ray
def test_the_scale_out_benchmark_runs_at_its_smallest_size(tmp_path):
    """``benchmarks/scale_out.py`` as a user runs it, at its smallest size: a one-run sweep (IDM+MOBIL, one episode)
    sequentially and on a local Ray of one CPU, and collection on one and two Ray actors of one road; it ends without
    an error and writes both ratios."""
    pytest.importorskip("ray")
    import os
    import subprocess
    from pathlib import Path

    out = tmp_path / "scale_out.json"
    cmd = [sys.executable, "-m", "benchmarks.scale_out", "--algos", "idm_mobil", "--seeds", "0", "--episodes", "1"]
    cmd += ["--eval-episodes", "1", "--ray-cpus", "1", "--collect-roads", "1", "--collect-frames", "20"]
    root, env = Path(__file__).resolve().parents[1], {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run([*cmd, "--out", str(out)], cwd=root, capture_output=True, text=True, timeout=1800, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(out.read_text())
    assert result["sweep_time_ratio"] > 0 and result["collect_scaling"] > 0
