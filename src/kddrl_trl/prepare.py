"""Build the naturalistic datasets and the IDM/MOBIL calibration (paper §IV.A, §IV.F, Table A.1).

    python -m kddrl_trl.prepare                          # source=synthetic (default): our SUMO recordings
    python -m kddrl_trl.prepare source=highd path=DIR    # a licensed copy of HighD (XX_tracks.csv, ...)

One reader and one extractor serve both sources. ``source=synthetic`` records ``record.num_roads`` x
``record.duration_s`` of traffic into ``recordings_dir`` first if it holds no recording. Writes into
``out_dir``: ``leaders/`` and ``lane_changes/`` (train / val / test, split 8:1:1 by vehicle), ``meta.json``
(counts, schema, input hash: a second run with the same input is a cache hit) and, with ``calibrate=true``,
``calibration.yaml`` (``env:`` overrides the environment loads, plus ``idm:`` and ``mobil:`` blocks) and
``calibration.json``.

``calibrate``: ``true`` (default) calibrates when the data allow it; when they do not (a short recording with no
car-following segment long enough, :class:`~kddrl_trl.data.calibrate.CalibrationImpossible`) the run still
finishes with the datasets and a warning saying why and what they are still good for. ``strict``: that case is
an error. ``false``: no calibration.
"""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
import pandas as pd
from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

from kddrl_trl import conf as _conf  # noqa: F401  (registers the typed schemas and the scenarios with Hydra)
from kddrl_trl.atomic_files import write_json_atomic
from kddrl_trl.data.calibrate import CalibrationImpossible, calibrate, write_calibration
from kddrl_trl.data.extract import extract_dataset
from kddrl_trl.data.highd import list_recordings, read_recording
from kddrl_trl.data.sumo_to_highd import (
    PAPER_LANE_CHANGER_SHARE,
    PAPER_VEHICLES_PER_HOUR,
    read_driver_params,
)
from kddrl_trl.data.synthetic import ensure_recordings
from kddrl_trl.data.tracks import longitudinal_tracks
from kddrl_trl.highway_config import default_drivers
from kddrl_trl.run_folder import no_folder_if_refused

log = logging.getLogger(__name__)

#: paper §IV.F: lane-change windows of 2 s extracted from HighD
PAPER_LANE_CHANGE_WINDOWS = 194_115
#: Table A.1 IDM (v0 in m/s)
TABLE_A1 = {"v0": 130 / 3.6, "T": 1.5, "s0": 5.0, "a": 5.0, "b": 4.0}


def recordings_directory(cfg: DictConfig) -> Path:
    """Where the recordings of ``cfg.source`` are; records them first for ``source=synthetic`` if needed."""
    if cfg.source == "highd":
        return Path(cfg.path)
    return ensure_recordings(
        OmegaConf.to_object(cfg.env),
        cfg.recordings_dir,
        int(cfg.seed),
        float(cfg.record.duration_s),
        int(cfg.record.num_roads),
        bool(cfg.progress),
    )


def print_dataset(meta: dict, hours: float) -> None:
    c = meta["counts"]
    lc = {
        name: sum(c["lane_changes"][s]["per_class"][name] for s in meta["splits"]) for name in ("left", "keep", "right")
    }
    windows = sum(lc.values())
    print(
        f"\ndataset ({'cached' if meta.get('cached') else 'extracted'}): {meta['recording_ids']} recordings, "
        f"{hours:.2f} h"
    )
    print(f"  {'':34s} {'ours':>12s} {'paper':>12s}")
    print(f"  {'vehicles':34s} {c['vehicles']:>12,d} {PAPER_VEHICLES_PER_HOUR:>12,d}")
    share = c["lane_changers"] / max(c["vehicles"], 1)
    print(f"  {'lane changers':34s} {100 * share:>11.1f}% {100 * PAPER_LANE_CHANGER_SHARE:>11.1f}%")
    print(f"  {'lane-change windows (2 s)':34s} {windows:>12,d} {PAPER_LANE_CHANGE_WINDOWS:>12,d}")
    for name, n in lc.items():
        print(f"  {'  ' + name:34s} {n:>12,d} ({100 * n / max(windows, 1):.2f} %)")
    for kind in meta["kinds"]:
        parts = ", ".join(f"{s} {c[kind][s]['samples']:,d}" for s in meta["splits"])
        print(f"  {kind + ' samples':34s} {parts}")


def print_calibration(result: dict, truth: pd.DataFrame | None) -> None:
    """Fitted class parameters beside Table A.1 (and beside the generating values, for our own data)."""
    classes = result["classes"].set_index("group")
    print(f"\ncalibration: {result['n_segments']} car-following segments, {result['seconds']:.0f} s")
    head = f"  {'class':12s} {'':9s}" + "".join(f"{p:>9s}" for p in ("v0", "T", "s0", "a", "b"))
    print(head + "   (v0 in km/h)")

    def row(label, kind, values):
        cells = [values["v0"] * 3.6, values["T"], values["s0"], values["a"], values["b"]]
        print(f"  {label:12s} {kind:9s}" + "".join(f"{x:9.2f}" for x in cells))

    row("Table A.1", "", TABLE_A1)
    for name, fit in classes.iterrows():
        row(str(name), "fitted", fit)
        if truth is not None and name in truth.index:
            row("", "true", truth.loc[name])
            err = {p: 100 * (fit[p] - truth.loc[name, p]) / truth.loc[name, p] for p in TABLE_A1}
            print(f"  {'':12s} {'error %':9s}" + "".join(f"{err[p]:9.1f}" for p in TABLE_A1))
    m = result["mobil"]
    print(
        f"  MOBIL: politeness {m['politeness']:.2f}, threshold {m['threshold']:.2f}, b_safe {m['b_safe']:.2f} "
        f"(balanced accuracy {m['balanced_accuracy']:.3f}; Table A.1's values {m['table_a1']['balanced_accuracy']:.3f})"
    )


