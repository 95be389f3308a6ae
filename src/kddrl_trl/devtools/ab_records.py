"""The A/B of a change that keeps the arithmetic: two run folders of the same job, from the code before and after.

A speed change (or a refactor) that claims to keep the records shows it: the same job (the same config and seed)
run from a worktree of the commit before and one of the commit after, side by side with one torch thread each, must
give byte-identical training, validation and final-evaluation records, scalar logs (those under ``logs/scalars``
but ``time/``, which hold wall-clock seconds) and, in the last checkpoint both runs share, the learner's parameters
and optimiser states bit for bit, with the same update counts. This script compares two such folders and says where
they part.

    git worktree add ../before <commit before>
    (cd ../before && OMP_NUM_THREADS=1 python -m kddrl_trl.train seed=0 episodes=150 eval_episodes=30 \\
        train.eval_every=50 train.eval_episodes=20 hydra.run.dir=/tmp/ab/before) &
    OMP_NUM_THREADS=1 python -m kddrl_trl.train seed=0 episodes=150 eval_episodes=30 \\
        train.eval_every=50 train.eval_episodes=20 hydra.run.dir=/tmp/ab/after; wait
    python -m kddrl_trl.devtools.ab_records /tmp/ab/before /tmp/ab/after --change "what changed" --before-rev <commit>

A change that adds a column to the records (a new per-episode field) names it with ``--new-columns``: the before side
must lack it, and the after side's records, with just those columns cut out of each line, must match the before
side's byte for byte (both read and written again by the ``csv`` module, which keeps every field's text).

Prints a table and writes ``benchmarks/results/ab_records.json`` (or ``--out``); exits 1 when anything differs.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
from pathlib import Path

import torch

from kddrl_trl.atomic_files import write_json_atomic
from kddrl_trl.reporting.records import record_bytes
from kddrl_trl.run_folder import checkpoint_dir

#: the records a training run writes; absent from both folders (no validation, say) is no difference
RECORDS = ("train_episodes.csv", "validation.csv", "eval_episodes.csv")
#: the training counts of ``summary.json`` that must match
COUNTS = ("cf_updates", "lc_updates", "frames", "decisions", "episodes")


def digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def without_columns(data: bytes, columns: tuple[str, ...]) -> tuple[bytes, set[str]]:
    """The CSV ``data`` with those of ``columns`` its header has cut out of every line, and which they were."""
    rows = list(csv.reader(io.StringIO(data.decode())))
    if not rows:
        return data, set()
    cut = {c for c in columns if c in rows[0]}
    keep = [i for i, c in enumerate(rows[0]) if c not in cut]
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows([[row[i] for i in keep] for row in rows])
    return out.getvalue().encode(), cut


def records(folder: Path, new_columns: tuple[str, ...] = (), side: str = "after") -> dict[str, str | None]:
    """Record name -> the first 16 hex digits of its SHA-256 (decompressed), None where the run has none. With
    ``new_columns``, every record goes through the ``csv`` module (the same reading and writing on both sides); the
    after side has them cut out where a record holds them (each must be in one at least), and the before side must
    not hold them."""
    out, found = {}, set()
    for name in RECORDS:
        try:
            data = record_bytes(folder, name)
        except FileNotFoundError:
            out[name] = None
            continue
        if new_columns:
            data, cut = without_columns(data, new_columns)
            if side == "before" and cut:
                raise SystemExit(f"{folder / name}: already has {', '.join(sorted(cut))}: not a new column")
            found |= cut
        out[name] = digest(data)
    missing = [c for c in new_columns if c not in found]
    if side == "after" and missing:
        raise SystemExit(f"{folder}: no record has {', '.join(missing)} to leave out (--new-columns)")
    return out


def scalar_logs(folder: Path) -> dict[str, bytes]:
    """``logs/scalars`` file (relative path) -> its bytes, wall-clock ``time/`` logs left out."""
    base = folder / "logs" / "scalars"
    return {
        str(p.relative_to(base)): p.read_bytes()
        for p in sorted(base.rglob("*"))
        if p.is_file() and p.relative_to(base).parts[0] != "time"
    }


def same(a, b) -> bool:
    """Equal bit for bit, through nested dicts, lists and tensors."""
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return isinstance(b, list | tuple) and len(a) == len(b) and all(map(same, a, b))
    return a == b


def last_shared_checkpoint(before: Path, after: Path) -> str | None:
    """The name of the newest ``epNNNNNN.pt`` both runs wrote, or None."""
    names = [{p.name for p in checkpoint_dir(f).glob("ep*.pt")} for f in (before, after)]
    shared = sorted(names[0] & names[1])
    return shared[-1] if shared else None


def learner_state(folder: Path, name: str) -> dict:
    return torch.load(checkpoint_dir(folder) / name, map_location="cpu", weights_only=False)["learner"]


def counts(folder: Path) -> dict:
    training = json.loads((folder / "summary.json").read_text()).get("training", {})
    return {k: training.get(k) for k in COUNTS}


def compare(before: Path, after: Path, new_columns: tuple[str, ...] = ()) -> dict:
    for folder in (before, after):
        if not (folder / "summary.json").is_file():
            raise SystemExit(f"{folder}: no summary.json (not a finished run folder)")
    rec = {"before": records(before, new_columns, "before"), "after": records(after, new_columns, "after")}
    logs = scalar_logs(before), scalar_logs(after)
    differing_logs = sorted(k for k in logs[0].keys() | logs[1].keys() if logs[0].get(k) != logs[1].get(k))
    result = {
        "records_sha256_16": rec,
        "records_identical": rec["before"] == rec["after"],
        "new_columns": list(new_columns),
        "scalar_logs_compared": len(logs[0].keys() | logs[1].keys()),
        "scalar_logs_identical": len(logs[0].keys() | logs[1].keys()) - len(differing_logs),
        "scalar_logs_differing": differing_logs,
        "counts": {"before": counts(before), "after": counts(after)},
    }
    result["counts_identical"] = result["counts"]["before"] == result["counts"]["after"]
    name = last_shared_checkpoint(before, after)
    result["checkpoint"] = name
    if name is not None:
        a, b = learner_state(before, name), learner_state(after, name)
        result["checkpoint_parameters_identical"] = same(a["modules"], b["modules"])
        result["checkpoint_optimizer_states_identical"] = same(a["optimizers"], b["optimizers"])
    result["identical"] = (
        result["records_identical"]
        and not differing_logs
        and result["counts_identical"]
        and result.get("checkpoint_parameters_identical", False)
        and result.get("checkpoint_optimizer_states_identical", False)
    )
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path, help="run folder of the code before")
    parser.add_argument("after", type=Path, help="run folder of the code after")
    parser.add_argument("--change", default="", help="what the change is, for the record")
    parser.add_argument("--before-rev", default="", help="the commit of the code before")
    parser.add_argument("--command", default="", help="the job both ran, for the record")
    parser.add_argument(
        "--new-columns", default="", help="comma-separated columns the after side adds to its records (cut out there)"
    )
    parser.add_argument("--out", type=Path, default=Path("benchmarks") / "results" / "ab_records.json")
    args = parser.parse_args(argv)
    result = {
        "change": args.change,
        "before": args.before_rev,
        "command": args.command,
        **compare(args.before, args.after, tuple(c for c in args.new_columns.split(",") if c)),
        "timing_note": "not a timing: the two ran side by side; speed is measured by the benchmarks",
    }
    rows = [
        *(
            (f"record {n}", h, result["records_sha256_16"]["after"][n])
            for n, h in result["records_sha256_16"]["before"].items()
        ),
        ("scalar logs identical", f"{result['scalar_logs_identical']} of {result['scalar_logs_compared']}", ""),
        *((f"count {k}", v, result["counts"]["after"][k]) for k, v in result["counts"]["before"].items()),
        (f"parameters at {result['checkpoint']}", result.get("checkpoint_parameters_identical"), ""),
        (f"optimiser states at {result['checkpoint']}", result.get("checkpoint_optimizer_states_identical"), ""),
    ]
    print(f"{'':36} {'before':>18} {'after':>18}")
    for label, b, a in rows:
        print(f"{label:36} {str(b):>18} {str(a):>18}")
    for name in result["scalar_logs_differing"]:
        print(f"differs: logs/scalars/{name}")
    print(f"identical: {result['identical']}")
    write_json_atomic(args.out, result)
    print(f"written {args.out}")
    return 0 if result["identical"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
