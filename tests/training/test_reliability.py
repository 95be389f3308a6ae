"""Reliability: damaged checkpoints, a writer killed mid-write, refused configs leaving no run folder, and
faults injected into the simulator and the observations."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest
import torch

from kddrl_trl.run_folder import checkpoint_candidates, latest_checkpoint
from kddrl_trl.training import (
    CheckpointError,
    load_latest_training_checkpoint,
    load_training_checkpoint,
    save_training_checkpoint,
)


def _three_checkpoints(run_dir):
    for episodes in (2, 4, 6):
        save_training_checkpoint(run_dir, episodes, {"episodes": episodes, "w": torch.full((8,), float(episodes))})
    return run_dir / "checkpoints"


def _truncate(path):
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _garble(path):
    path.write_bytes(os.urandom(path.stat().st_size))


def test_the_last_two_checkpoints_are_kept(tmp_path):
    folder = _three_checkpoints(tmp_path)
    assert sorted(p.name for p in folder.glob("ep*.pt")) == ["ep000004.pt", "ep000006.pt"]
    assert [p.name for p in checkpoint_candidates(tmp_path)] == ["ep000006.pt", "ep000004.pt"]
    path, payload = load_latest_training_checkpoint(tmp_path)
    assert path.name == "ep000006.pt" and payload["episodes"] == 6


@pytest.mark.parametrize("damage", [_truncate, _garble], ids=["truncated", "garbage"])
def test_a_damaged_newest_checkpoint_falls_back_to_the_previous_with_a_warning(tmp_path, caplog, damage):
    folder = _three_checkpoints(tmp_path)
    damage(folder / "ep000006.pt")
    with pytest.raises(CheckpointError, match="ep000006.pt: cannot be loaded"):
        load_training_checkpoint(folder / "ep000006.pt")
    with caplog.at_level(logging.WARNING):
        path, payload = load_latest_training_checkpoint(tmp_path)
    assert path.name == "ep000004.pt" and payload["episodes"] == 4
    warned = caplog.text
    assert "ep000006.pt: cannot be loaded" in warned and "resuming from" in warned and "ep000004.pt" in warned

    damage(folder / "ep000004.pt")  # none loads: one error listing each file and its cause
    with pytest.raises(CheckpointError) as err:
        load_latest_training_checkpoint(tmp_path)
    message = str(err.value)
    assert "no checkpoint of" in message and "ep000006.pt: cannot be loaded" in message
    assert "ep000004.pt: cannot be loaded" in message


def test_a_missing_or_dangling_latest_pointer_still_finds_the_checkpoints(tmp_path):
    folder = _three_checkpoints(tmp_path)
    (folder / "latest").write_text("ep000099.pt\n")
    assert latest_checkpoint(tmp_path).name == "ep000006.pt"
    (folder / "latest").unlink()
    assert load_latest_training_checkpoint(tmp_path)[1]["episodes"] == 6
    with pytest.raises(FileNotFoundError, match="no checkpoint in"):
        load_latest_training_checkpoint(tmp_path / "elsewhere")


WRITER = textwrap.dedent("""
    import sys, torch
    from kddrl_trl.training import save_training_checkpoint
    episodes = 0
    while True:
        episodes += 1
        save_training_checkpoint(sys.argv[1], episodes, {"episodes": episodes, "w": torch.randn(4_000_000)})
        print(episodes, flush=True)