def true_class_parameters(rec_dir: Path, ids: list[int]) -> pd.DataFrame | None:
    """Median per-class generating parameters of our own recordings (``XX_driverParams.csv``), else None."""
    try:
        params = pd.concat([read_driver_params(rec_dir, i) for i in ids], ignore_index=True)
    except FileNotFoundError:
        return None
    return params.groupby("driverType")[list(TABLE_A1)].median()


def recording_ids(rec_dir: Path) -> list[int]:
    """The recording ids of ``rec_dir``; a clear error when it holds none."""
    ids = list_recordings(rec_dir) if rec_dir.is_dir() else []
    if not ids:
        raise SystemExit(
            f"no HighD-format recording (XX_tracks.csv, XX_tracksMeta.csv, XX_recordingMeta.csv) in {rec_dir}"
        )
    return ids


def check_options(cfg: DictConfig) -> str | bool:
    """Refuse a bad ``source`` / ``path`` / ``calibrate`` before anything is recorded; returns the calibration
    mode: true | false | ``"strict"`` (strict: data too thin to calibrate is an error, not a warning)."""
    if cfg.source not in ("synthetic", "highd"):
        raise SystemExit(f"source must be 'synthetic' or 'highd', got {cfg.source!r}")
    if cfg.source == "highd" and not cfg.path:
        raise SystemExit(
            "source=highd needs path=DIR, the folder holding HighD's XX_tracks.csv, "
            "XX_tracksMeta.csv and XX_recordingMeta.csv"
        )
    if isinstance(cfg.calibrate, bool):
        return cfg.calibrate
    if str(cfg.calibrate).lower() == "strict":
        return "strict"
    raise SystemExit(f"calibrate must be true, false or strict, got {cfg.calibrate!r}")


def skip_calibration(err: CalibrationImpossible, out_dir: Path) -> str:
    """Warn that ``out_dir``'s data cannot be calibrated, why, and what its datasets are still good for; remove
    a calibration left there by an earlier run (it would not describe these data). Returns the reason."""
    for stale in ("calibration.yaml", "calibration.json"):
        (out_dir / stale).unlink(missing_ok=True)
    log.warning(
        "%s: no calibration written. The datasets in %s are complete and still good for pretraining "
        "trajGAN and lcGAN (python -m kddrl_trl.pretrain gan=trajgan|lcgan data_dir=%s); the env keeps its "
        "default drivers (highway_config.py). Calibrating needs longer recordings (record.duration_s, or more "
        "HighD files); calibrate=strict makes this an error.",
        err,
        out_dir,
        out_dir,
    )
    return str(err)


@hydra.main(version_base="1.3", config_path="conf", config_name="prepare")
def main(cfg: DictConfig) -> dict:
    with no_folder_if_refused():  # bad options or a HighD folder without recordings: no run folder left
        mode = check_options(cfg)
        if cfg.source == "highd":
            recording_ids(Path(cfg.path))
    rec_dir = recordings_directory(cfg)  # records first for source=synthetic if needed
    ids = recording_ids(rec_dir)
    recordings = [read_recording(rec_dir, i) for i in tqdm(ids, desc="read", unit="rec", disable=not cfg.progress)]
    out_dir = Path(cfg.out_dir)
    meta = extract_dataset(
        recordings,
        out_dir,
        seed=int(cfg.seed),
        stride=int(cfg.stride),
        label=str(cfg.label),
        progress=bool(cfg.progress),
        force=bool(cfg.force),
    )
    hours = sum(float(r.meta["duration"]) for r in recordings) / 3600.0
    print_dataset(meta, hours)
    summary = {"source": cfg.source, "recordings_dir": str(rec_dir), "out_dir": str(out_dir), "dataset": meta}
    if mode:
        cal_json = out_dir / "calibration.json"
        try:
            result = calibrate(
                pd.concat([longitudinal_tracks(r) for r in recordings], ignore_index=True),
                progress=bool(cfg.progress),
                source=f"{cfg.source}: {rec_dir}",
            )
        except CalibrationImpossible as err:
            if mode == "strict":
                raise
            summary["calibration_skipped"] = skip_calibration(err, out_dir)
            print(f"\ndatasets in {out_dir} (not calibrated)")
            return summary
        write_calibration(result, out_dir / "calibration.yaml")
        truth = true_class_parameters(rec_dir, ids) if cfg.source == "synthetic" else None
        print_calibration(result, truth)
        record = {
            "input_hash": meta["input_hash"],
            "classes": result["classes"].to_dict(orient="records"),
            "population": result["population"].to_dict(orient="records"),
            "shares": result["shares"],
            "mobil": {k: v for k, v in result["mobil"].items() if k != "table_a1"},
            "mobil_table_a1": result["mobil"].get("table_a1"),
            "seconds": result["seconds"],
            "truth": None if truth is None else truth.reset_index().to_dict(orient="records"),
            "default_drivers": [d.__dict__ for d in default_drivers()],
        }
        write_json_atomic(cal_json, record)
        summary["calibration"] = str(out_dir / "calibration.yaml")
    print(f"\ndatasets in {out_dir}")
    return summary


if __name__ == "__main__":
    main()
