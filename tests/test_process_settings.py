"""A job's process-wide torch arithmetic (``matmul_precision``, ``flush_denormal``): applied by the job, and by every
process it starts (the collection workers' and the validation worker's env factories), whatever the process had."""

from __future__ import annotations

import logging
from functools import partial

import pytest
import torch

from kddrl_trl.collectors.workers import WorkerEnv
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.eval.periodic import PeriodicEvaluator
from kddrl_trl.process_settings import TorchSettings, apply_flush_denormal

#: not torch's defaults in either setting
OTHER = TorchSettings("high", False)


@pytest.fixture
def restored():
    """The test process's settings, put back afterwards."""
    before = TorchSettings.in_force()
    yield before
    before.apply()


def compose_job(*overrides: str):
    from hydra import compose, initialize_config_module

    from kddrl_trl.factories import make_job

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        return make_job(compose(config_name="config", overrides=list(overrides)))


def test_settings_are_applied_and_read_back(restored):
    for settings in (OTHER, TorchSettings("highest", True), TorchSettings("medium", False)):
        settings.apply()
        assert TorchSettings.in_force() == settings


def test_a_cpu_without_flush_to_zero_is_warned_about_and_runs_on(monkeypatch, caplog, restored):
    monkeypatch.setattr(torch, "set_flush_denormal", lambda on: False)  # a CPU without the mode
    with caplog.at_level(logging.WARNING, logger="kddrl_trl.process_settings"):
        assert apply_flush_denormal(False) is False
        assert not caplog.records  # off: nothing to warn about
        assert apply_flush_denormal(True) is False
    assert [r.getMessage() for r in caplog.records] == [
        "flush_denormal=true: this CPU has no flush-to-zero mode; denormals kept"
    ]


def test_a_worker_env_applies_the_settings_before_it_builds_the_env(restored):
    seen = []

    def make(seed):
        seen.append((seed, TorchSettings.in_force()))
        return seed

    TorchSettings().apply()  # the defaults of a job
    assert WorkerEnv(make, 3, seed_torch=False, settings=OTHER)() == 3
    assert seen == [(3, OTHER)]
    TorchSettings().apply()
    WorkerEnv(make, 4, seed_torch=False)()  # no settings: the process keeps its own
    assert seen[-1] == (4, TorchSettings())


def test_every_worker_of_a_job_gets_the_jobs_settings(restored):
    """The collection workers' env factories and the validation worker's carry the job's keys, not the defaults."""
    from kddrl_trl.factories import make_env_factories, make_evaluator

    job = compose_job("matmul_precision=high", "flush_denormal=false", "collector.workers=2")
    assert TorchSettings.in_force() == OTHER  # the job's own process
    factories = make_env_factories(job, seed=0, fake=True)
    assert [f.settings for f in factories] == [OTHER, OTHER]
    evaluator = make_evaluator(job)
    try:
        assert evaluator.make_env.settings == OTHER
    finally:
        evaluator.close()


def test_the_validation_worker_process_computes_under_the_jobs_settings(restored):
    """A spawned worker starts with torch's defaults; its env factory applies the job's settings there."""
    TorchSettings().apply()
    make = WorkerEnv(partial(FakeHighwayEnv, num_roads=1), 0, seed_torch=False, settings=OTHER)
    evaluator = PeriodicEvaluator(make, episodes=1, seed=5)
    try:
        from kddrl_trl.baselines.random_policy import RandomDrivingPolicy

        evaluator(RandomDrivingPolicy(generator=torch.Generator().manual_seed(0)))
        assert evaluator.pool.submit(TorchSettings.in_force).result(timeout=60) == OTHER
        assert TorchSettings.in_force() == TorchSettings()  # the training process keeps its own
    finally:
        evaluator.close()
