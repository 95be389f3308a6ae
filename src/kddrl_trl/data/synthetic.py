"""The default naturalistic dataset (paper §IV.A, with our own SUMO traffic in place of HighD): record traffic
into a folder if it holds none, then extract the leaders' and lane changes' datasets from it. The traffic is that
of the ``env`` node's simulator (:func:`traffic_recorder`): our SUMO highway, or HighwayEnv's own traffic.

:mod:`kddrl_trl.prepare` (the entry point) and :func:`kddrl_trl.data.gan_datasets.gan_dataset` both build it here.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path

from kddrl_trl.data.extract import extract_dataset
from kddrl_trl.data.highd import list_recordings, read_recording
from kddrl_trl.data.sumo_to_highd import (
    PAPER_LANE_CHANGER_SHARE,
    PAPER_VEHICLES_PER_HOUR,
    RecordedTraffic,
    record_to_directory,
    record_traffic,
)

Recorder = Callable[..., list[RecordedTraffic]]


def traffic_recorder(env) -> Recorder:
    """The recorder of an ``env`` node's simulator (``conf/schema.py``'s env node, or anything with its
    ``simulator`` and ``highwayenv`` fields): :func:`~kddrl_trl.data.sumo_to_highd.record_traffic` for ``sumo``,
    :func:`~kddrl_trl.data.highwayenv_to_highd.record_highwayenv_traffic` with the node's HighwayEnv options for
    ``highwayenv``. Both take ``(highway config, duration_s, num_roads=, seed=, progress=)``."""
    simulator = getattr(env, "simulator", "sumo")
    if simulator == "sumo":
        return record_traffic
    if simulator == "highwayenv":
        from kddrl_trl.data.highwayenv_to_highd import record_highwayenv_traffic

        return partial(record_highwayenv_traffic, options=env.highwayenv)
    raise ValueError(f"env.simulator={simulator!r}: no traffic recorder (known: sumo, highwayenv)")


def print_summary(s: dict, hw, seed: int, duration_s: float, num_roads: int, simulator: str = "sumo") -> None:
    """The recording's vehicle count, lane-changer share and driver types beside the paper's figures."""
    hours = s["simulated_hours"]
    per_hour = s["vehicles"] / hours if hours > 0 else float("nan")
    wall, wall_record = s["wall_s"], s["wall_record_s"]
    traffic = f"{hw.flow:.0f} veh/h per road" if simulator == "sumo" else f"{simulator}'s own traffic"
    print(
        f"\nrecorded {hw.scenario} traffic ({traffic}), seed {seed}: "
        f"{num_roads} recording(s) x {duration_s:g} s = {hours:.3f} h"
    )
    for rid in s["skipped"]:
        print(f"  recording {rid:02d}: no vehicle entered the view; nothing written")
    print(f"  {'':30s} {'ours':>12s} {'paper':>12s}")
    print(f"  {'vehicles':30s} {s['vehicles']:>12,d} {'':>12s}")
    print(f"  {'vehicles per hour':30s} {per_hour:>12,.0f} {PAPER_VEHICLES_PER_HOUR:>12,d}")
    print(f"  {'lane changers (%)':30s} {100 * s['lane_changer_share']:>12.1f} {100 * PAPER_LANE_CHANGER_SHARE:>12.1f}")
    for name, count in s["driver_types"].items():
        share = 100 * count / s["vehicles"] if s["vehicles"] else float("nan")
        print(f"  {'driver ' + name:30s} {count:>8,d} ({share:4.1f} %)")
    print(
        f"  {'wall time (s)':30s} {wall:>12.1f}   (recording {wall_record:.1f} s: "
        f"{hours * 3600 / wall_record if wall_record > 0 else float('nan'):.0f} recorded s per wall s; "
        f"writing {wall - wall_record:.1f} s)"
    )
    print(f"recordings in {s['out_dir']}")


def record_env_traffic(
    env, out_dir: str | Path, seed: int, duration_s: float, num_roads: int, progress: bool = True
) -> dict:
    """Record ``num_roads`` x ``duration_s`` of the traffic of ``env`` (an env node, :func:`traffic_recorder`) into
    ``out_dir`` (:func:`~kddrl_trl.data.sumo_to_highd.record_to_directory`), print :func:`print_summary` and return
    the summary."""
    hw = env.highway()
    s = record_to_directory(
        hw, Path(out_dir), duration_s, num_roads=num_roads, seed=seed, progress=progress, recorder=traffic_recorder(env)
    )
    print_summary(s, hw, seed, duration_s, num_roads, getattr(env, "simulator", "sumo"))
    return s


def ensure_recordings(
    env, recordings_dir: str | Path, seed: int, duration_s: float, num_roads: int, progress: bool = True
) -> Path:
    """``recordings_dir``, after recording ``num_roads`` x ``duration_s`` of the traffic of ``env`` (an env node,
    :func:`traffic_recorder`) into it if it holds none (:func:`record_env_traffic`)."""
    rec_dir = Path(recordings_dir)
    if not (rec_dir.is_dir() and list_recordings(rec_dir)):
        record_env_traffic(env, rec_dir, seed, duration_s, num_roads, progress)
    return rec_dir


def synthetic_dataset(
    env,
    out_dir: str | Path,
    recordings_dir: str | Path,
    seed: int = 0,
    duration_s: float = 900.0,
    num_roads: int = 4,
    stride: int = 1,
    progress: bool = True,
) -> dict:
    """The default naturalistic dataset from our own recordings of the traffic of ``env`` (an env node,
    :func:`traffic_recorder`): record into ``recordings_dir`` if it holds none, then extract (a cache hit when
    ``out_dir`` already holds this dataset). Returns its meta."""
    rec_dir = ensure_recordings(env, recordings_dir, seed, duration_s, num_roads, progress)
    recordings = [read_recording(rec_dir, i) for i in list_recordings(rec_dir)]
    return extract_dataset(recordings, out_dir, seed=seed, stride=stride, progress=progress)
