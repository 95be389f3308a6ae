"""A job's torch threads (kddrl_trl.threads): a fixed count, OMP_NUM_THREADS, the free cores under ``auto``, a
governor that follows the machine while the job trains and warns once when it is busy, a real reading of another
busy process, and a run's records that do not depend on the count."""

from __future__ import annotations

import csv
import io
import json
import logging
import subprocess
import sys
import time

import pytest
import torch
from testkit import TINY_BUDGET

from kddrl_trl import threads


@pytest.fixture(autouse=True)
def _keep_torch_threads(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def _machine(monkeypatch, cores: int, elsewhere: float):
    monkeypatch.setattr(threads, "cores", lambda: cores)
    monkeypatch.setattr(threads, "busy_elsewhere", lambda: elsewhere)


def test_a_fixed_count_or_omp_num_threads_is_taken_as_it_is(monkeypatch):
    _machine(monkeypatch, 8, 7.0)
    assert threads.choose_threads(3).threads == 3 and threads.choose_threads(3).reason == "torch_threads"
    monkeypatch.setenv("OMP_NUM_THREADS", "5")
    assert threads.choose_threads("auto").threads == 5 and threads.choose_threads("auto").reason == "OMP_NUM_THREADS"
    monkeypatch.setenv("OMP_NUM_THREADS", "many")
    with pytest.raises(ValueError, match="OMP_NUM_THREADS='many'"):
        threads.choose_threads("auto")
    with pytest.raises(ValueError, match="positive integer"):
        threads.choose_threads(0)


@pytest.mark.parametrize(
    ("cores", "elsewhere", "workers", "expected", "busy"),
    [
        (2, 0.0, 0, 2, False),
        (2, 1.0, 0, 1, False),  # one other job: a core each
        (2, 0.2, 0, 2, False),  # a thread runnable in one sample of five holds no core
        (2, 3.0, 0, 1, True),
        (8, 2.6, 1, 4, False),  # three busy cores and the job's own overlapped worker
        (8, 0.0, 0, 8, False),
    ],
)
def test_auto_takes_the_cores_other_work_leaves_free(monkeypatch, cores, elsewhere, workers, expected, busy):
    _machine(monkeypatch, cores, elsewhere)
    choice = threads.choose_threads("auto", workers=workers)
    assert choice.threads == expected and choice.reason == "free cores" and choice.busy == busy


def test_the_governor_follows_the_machine_and_warns_once(monkeypatch, caplog):
    now = [0.0]
    load = [0.0]
    monkeypatch.setattr(threads, "cores", lambda: 2)
    monkeypatch.setattr(threads, "busy_elsewhere", lambda: load[0])
    with caplog.at_level(logging.INFO, logger="kddrl_trl.threads"):
        gov = threads.ThreadGovernor("auto", clock=lambda: now[0])
        assert gov.choice.threads == 2 and torch.get_num_threads() == 2
        load[0] = 1.0  # another job starts beside it
        gov.tick()
        assert torch.get_num_threads() == 2  # not read again before RECHECK_S
        now[0] += threads.RECHECK_S
        gov.tick()
        assert gov.choice.threads == 1 and torch.get_num_threads() == 1 and gov.changes == 1
        load[0] = 2.0
        now[0] += threads.RECHECK_S
        gov.tick()
        load[0] = 0.0  # it ended: the second thread comes back
        now[0] += threads.RECHECK_S
        gov.tick()
    assert gov.choice.threads == 2 and gov.changes == 2
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "busy" in warnings[0].getMessage() and "torch_threads=N" in warnings[0].getMessage()
    assert gov.record()["changes"] == 2 and gov.record()["setting"] == "auto"
    fixed = threads.ThreadGovernor(1, clock=lambda: now[0])
    now[0] += threads.RECHECK_S
    fixed.tick()
    assert torch.get_num_threads() == 1 and not fixed.adaptive


def test_another_busy_process_is_seen_and_this_ones_threads_are_not():
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)
        assert threads.busy_elsewhere() >= 0.6  # the spinner is runnable in (nearly) every sample
    finally:
        spinner.kill()
        spinner.wait()


def test_a_runs_records_are_the_same_at_one_and_two_threads(tmp_path):
    """The training records of a short real-SUMO run (default network sizes) are byte-identical at 1 and 2 torch
    threads, so ``auto`` may follow the machine, and its final evaluation's agree to 1e-6 (byte-identical on the
    Intel Xeon; on an AMD EPYC with AVX-512 the greedy evaluation's floats part at about 1e-8 between the two thread
    counts, measured); ``summary.json`` records the choice."""
    records = {}
    for n in (1, 2):
        out = tmp_path / f"t{n}"
        cmd = [sys.executable, "-m", "kddrl_trl.train", "episodes=2", "eval_episodes=1", f"torch_threads={n}"]
        budget = [o for o in TINY_BUDGET if not o.startswith("train.batch_size_cf")]  # the default batch of 128
        done = subprocess.run(
            [*cmd, *budget, f"hydra.run.dir={out}"], cwd=tmp_path, capture_output=True, text=True, timeout=600
        )
        assert done.returncode == 0, done.stderr[-3000:]
        summary = json.loads((out / "summary.json").read_text())
        assert summary["torch_threads"]["threads"] == n and summary["torch_threads"]["reason"] == "torch_threads"
        records[n] = [(out / f).read_bytes() for f in ("train_episodes.csv", "eval_episodes.csv")]
    assert records[1][0] == records[2][0]
    one, two = (list(csv.DictReader(io.StringIO(r[1].decode()))) for r in (records[1], records[2]))
    assert len(one) == len(two) and one
    for a, b in zip(one, two):
        assert a.keys() == b.keys()
        for k in a:
            try:
                x, y = float(a[k]), float(b[k])
            except ValueError:
                assert a[k] == b[k], k
                continue
            assert x == y or abs(x - y) <= 1e-6 * max(abs(x), abs(y)), (k, x, y)
