"""A training job run as a user runs it, timed: the shared step of the benchmarks that time whole jobs
(``default_job.py``, ``compile_cost.py``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path


def timed_train_job(out: Path, overrides: list[str], env: dict[str, str] | None = None) -> dict:
    """``python -m kddrl_trl.train progress=false hydra.run.dir=<out> <overrides>`` in ``out`` 's parent folder, one
    torch thread unless ``OMP_NUM_THREADS`` says otherwise, with ``env`` added to the environment. Returns the
    process's wall time (``process_s``) and the run's ``summary.json`` (``summary``); a failed job raises, with the end
    of its standard error."""
    full_env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1"), **(env or {})}
    cmd = [sys.executable, "-m", "kddrl_trl.train", "progress=false", f"hydra.run.dir={out}", *overrides]
    started = time.perf_counter()
    done = subprocess.run(cmd, cwd=out.parent, env=full_env, capture_output=True, text=True)
    elapsed = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed in {out}:\n{done.stderr[-3000:]}")
    return {"process_s": elapsed, "summary": json.loads((out / "summary.json").read_text())}