""")


def test_kill_9_during_a_checkpoint_write_leaves_a_loadable_checkpoint(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        for _ in range(3):  # a few complete checkpoints, then kill at an arbitrary point of the next writes
            assert proc.stdout.readline(), "the writer died"
        time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    path, payload = load_latest_training_checkpoint(tmp_path)
    assert payload["episodes"] >= 3 and path.name == f"ep{payload['episodes']:06d}.pt"
    save_training_checkpoint(tmp_path, 100, {"episodes": 100})  # the next save sweeps a killed write's temp file
    assert not list((tmp_path / "checkpoints").glob(".*.tmp"))


def test_the_next_checkpoint_save_sweeps_every_killed_writes_temp_file(tmp_path):
    """A kill can land in any of the three atomic writes (a checkpoint, ``latest``, ``best.pt``): each leaves its
    own temp file, and the next save removes them all (the kill test above hits the ``latest`` case rarely)."""
    stale = [".ep000003.pt.k1.tmp", ".latest.k2.tmp", ".best.pt.k3.tmp"]
    (tmp_path / "checkpoints").mkdir()
    for name in stale:
        (tmp_path / "checkpoints" / name).write_bytes(b"half a file")
    save_training_checkpoint(tmp_path, 4, {"episodes": 4})
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == ["ep000004.pt", "latest"]


@pytest.mark.parametrize(
    "override, sweep",
    [
        ("env.flow_vph=-1", []),
        ("env.flow_vphh=3", []),
        ("train.batch_size_cf=0", []),
        ("env.flow_vph=-1", ["-m", "seed=0,1"]),
    ],
)
def test_a_refused_config_leaves_no_run_folder(tmp_path, override, sweep):
    cmd = [sys.executable, "-m", "kddrl_trl.train", *sweep, override, "episodes=1", "progress=false"]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and override.split("=")[0].split(".")[-1] in done.stderr, done.stderr
    assert not list(tmp_path.glob("runs/*")), list(tmp_path.rglob("*"))


def test_a_refused_resumed_run_keeps_its_folder(tmp_path):
    from kddrl_trl.run_folder import remove_refused_run_dir

    run = tmp_path / "runs" / "baseline__kddrl__0__x"
    (run / ".hydra").mkdir(parents=True)
    (run / "train.log").write_text("")
    (run / "config.yaml").write_text("seed: 0\n")
    assert not remove_refused_run_dir(run) and run.is_dir()
    (run / "config.yaml").unlink()
    assert remove_refused_run_dir(run) and not run.exists()


# ---------------------------------------------------------------------------------------- faults in the simulator
def _sumo_env(num_roads=4):
    from kddrl_trl.envs import SumoHighwayEnv

    return SumoHighwayEnv("baseline", num_roads=num_roads, seed=0)


def _fail_for(monkeypatch, name, vid, result=None):
    """Make ``libsumo.vehicle.<name>`` raise a TraCIException for vehicle ``vid`` (or return ``result`` for it)."""
    import libsumo

    real = getattr(libsumo.vehicle, name)

    def patched(v, *args):
        if v != vid:
            return real(v, *args)
        if result is not None:
            return result
        raise libsumo.TraCIException(f"injected fault in {name}({v})")

    monkeypatch.setattr(libsumo.vehicle, name, staticmethod(patched))


@pytest.mark.parametrize("call", ["setSpeed", "getLateralSpeed", "getLeader"])
def test_a_sumo_fault_mid_episode_truncates_that_road_as_lost_and_the_others_go_on(
    monkeypatch, caplog, no_sumo_open, call
):
    from kddrl_trl import keys as K
    from kddrl_trl.baselines import IDMMobilPolicy
    from kddrl_trl.eval import EpisodeTracker

    env, policy = _sumo_env(), IDMMobilPolicy()
    try:
        td, frames = env.reset(), []
        for _ in range(3):
            full, td = env.step_and_maybe_reset(policy(td))
            frames.append(full)
        with monkeypatch.context() as m, caplog.at_level(logging.WARNING):
            _fail_for(m, call, env.sim.ego[1])  # setSpeed: commanding; the getters: observing
            full, td = env.step_and_maybe_reset(policy(td))
        frames.append(full)
        done = full["next", "done"].reshape(-1).tolist()
        assert full["next", "truncated"][1].item() and not full["next", "terminated"][1].item()
        assert full["next", *K.OUTCOME][1].item() == K.LOST and done.count(True) == 1
        assert env.stats["sumo_errors"] == 1 and "injected fault" in caplog.text
        episodes = EpisodeTracker()(torch.stack(frames, 1))
        assert [(e["road"], e["outcome"]) for e in episodes] == [(1, "lost")]  # counted as lost, once
        for _ in range(30):  # every road runs on, road 1 with a new ego
            full, td = env.step_and_maybe_reset(policy(td))
        assert env.sim.ego[1] is not None and env.stats["sumo_errors"] == 1
    finally:
        env.close()


def test_a_nan_from_sumo_is_refused_naming_the_key(monkeypatch, no_sumo_open):
    from kddrl_trl.baselines import IDMMobilPolicy
    from kddrl_trl.envs.observe import NonFiniteObservation

    env, policy = _sumo_env(2), IDMMobilPolicy()
    try:
        td = env.reset()
        full, td = env.step_and_maybe_reset(policy(td))
        neighbour = next(v for v in env.sim.observer.slots[0] if v)  # its acceleration is in ("neighbors","kin")
        _fail_for(monkeypatch, "getAcceleration", neighbour, result=float("nan"))
        with pytest.raises(NonFiniteObservation, match=r"\('neighbors', 'kin'\) on road\(s\) \[0"):
            env.step(policy(td))
    finally:
        env.close()


@pytest.mark.slow  # a full KDDRL trainer (136 s in a contended full run); the fallback itself is tested on files above
def test_a_trainer_resumes_from_the_previous_checkpoint_when_the_newest_is_truncated(tmp_path, caplog):
    from testkit import compose_job, fake_trainer

    job = compose_job(
        "env.num_roads=2", "compile=false", "algo.learner.d3qn.hidden=[16]", "algo.learner.td3.hidden=[16]"
    )
    small = dict(warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10, checkpoint_every=1)
    env, _, trainer, collector = fake_trainer(job, tmp_path, **small)
    trainer.run(collector)
    env.close()
    assert [p.name for p in checkpoint_candidates(tmp_path)] == ["ep000003.pt", "ep000002.pt"]
    _truncate(tmp_path / "checkpoints" / "ep000003.pt")
    env, _, again, _ = fake_trainer(job, tmp_path, **small)
    env.close()
    with caplog.at_level(logging.WARNING):
        assert again.load(tmp_path) == 2 and len(again.history) == 2
    assert "ep000003.pt: cannot be loaded" in caplog.text
