"""Merging a benchmark's results file with the previous one: a run keeps every measurement it did not make
itself, each attributed to the run that made it (used by ``benchmarks/train_throughput.py``)."""

from __future__ import annotations

#: the entries that describe runs, not measurements
BOOKKEEPING = ("args", "machine", "note", "runs", "measured_by", "kept_from_previous_run")


def keep_previous(result: dict, previous: dict) -> None:
    """Adds to ``result`` every measurement of the previous results file that this run did not make (a CPU run
    keeps the ``gpu`` entry, a ``--full-run`` alone keeps the update and collection figures), and says which run
    made each: ``runs`` lists the runs (``args``, ``machine``, ``note``; this one first) and ``measured_by`` maps
    each measurement to its run's index there. The top-level ``args`` / ``machine`` / ``note`` are this run's."""
    made = [k for k, v in result.items() if k not in BOOKKEEPING and v not in (None, [], {})]
    old_runs = previous.get("runs") or [{k: previous.get(k) for k in ("args", "machine", "note")}]
    old_by = previous.get("measured_by", {})
    runs = [{k: result.get(k) for k in ("args", "machine", "note")}]
    measured_by = dict.fromkeys(made, 0)
    for key, value in previous.items():
        if key in BOOKKEEPING or key in made or value in (None, [], {}):
            continue
        result[key] = value
        run = old_runs[old_by.get(key, 0)]
        if run not in runs:
            runs.append(run)
        measured_by[key] = runs.index(run)
    result["runs"], result["measured_by"] = runs, measured_by
