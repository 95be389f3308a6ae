"""A training job run as a user runs it, timed: the shared step of the benchmarks that time whole jobs
(``default_job.py``, ``compile_cost.py``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path


def train_command(out: Path, overrides: list[str]) -> list[str]:
    return [sys.executable, "-m", "kddrl_trl.train", "progress=false", f"hydra.run.dir={out}", *overrides]


def run_summaries(out: Path) -> list[dict]:
    """The ``summary.json`` of the run in ``out``, or of each seed of the seed batch there (``seed_batch.json``'s
    folders, in its seeds' order)."""
    batch = out / "seed_batch.json"
    folders = json.loads(batch.read_text())["folders"] if batch.is_file() else ["."]
    return [json.loads((out / folder / "summary.json").read_text()) for folder in folders]


def started_train_jobs(outs: list[Path], overrides: list[str], env: dict[str, str]) -> list[dict]:
    """The same job in each of ``outs`` at once, each a process of its own with exactly ``env`` as its environment
    (``OMP_NUM_THREADS`` included or not, as given); waits for all. Returns each one's wall time (``process_s``) and
    ``summary.json`` (``summary``; a seed batch's seeds' in ``summaries``, its first seed's as ``summary``); a failed job
    raises, with the end of its standard error."""
    logs = [out.parent / f"{out.name}.stderr" for out in outs]  # a file, not a pipe a chatty job could fill
    handles = [log.open("w") for log in logs]
    started = time.perf_counter()
    procs = [
        subprocess.Popen(train_command(out, overrides), cwd=out.parent, env=env, stdout=subprocess.DEVNULL, stderr=h)
        for out, h in zip(outs, handles, strict=True)
    ]
    ended: dict[int, float] = {}
    while len(ended) < len(procs):  # each job's own end, not the order they are waited for in
        for i, proc in enumerate(procs):
            if i not in ended and proc.poll() is not None:
                ended[i] = time.perf_counter() - started
        time.sleep(0.05)
    results = []
    for handle in handles:
        handle.close()
    for i, (out, proc) in enumerate(zip(outs, procs, strict=True)):
        if proc.returncode != 0:
            err = logs[i].read_text()
            raise RuntimeError(f"{' '.join(train_command(out, overrides))} failed in {out}:\n{err[-3000:]}")
        summaries = run_summaries(out)
        results.append({"process_s": ended[i], "summary": summaries[0], "summaries": summaries})
    return results


def timed_train_job(out: Path, overrides: list[str], env: dict[str, str] | None = None) -> dict:
    """``python -m kddrl_trl.train progress=false hydra.run.dir=<out> <overrides>`` in ``out`` 's parent folder, one
    torch thread unless ``OMP_NUM_THREADS`` says otherwise, with ``env`` added to the environment. Returns the
    process's wall time (``process_s``) and the run's ``summary.json`` (``summary``); a failed job raises, with the end
    of its standard error."""
    full_env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1"), **(env or {})}
    cmd = train_command(out, overrides)
    started = time.perf_counter()
    done = subprocess.run(cmd, cwd=out.parent, env=full_env, capture_output=True, text=True)
    elapsed = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed in {out}:\n{done.stderr[-3000:]}")
    return {"process_s": elapsed, "summary": json.loads((out / "summary.json").read_text())}
