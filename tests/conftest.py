"""The suite's fixtures and settings (shared helpers: testkit.py)."""

from __future__ import annotations

import os
import tempfile

import pytest
import torch

# keep the network cache of the tests away from the user's cache, but share it between tests
os.environ.setdefault("KDDRL_TRL_CACHE", os.path.join(tempfile.gettempdir(), "kddrl_trl_test_cache"))
torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def no_flush_to_zero_left_behind():
    """A job run in the test process sets the CPU's flush-to-zero mode (``flush_denormal=true``, the default) for the
    whole process; each test leaves it off, as a process starts, so that a later test on the same worker (the
    property tests' float strategies, which refuse to run without subnormal floats) does not depend on the order."""
    yield
    torch.set_flush_denormal(False)


@pytest.fixture
def no_sumo_open():
    """Every test that opens a SUMO env must leave none open behind it."""
    from kddrl_trl.envs import sim

    yield
    assert sim._ACTIVE is None, "a test left a SUMO simulation open"
