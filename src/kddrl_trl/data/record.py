"""Record naturalistic traffic: ``python -m kddrl_trl.data.record [+scenario=congested] [duration_s=900] ...``.

Runs :func:`kddrl_trl.data.recorder.record_traffic` on the highway config composed from
``conf/record.yaml`` (``env: highway`` + optional ``+scenario=...`` + ``env.*`` overrides), writes one HighD
recording per road into ``out_dir`` (``XX_tracks.csv``, ``XX_tracksMeta.csv``, ``XX_recordingMeta.csv``
and ``XX_driverParams.csv``, each atomically) and prints the vehicle count, the share of lane changers and
the driver-type counts beside the paper's figures. The top-level ``num_roads`` sets the number of
recordings; ``env.num_roads`` (the RL env's batch size) is ignored.
"""

from __future__ import annotations  # noqa: I001  (kddrl_trl.conf must be imported before hydra)

from pathlib import Path

from kddrl_trl import conf as _conf  # noqa: F401  (registers the typed schemas and the scenarios with Hydra; first)

import hydra
from omegaconf import DictConfig, OmegaConf

from kddrl_trl.data.recorder import PAPER_LANE_CHANGER_SHARE, PAPER_VEHICLES_PER_HOUR, record_to_directory


def print_summary(s: dict, hw, seed: int, duration_s: float, num_roads: int) -> None:
    """The recording's vehicle count, lane-changer share and driver types beside the paper's figures."""
    hours = s["simulated_hours"]
    per_hour = s["vehicles"] / hours if hours > 0 else float("nan")
    wall, wall_record = s["wall_s"], s["wall_record_s"]
    print(
        f"\nrecorded {hw.scenario} traffic ({hw.flow:.0f} veh/h per road), seed {seed}: "
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


@hydra.main(version_base="1.3", config_path="../conf", config_name="record")
def main(cfg: DictConfig) -> dict:
    hw = OmegaConf.to_object(cfg.env).highway()
    s = record_to_directory(
        hw,
        Path(cfg.out_dir),
        float(cfg.duration_s),
        num_roads=int(cfg.num_roads),
        seed=int(cfg.seed),
        progress=bool(cfg.progress),
    )
    print_summary(s, hw, int(cfg.seed), float(cfg.duration_s), int(cfg.num_roads))
    return s


if __name__ == "__main__":
    main()
