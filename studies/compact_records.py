"""Keeps the committed runs' training records small: each ``train_episodes.csv[.xz]`` under the given folders is
rewritten (xz-compressed) with the columns the reports and a reader of the learning curves use, and no others.

    python studies/compact_records.py studies/paper/runs studies/ablation/runs ...

The report draws Fig. 8 from ``return_lc`` / ``return_cf``; ``mean_speed_kmh`` and ``collision`` stay for a reader
who asks how driving changed while learning. The evaluation records (``eval_episodes.csv``) are never touched: the
report's tables and the verdict read every one of their columns. Rewriting keeps every kept value's text as it was.
"""

from __future__ import annotations

import csv
import io
import lzma
import sys
from pathlib import Path

from kddrl_trl.atomic_files import write_atomic

KEPT = ("index", "return_lc", "return_cf", "mean_speed_kmh", "collision")


def compact(path: Path) -> int:
    """Rewrites one training record as ``train_episodes.csv.xz`` with the ``KEPT`` columns; returns bytes saved."""
    raw = lzma.decompress(path.read_bytes()) if path.suffix == ".xz" else path.read_bytes()
    rows = list(csv.reader(io.StringIO(raw.decode())))
    header = rows[0]
    missing = [k for k in KEPT if k not in header]
    if missing:
        raise ValueError(f"{path}: no column(s) {', '.join(missing)}")
    if header == list(KEPT) and path.suffix == ".xz":
        return 0
    at = [header.index(k) for k in KEPT]
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows([[row[i] for i in at] for row in rows])
    target = path.with_name("train_episodes.csv.xz")
    before = path.stat().st_size
    data = lzma.compress(out.getvalue().encode(), preset=9)
    write_atomic(target, lambda fh: fh.write(data), binary=True)  # a killed rewrite leaves the record as it was
    if target != path:
        path.unlink()
    return before - target.stat().st_size


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    saved = sum(compact(p) for folder in sys.argv[1:] for p in sorted(Path(folder).rglob("train_episodes.csv*")))
    print(f"{saved / 1e6:.1f} MB saved")
