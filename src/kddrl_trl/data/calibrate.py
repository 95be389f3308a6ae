"""Calibration of the background drivers' IDM and MOBIL parameters from naturalistic tracks (paper §IV.A).

Input is the 10 Hz longitudinal track table described in ``TRACKS10.md`` (one row per vehicle per frame,
front-bumper ``y`` growing in the direction of travel, ``lane`` 0 = rightmost, neighbour ids, 0 = none).

* IDM (Eqs. 11-12): :mod:`kddrl_trl.data.calibrate_idm` (:func:`car_following_segments`, :func:`fit_idm`);
  :func:`class_parameters` turns per-vehicle fits into driver classes.
* MOBIL (Eqs. 20-22): :mod:`kddrl_trl.data.calibrate_mobil` (:func:`decision_points`, :func:`fit_mobil`).
* :func:`calibrate` runs everything; :func:`write_calibration` writes a YAML file whose ``env:`` block is a
  valid :func:`kddrl_trl.envs.make_config` override (``drivers:``) plus ``idm:`` and ``mobil:`` blocks.
"""

from __future__ import annotations

import datetime as _dt
import os
import time
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from kddrl_trl.atomic_files import write_text_atomic
from kddrl_trl.data.calibrate_idm import DEFAULT_BOUNDS, IDM_FIELDS, car_following_segments, fit_idm, simulate_following
from kddrl_trl.data.calibrate_mobil import (
    DEFAULT_MOBIL_GRID,
    balanced_accuracy,
    decision_points,
    fit_mobil,
    mobil_decision,
)
from kddrl_trl.physics.idm import IDMParams


def class_parameters(vehicle_fits: pd.DataFrame, by: str = "driver_type") -> pd.DataFrame:
    """Class centres as the median of per-vehicle fits (:func:`fit_idm` with ``groups=None``).

    The environment draws each vehicle around its class value (``DriverClass.spread``); the median of the
    per-vehicle estimates is a consistent estimate of that centre, whereas one parameter set fitted to the
    pooled segments of heterogeneous drivers is a compromise that damps the dynamics (on synthetic data
    with 5 % spread it underestimates ``a`` and ``b`` by up to ~40-70 %). Also returns ``spread``: the median
    over the five parameters of the robust relative sd (1.4826 MAD / median) within the class, and the
    median per-vehicle ``rmse`` / ``rmse_init``.
    """
    rows = []
    for name, g in vehicle_fits.groupby(by, sort=False):
        med = g[list(IDM_FIELDS)].median()
        mad = (g[list(IDM_FIELDS)] - med).abs().median() * 1.4826 / med
        rows.append(
            {
                "group": name,
                "driver_type": name,
                **med.to_dict(),
                "delta": float(g["delta"].iloc[0]),
                "rmse": float(g["rmse"].median()),
                "rmse_init": float(g["rmse_init"].median()),
                "n_segments": int(g["n_segments"].sum()),
                "seconds": float(g["seconds"].sum()),
                "n_vehicles": len(g),
                "spread": float(np.clip(mad.median(), 0.0, 0.45)) if len(g) >= 5 else float("nan"),
            }
        )
    return pd.DataFrame(rows)


_TERCILE_NAMES = ("aggressive", "normal", "timid")  # increasing fitted T


class CalibrationImpossible(ValueError):
    """The tracks hold too little of what a calibration fits (the message says what is missing)."""


def calibrate(
    tracks: pd.DataFrame,
    per_vehicle: bool = True,
    progress: bool = True,
    min_duration_s: float = 5.0,
    steps: int = 250,
    mobil_grid: Mapping[str, Sequence[float]] | None = None,
    source: str = "",
) -> dict[str, Any]:
    """Run the whole calibration on one tracks10 table (several recordings may be concatenated).

    IDM is fitted per vehicle (if ``per_vehicle``) and for the whole population. Driver classes come from
    ``driver_type``; when the table has none, the vehicles are split into terciles of their per-vehicle time
    headway T, named aggressive / normal / timid (needs ``per_vehicle``; otherwise one class ``normal``).
    Class parameters are the medians of the per-vehicle fits (:func:`class_parameters`, consistent for a
    population drawn around class centres) when ``per_vehicle``, else one pooled fit per class.
    MOBIL is then fitted with the population IDM. Class shares are the fraction of the table's vehicles in
    each class (classes without a car-following segment are dropped and the shares renormalised).

    Returns:
        dict with ``classes``, ``population`` (one-row), ``vehicles`` (or None) DataFrames from
        :func:`fit_idm`, ``shares`` {class: share}, ``mobil`` (from :func:`fit_mobil`), ``source``,
        ``created`` (ISO date), ``n_segments``, ``seconds`` (wall time).

    Raises:
        CalibrationImpossible: no car-following segment of at least ``min_duration_s``.
    """
    t0 = time.perf_counter()
    seg = car_following_segments(tracks, min_duration_s=min_duration_s)
    if seg.batch_size[0] == 0:
        raise CalibrationImpossible(
            "calibrate: no car-following segment of at least "
            f"{min_duration_s} s in the tracks (too short a recording, or too few "
            "vehicles following one another)"
        )
    kw = dict(steps=steps, progress=progress)
    population = fit_idm(seg, groups="all", **kw)
    vehicles = fit_idm(seg, groups=None, **kw) if per_vehicle else None
    vtypes = tracks.groupby(["recording_id", "vehicle_id"])["driver_type"].first().astype(str)
    typed = bool((vtypes != "").any())
    if typed:
        classes = class_parameters(vehicles) if vehicles is not None else fit_idm(seg, groups="driver_type", **kw)
        counts = vtypes.value_counts()
    elif vehicles is not None and len(vehicles) >= 3:
        q = vehicles["T"].rank(method="first", pct=True).to_numpy()
        tercile = np.minimum((q * 3 - 1e-9).astype(int), 2)
        vehicles["tercile"] = [_TERCILE_NAMES[t] for t in tercile]
        classes = class_parameters(vehicles, by="tercile")
        counts = vehicles["tercile"].value_counts()
    else:
        classes = fit_idm(seg, groups=["normal"] * seg.batch_size[0], **kw)
        counts = pd.Series({"normal": len(vtypes)})
    counts = counts.reindex(classes["group"]).fillna(0.0)
    shares = (
        (counts / counts.sum()).to_dict() if counts.sum() > 0 else {g: 1.0 / len(classes) for g in classes["group"]}
    )
    pop = population.iloc[0]
    idm = IDMParams(
        v0=float(pop["v0"]), T=float(pop["T"]), s0=float(pop["s0"]), a_max=float(pop["a"]), b=float(pop["b"])
    )
    decisions = decision_points(tracks)
    mobil = fit_mobil(decisions, grid=mobil_grid, idm=idm)
    return {
        "classes": classes,
        "population": population,
        "vehicles": vehicles,
        "shares": shares,
        "mobil": mobil,
        "source": source or "tracks10 table",
        "created": _dt.date.today().isoformat(),
        "n_segments": int(seg.batch_size[0]),
        "seconds": time.perf_counter() - t0,
    }


