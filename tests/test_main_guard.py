"""``require_main_guard``: a script that would start worker processes from module-level code outside an
``if __name__ == "__main__":`` block is told so, with its file and line, before any worker starts (a spawned worker
imports the script again and runs that code; TorchRL's multi-process collector would then wait for it forever)."""

from __future__ import annotations

import pytest
from testkit import run_script


def test_unguarded_main_call_finds_the_script_line_outside_the_guard(tmp_path):
    done = run_script(
        tmp_path,
        """
        from kddrl_trl.main_guard import unguarded_main_call

        def start():
            return unguarded_main_call()

        print("outside", start())
        if __name__ == "__main__":
            print("inside", start())
        if "__main__" == __name__:
            print("reversed", start())
        print("later", start())
        """,
    )
    assert done.returncode == 0, done.stderr
    lines = dict(line.split(" ", 1) for line in done.stdout.splitlines())
    path = str(tmp_path / "script.py")
    assert lines["outside"] == repr((path, 7))
    assert lines["inside"] == "None"
    assert lines["reversed"] == "None"
    assert lines["later"] == repr((path, 12))


def test_a_call_that_is_not_from_a_script_passes():
    """Under pytest (a guarded entry point, or an xdist worker, whose ``__main__`` has no script), nothing is
    refused."""
    from kddrl_trl.main_guard import require_main_guard, unguarded_main_call

    assert unguarded_main_call() is None
    require_main_guard("anything")


@pytest.mark.parametrize("option", ["workers", "sync"])
def test_a_collector_with_worker_processes_in_an_unguarded_script_is_refused_before_it_starts(tmp_path, option):
    """Without the check the script never ends: the spawned workers die on the script's own line, and TorchRL's
    collector waits for their first message forever (the subprocess timeout fails the test)."""
    factories = "[make, make]" if option == "workers" else "[make]"
    done = run_script(
        tmp_path,
        f"""
        from functools import partial
        from kddrl_trl.baselines.random_policy import RandomDrivingPolicy
        from kddrl_trl.collectors import MultiTimescaleCollector
        from kddrl_trl.envs import FakeHighwayEnv

        make = partial(FakeHighwayEnv, num_roads=1, seed=0)
        MultiTimescaleCollector.from_env(
            {factories}, RandomDrivingPolicy(), frames_per_env=2, rows=1, sync={option == "workers"}
        )
        """,
        timeout=120,
    )
    assert done.returncode != 0
    expected = "collector.workers=2" if option == "workers" else "collector.sync=false"
    assert f"script.py, line 8: {expected} spawns worker processes" in done.stderr
    assert "Put that code under the guard" in done.stderr
