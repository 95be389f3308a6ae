"""Collection worker processes (``collector.workers``, issue 15 "Worker processes"): N envs through TorchRL's
multi-process collector feeding the learner's two buffers, seeded per worker, acting with the learner's weights and
exploration state."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import cloudpickle
import pytest
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from testkit import TINY as KDDRL_TINY

from kddrl_trl import keys as K
from kddrl_trl.collectors.workers import WorkerEnv
from kddrl_trl.protocol import MAX_WORKERS, WORKER_OFFSET, protocol

#: what the probe writes into every frame: the ε and σ the acting policy used, and a checksum of its weights
PROBE_EPS, PROBE_SIGMA, PROBE_W = ("probe", "eps"), ("probe", "sigma"), ("probe", "weights")


def compose_job(*overrides: str):
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        return OmegaConf.to_object(compose(config_name="config", overrides=list(overrides)))


def weights_checksum(policy) -> float:
    return float(sum(p.detach().double().sum() for p in policy.parameters()))


class ExplorationProbe(TensorDictModuleBase):
    """The acting policy, then the ε of its ε-greedy module, the σ of its Gaussian noise and a checksum of its
    weights written into every row (read where the policy runs: in a worker process)."""

    def __init__(self, policy: TensorDictModuleBase):
        super().__init__()
        self.policy = policy
        self.in_keys = list(policy.in_keys)
        self.out_keys = [*policy.out_keys, PROBE_EPS, PROBE_SIGMA, PROBE_W]

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        td = self.policy(td)
        eps = next(m.eps for m in self.policy.modules() if hasattr(m, "eps_end"))
        sigma = next(m.sigma for m in self.policy.modules() if hasattr(m, "sigma_end"))
        shape = (*td.batch_size, 1)
        td.set(PROBE_EPS, eps.detach().double().expand(shape).clone())
        td.set(PROBE_SIGMA, sigma.detach().double().expand(shape).clone())
        td.set(PROBE_W, torch.full(shape, weights_checksum(self.policy), dtype=torch.float64))
        return td


class RecordingCollector:
    """Passes a :class:`~kddrl_trl.collectors.MultiTimescaleCollector` 's batches to the trainer and records them,
    with the learner's ε, σ and weights checksum once the trainer has processed each (updates and weight sync
    done: when it asks for the next batch)."""

    def __init__(self, mtc, learner):
        self.mtc, self.learner, self.batches, self.after = mtc, learner, [], []
        self.writer = mtc.writer

    def __iter__(self):
        for batch in self.mtc:
            self.batches.append(batch)
            yield batch
            self.after.append(self.learner_state())

    def learner_state(self) -> tuple[float, float, float]:
        learner = self.learner
        return (
            float(learner.lc_explore.eps),
            float(learner.cf_explore.sigma),
            weights_checksum(learner.policy(explore=True)),
        )

    def update_policy_weights_(self) -> None:
        self.mtc.update_policy_weights_()

    def shutdown(self, close_env: bool = True) -> None:
        self.mtc.shutdown(close_env=close_env)


def test_worker_env_factories_have_distinct_documented_reproducible_seeds():
    from kddrl_trl.factories import make_env_factories

    job = compose_job("collector.workers=3", "compile=false")
    factories = make_env_factories(job, seed=7)
    assert [f.seed for f in factories] == [7, 7 + WORKER_OFFSET, 7 + 2 * WORKER_OFFSET]
    assert all(f.seed_torch for f in factories)  # worker processes start with torch's fixed default seed
    assert [f.seed for f in make_env_factories(job, seed=7)] == [f.seed for f in factories]  # same seed, same seeds
    assert [f.seed for f in make_env_factories(job, seed=8)] == [8, 8 + WORKER_OFFSET, 8 + 2 * WORKER_OFFSET]
    # what a spawned worker receives (TorchRL pickles env factories with cloudpickle: the algo schemas are made by
    # dataclasses.make_dataclass, which the standard pickle cannot find by name)
    # (loaded in a fresh process, as a worker does: cloudpickle loading classes pickled by value back into the
    # process that defined them rewrites those classes, which broke later tests of the same pytest worker)
    loaded = subprocess.run(
        [sys.executable, "-c", "import pickle, sys; print([f.seed for f in pickle.loads(sys.stdin.buffer.read())])"],
        input=cloudpickle.dumps(factories),
        capture_output=True,
        check=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    assert loaded.stdout.decode().strip() == str([f.seed for f in factories])
    (single,) = make_env_factories(compose_job("compile=false"), seed=7)
    assert single.seed == 7 and not single.seed_torch  # the learner process's env: as before, torch left alone
    assert protocol(7, 10, None, 1, workers=3)["worker_seeds"] == [f.seed for f in factories]
    assert "worker_seeds" not in protocol(7, 10, None, 1)


def _fake_env(seed: int):
    return seed


def test_a_worker_env_seeds_the_torch_generator_of_its_process():
    a = WorkerEnv(_fake_env, 11)
    assert a() == 11
    first = torch.rand(3)
    assert a() == 11 and torch.equal(torch.rand(3), first)  # the same exploration draws from the same seed
    WorkerEnv(_fake_env, 12)()
    assert not torch.equal(torch.rand(3), first)
    torch.manual_seed(5)
    WorkerEnv(_fake_env, 11, seed_torch=False)()
    expected = torch.Generator().manual_seed(5)
    assert torch.equal(torch.rand(3), torch.rand(3, generator=expected))


@pytest.mark.parametrize(
    "override, match",
    [
        ("collector.workers=0", "collector.workers must be >= 1, got 0"),
        (f"collector.workers={MAX_WORKERS + 1}", f"collector.workers must be <= {MAX_WORKERS}"),
        ("collector.backend=threads", "collector.backend must be one of process, ray, got 'threads'"),
        (
            "collector.sync=false collector.workers=2",
            "collector.sync=false runs one worker process: it needs "
            "collector.workers=1 and collector.backend=process, got workers=2",
        ),
    ],
)
def test_bad_collector_values_are_refused_naming_the_key(override, match):
    with pytest.raises(ValueError, match=match):
        compose_job(*override.split())


def test_the_ray_backend_without_ray_names_the_extra():
    import importlib.util

    if importlib.util.find_spec("ray") is not None:
        pytest.skip("ray is installed here")
    with pytest.raises(ValueError, match=r"collector.backend=ray needs Ray.*pip install '\.\[ray\]'"):
        compose_job("collector.backend=ray", "collector.workers=2")


def test_an_eval_seed_inside_a_workers_training_seeds_is_refused():
    with pytest.raises(ValueError, match=r"eval_seed=10003 lies in the training seeds .* \(collection worker 1\)"):
        compose_job("collector.workers=2", "eval_seed=10003", "episodes=10")
    compose_job("eval_seed=10003", "episodes=10")  # one worker: not a training seed


def probe_training(tmp_path, collector_override: str):
    """Trainer on the fake env (2 roads, tiny networks, σ annealed so that its sync is seen) with the collector of
    ``collector_override``, its acting policy wrapped in :class:`ExplorationProbe` and its batches recorded:
    (trainer, recorder, history, the learner's (ε, σ, weights checksum) before training, the collector)."""
    from dataclasses import replace

    from kddrl_trl.conf.schema import LoggerConfig
    from kddrl_trl.factories import make_buffers, make_collector, make_env_factories, make_learner, make_logger
    from kddrl_trl.training import Trainer

    job = compose_job(
        "env.num_roads=2",
        "compile=false",
        collector_override,
        "env.ego_start=window",
        "algo.learner.d3qn.hidden=[16]",
        "algo.learner.td3.hidden=[16]",
    )
    learner = make_learner(job.algo, compile=False)
    train = replace(
        job.train, warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10, checkpoint_every=1000
    )
    buffers = make_buffers(train, seed=0)
    trainer = Trainer(
        learner,
        buffers,
        train,
        tmp_path,
        make_logger(LoggerConfig(csv=True, tensorboard=False), tmp_path),
        episodes=6,
        progress=False,
    )
    step = learner.explore_step

    def explore_step(decisions, frames):  # also anneal σ (constant in kddrl.yaml), so that its sync is seen
        step(decisions, frames)
        learner.cf_explore.sigma.mul_(0.9)

    learner.explore_step = explore_step
    acting = learner.policy
    learner.policy = lambda explore=True: ExplorationProbe(acting(explore))
    before = (float(learner.lc_explore.eps), float(learner.cf_explore.sigma), weights_checksum(acting(True)))
    mtc = make_collector(
        make_env_factories(job, seed=0, fake=True),
        learner,
        buffers,
        train,
        job.algo.lc_reward,
        collector=job.collector,
        rows=job.env.num_roads,
    )
    learner.policy = acting
    recorder = RecordingCollector(mtc, learner)
    return trainer, recorder, trainer.run(recorder), before, mtc


@pytest.mark.slow  # two spawned worker processes importing torch / torchrl: ~45 s on the loaded 2-core machine
def test_two_workers_feed_both_buffers_in_a_stable_row_order_acting_with_the_learners_state(tmp_path):
    """Trainer + ``collector.workers=2`` on the fake env (2 roads each): batches ``[4, T]`` whose rows continue
    from one iteration to the next, every frame in buffer L and every macro-transition in buffer H, decisions
    counted as the single-process collector counts them, and each iteration's frames acted with the ε, σ and
    weights the learner had after the previous iteration's updates."""
    trainer, recorder, history, before, _ = probe_training(tmp_path, "collector.workers=2")

    batches = recorder.batches
    assert len(history) == 6 and len(batches) >= 3 and trainer.counters["cf_updates"] > 0
    frames = torch.cat([b.frames for b in batches], dim=1)
    assert frames.batch_size == (4, 10 * len(batches))  # 2 workers x 2 roads, worker-major
    # stable row order: each row's first frame of a batch continues its last frame of the previous one
    for prev, cur in zip(batches, batches[1:]):
        cont = ~prev.frames["next", "done"][:, -1, 0]
        assert cont.any()
        torch.testing.assert_close(cur.frames[K.EGO_STATE][:, 0][cont], prev.frames["next", *K.EGO_STATE][:, -1][cont])
    # the workers are distinct envs (their own seeds): their rows differ
    assert not torch.equal(frames[K.EGO_STATE][:2, 0], frames[K.EGO_STATE][2:, 0])
    # both buffers: every frame, every closed macro-transition
    macros = torch.cat([b.macros for b in batches if b.macros is not None])
    assert len(trainer.buffer_cf) == frames.numel() == trainer.counters["frames"]
    assert len(trainer.buffer_lc) == macros.numel() > 0
    # decisions: every episode decides on its first frame, then every lc_period frames; macros close on them
    period, decisions = compose_job().algo.lc_period, int(frames[K.LC_DECIDE].sum())
    assert trainer.counters["decisions"] == decisions
    assert frames.numel() / period <= decisions <= frames.numel()
    n = macros["next", K.LC_MACRO_FRAMES].squeeze(-1)
    assert ((n == period) | macros["next", "done"].squeeze(-1)).all() and trainer.collector.writer.dropped_frames == 0
    # the workers act with the learner's state as it was after the previous iteration's updates and sync
    states = [before, *recorder.after]
    for batch, (eps, sigma, checksum) in zip(batches, states):
        f = batch.frames
        assert torch.allclose(f[PROBE_EPS], torch.tensor(eps, dtype=torch.float64))
        assert torch.allclose(f[PROBE_SIGMA], torch.tensor(sigma, dtype=torch.float64))
        assert torch.allclose(f[PROBE_W], torch.tensor(checksum, dtype=torch.float64), rtol=1e-6)
    assert states[len(batches) - 1][0] < before[0] and states[len(batches) - 1][1] < before[1]  # ε and σ moved
    assert len({s[2] for s in states[: len(batches)]}) > 1  # and the weights were updated


@pytest.mark.slow  # a spawned worker process importing torch / torchrl
def test_overlapped_collection_acts_with_the_learners_state_of_two_batches_before(tmp_path):
    """``collector.sync=false`` on the fake env (2 roads, one worker process): the batches continue row by row
    and fill both buffers as the synchronous collector's do, and batch ``j`` was collected with the ε, σ and
    weights the learner had after its updates on batch ``j - 2`` (the worker collects batch ``j`` while the learner
    updates on batch ``j - 1``; the snapshot was taken when batch ``j - 1`` arrived), whatever the timing."""
    from kddrl_trl.collectors import OverlappedCollector

    trainer, recorder, history, before, mtc = probe_training(tmp_path, "collector.sync=false")
    assert isinstance(mtc.collector, OverlappedCollector)

    batches = recorder.batches
    assert len(history) == 6 and len(batches) >= 4 and trainer.counters["cf_updates"] > 0
    frames = torch.cat([b.frames for b in batches], dim=1)
    assert frames.batch_size == (2, 10 * len(batches))
    for prev, cur in zip(batches, batches[1:]):
        cont = ~prev.frames["next", "done"][:, -1, 0]
        torch.testing.assert_close(cur.frames[K.EGO_STATE][:, 0][cont], prev.frames["next", *K.EGO_STATE][:, -1][cont])
    assert len(trainer.buffer_cf) == frames.numel() == trainer.counters["frames"]
    states = [before, before, *recorder.after]  # batch j: the state after batch j - 2 (the first two: the initial one)
    for batch, (eps, sigma, checksum) in zip(batches, states):
        f = batch.frames
        assert torch.allclose(f[PROBE_EPS], torch.tensor(eps, dtype=torch.float64))
        assert torch.allclose(f[PROBE_SIGMA], torch.tensor(sigma, dtype=torch.float64))
        assert torch.allclose(f[PROBE_W], torch.tensor(checksum, dtype=torch.float64), rtol=1e-6)
    assert len({s[2] for s in states[: len(batches)]}) > 1  # the weights moved between batches
    # and not the synchronous collector's lag: batch j != the state after batch j - 1 once they differ
    lagged_one = [before, *recorder.after]
    assert any(float(b.frames[PROBE_W][0, 0, 0]) != pytest.approx(s[2], rel=1e-6) for b, s in zip(batches, lagged_one))


#: testkit's tiny KDDRL budget on SUMO, without periodic validation
TINY = [*KDDRL_TINY, "train.eval_every=0"]


@pytest.mark.slow  # two SUMO worker processes + the learner + the final evaluation
def test_kddrl_trains_with_two_sumo_workers_as_typed(tmp_path):
    cmd = [sys.executable, "-m", "kddrl_trl.train", "collector.workers=2", "episodes=4", "eval_episodes=2", *TINY]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    (run,) = list((tmp_path / "runs").glob("baseline__kddrl__0__*"))
    summary = json.loads((run / "summary.json").read_text())
    assert summary["protocol"]["worker_seeds"] == [0, WORKER_OFFSET]
    training = summary["training"]
    assert training["episodes"] == 4 and training["cf_updates"] > 0 and training["decisions"] > 0
    assert training["frames"] % (2 * 2 * 20) == 0  # whole iterations of 2 workers x 2 roads x frames_per_env
    assert (run / "train_episodes.csv").read_text().count("\n") == 5
    roads = {int(line.split(",")[2]) for line in (run / "train_episodes.csv").read_text().split()[1:]}
    assert roads <= {0, 1, 2, 3}  # rows of both workers
    assert summary["episodes"] == 2 and (run / "checkpoints" / "latest").read_text().strip() == "ep000004.pt"


@pytest.mark.slow  # two tiny runs on SUMO, each with a worker process
def test_an_overlapped_sumo_run_repeats_exactly(tmp_path):
    """``collector.sync=false`` trains on SUMO and the same seed gives the same training records twice (the
    snapshot is refreshed only between the worker's batches, so the timing of the two processes does not count)."""
    records = []
    for name in ("a", "b"):
        cmd = [
            sys.executable,
            "-m",
            "kddrl_trl.train",
            "collector.sync=false",
            "episodes=4",
            "eval_episodes=1",
            *TINY,
            f"hydra.run.dir={tmp_path / name}",
        ]
        done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr[-3000:]
        summary = json.loads((tmp_path / name / "summary.json").read_text())
        assert summary["training"]["episodes"] == 4 and summary["training"]["cf_updates"] > 0
        records.append((tmp_path / name / "train_episodes.csv").read_text())
    assert records[0] == records[1] and records[0].count("\n") == 5


def test_the_single_process_collector_closes_the_env_it_builds():
    """One factory, in this process: the collector builds the env and ``shutdown`` closes it, so the run's final
    evaluation can start its own SUMO (libsumo: one simulation per process; TorchRL's collector leaves a custom
    ``EnvBase`` open)."""
    from functools import partial

    from kddrl_trl.baselines import IDMMobilPolicy
    from kddrl_trl.collectors import MultiTimescaleCollector
    from kddrl_trl.envs import SumoHighwayEnv

    mtc = MultiTimescaleCollector.from_env(
        [partial(SumoHighwayEnv, "baseline", num_roads=1, seed=0)], IDMMobilPolicy(), frames_per_env=2, rows=1
    )
    assert isinstance(mtc.local_env, SumoHighwayEnv)
    mtc.shutdown(close_env=False)
    assert mtc.local_env is None
    SumoHighwayEnv("baseline", num_roads=1, seed=1).close()  # refused while the first simulation is open