def _r(x: float, nd: int = 4) -> float:
    return float(round(float(x), nd))


def write_calibration(result: Mapping[str, Any], path: str | os.PathLike) -> None:
    """Write ``result`` of :func:`calibrate` as YAML, atomically (temp file in the same folder + os.replace).

    ``env: drivers:`` is a valid ``make_config`` override: one entry per fitted class with its share, IDM
    parameters and (when estimated from >= 5 per-vehicle fits) spread; the lane-change eagerness (and the
    spread otherwise) are those of the default class of the same name (``DriverClass`` defaults otherwise). ``idm:``
    holds the population fit, ``mobil:`` the MOBIL fit.
    """
    import yaml

    from kddrl_trl.highway_config import DriverClass, default_drivers

    defaults = {d.name: d for d in default_drivers()}
    classes, mobil, pop = result["classes"], result["mobil"], result["population"].iloc[0]
    drivers = []
    for _, row in classes.iterrows():
        name = str(row["group"]) or "normal"
        base = defaults.get(name, DriverClass(name=name))
        drivers.append(
            {
                "name": name,
                "share": _r(result["shares"].get(row["group"], 0.0), 6),
                **{k: _r(row[k]) for k in IDM_FIELDS},
                "lc_speed_gain": float(base.lc_speed_gain),
                "lc_keep_right": float(base.lc_keep_right),
                "spread": _r(row["spread"]) if "spread" in row and np.isfinite(row["spread"]) else float(base.spread),
            }
        )
    drivers = [d for d in drivers if d["share"] > 0] or drivers
    if any(d["share"] <= 0 for d in drivers):
        for d in drivers:
            d["share"] = _r(1.0 / len(drivers))
    doc = {
        "env": {"drivers": drivers},
        "idm": {
            **{k: _r(pop[k]) for k in IDM_FIELDS},
            "delta": _r(pop["delta"]),
            "rmse_m": _r(pop["rmse"]),
            "rmse_table_a1_m": _r(pop["rmse_init"]),
            "segments": int(pop["n_segments"]),
            "seconds": _r(pop["seconds"], 1),
        },
        "mobil": {
            "politeness": _r(mobil["politeness"]),
            "threshold": _r(mobil["threshold"]),
            "b_safe": _r(mobil["b_safe"]),
            "balanced_accuracy": _r(mobil["balanced_accuracy"]),
            "balanced_accuracy_table_a1": _r(mobil["table_a1"]["balanced_accuracy"]),
        },
    }
    veh = result.get("vehicles")
    lines = [
        "# IDM / MOBIL calibration of the background drivers (kddrl_trl.data.calibrate)",
        f"# data source: {result.get('source', '')}",
        f"# date: {result.get('created', _dt.date.today().isoformat())}",
        f"# car-following segments: {result.get('n_segments', int(pop['n_segments']))}; "
        f"population gap RMSE {pop['rmse']:.3f} m (Table A.1: {pop['rmse_init']:.3f} m)",
    ]
    for _, row in classes.iterrows():
        lines.append(
            f"#   class {row['group']}: gap RMSE {row['rmse']:.3f} m (Table A.1 {row['rmse_init']:.3f} m), "
            f"{int(row['n_segments'])} segments, {row['seconds']:.0f} s"
        )
    if veh is not None and len(veh):
        lines.append(
            f"# per-vehicle fits: {len(veh)} vehicles, median gap RMSE {veh['rmse'].median():.3f} m "
            f"(Table A.1 {veh['rmse_init'].median():.3f} m)"
        )
    lines.append(
        f"# MOBIL balanced accuracy {mobil['balanced_accuracy']:.3f} "
        f"(Table A.1: {mobil['table_a1']['balanced_accuracy']:.3f}); decisions {mobil['n_decisions']}"
    )
    lines.append("# load: kddrl_trl.envs.make_config('baseline', OmegaConf.load(path)['env'])")
    text = "\n".join(lines) + "\n" + yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)
    write_text_atomic(path, text)


__all__ = [
    "DEFAULT_BOUNDS",
    "DEFAULT_MOBIL_GRID",
    "IDM_FIELDS",
    "balanced_accuracy",
    "calibrate",
    "class_parameters",
    "car_following_segments",
    "decision_points",
    "fit_idm",
    "fit_mobil",
    "mobil_decision",
    "simulate_following",
    "write_calibration",
]
