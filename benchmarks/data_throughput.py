"""Throughput of the naturalistic-data pipeline on the default hour of traffic, in one run.

Measures (a) recording: simulated road-seconds per wall second of ``record_traffic`` (4 roads x 900 s
by default, SUMO start and warm-up included: it is what a user waits for); (b) writing the
HighD CSV files; (c) extraction: samples (leader + lane-change) per second of ``extract_dataset`` from the
recordings read back from disk, and the reading itself. Prints a table and writes
``benchmarks/results/data_throughput.json``.

    python -m benchmarks.data_throughput [--duration 900] [--roads 4] [--seed 0]
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
import time
from pathlib import Path

import torch

from kddrl_trl.atomic_files import write_json_atomic
from kddrl_trl.data.extract import extract_dataset
from kddrl_trl.data.highd import list_recordings, read_recording
from kddrl_trl.data.sumo_to_highd import record_traffic, summarize_recorded
from kddrl_trl.envs import make_config


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=900.0, help="simulated seconds per recording")
    ap.add_argument("--roads", type=int, default=4, help="recordings (roads simulated side by side)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scenario", default="baseline")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "data_throughput.json"))
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    cfg = make_config(args.scenario)
    with tempfile.TemporaryDirectory() as tmp:
        rec_dir, ds_dir = Path(tmp) / "recordings", Path(tmp) / "dataset"
        t0 = time.perf_counter()
        recorded = record_traffic(cfg, args.duration, num_roads=args.roads, seed=args.seed, progress=True)
        t_record = time.perf_counter() - t0
        t0 = time.perf_counter()
        for rec in recorded:
            rec.write(rec_dir)
        t_write = time.perf_counter() - t0
        t0 = time.perf_counter()
        recordings = [read_recording(rec_dir, i) for i in list_recordings(rec_dir)]
        t_read = time.perf_counter() - t0
        t0 = time.perf_counter()
        meta = extract_dataset(recordings, ds_dir, seed=args.seed, progress=True)
        t_extract = time.perf_counter() - t0
    stats = summarize_recorded(recorded)
    counts = meta["counts"]
    samples = {kind: sum(counts[kind][s]["samples"] for s in meta["splits"]) for kind in meta["kinds"]}
    total = sum(samples.values())
    sim_seconds = args.duration * args.roads
    rows = [
        ("record", f"{sim_seconds:,.0f} simulated s", t_record, f"{sim_seconds / t_record:,.0f} simulated s / s"),
        ("write CSV", f"{len(recorded)} recordings", t_write, ""),
        ("read CSV", f"{len(recordings)} recordings", t_read, ""),
        ("extract", f"{total:,d} samples", t_extract, f"{total / t_extract:,.0f} samples / s"),
    ]
    print(
        f"\ndata pipeline, {args.scenario}, {args.roads} x {args.duration:g} s, seed {args.seed}: "
        f"{stats['vehicles']:,d} vehicles, {100 * stats['lane_changer_share']:.1f} % lane changers"
    )
    print(f"{'step':10s} {'work':>24s} {'wall s':>8s} {'rate':>26s}")
    for name, work, wall, rate in rows:
        print(f"{name:10s} {work:>24s} {wall:8.2f} {rate:>26s}")
    result = {
        "machine": {"platform": platform.platform(), "python": sys.version.split()[0], "torch": torch.__version__},
        "args": vars(args),
        "vehicles": stats["vehicles"],
        "lane_changer_share": stats["lane_changer_share"],
        "samples": samples,
        "lane_change_per_class": {s: counts["lane_changes"][s]["per_class"] for s in meta["splits"]},
        "record_wall_s": t_record,
        "record_sim_s_per_wall_s": sim_seconds / t_record,
        "write_wall_s": t_write,
        "read_wall_s": t_read,
        "extract_wall_s": t_extract,
        "extract_samples_per_s": total / t_extract,
    }
    write_json_atomic(args.out, result)
    print(f"results written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
