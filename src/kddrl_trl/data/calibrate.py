"""Calibration of the background drivers' IDM and MOBIL parameters from naturalistic tracks (paper §IV.A).

Input is the 10 Hz longitudinal track table described in ``TRACKS10.md`` (one row per vehicle per frame,
front-bumper ``y`` growing in the direction of travel, ``lane`` 0 = rightmost, neighbour ids, 0 = none).

* :func:`car_following_segments` cuts the table into maximal car-following runs (same lane, same present
  leader every frame).
* :func:`fit_idm` fits IDM (Eq. 11-12; ``delta`` = 4 fixed) per vehicle, per driver class or for the whole
  population by minimising the gap RMSE of a closed-loop simulation of the follower behind the observed
  leader; all groups at once, batched in torch, Adam on bounded log-parameters.
* :func:`decision_points` and :func:`fit_mobil` calibrate MOBIL's politeness, threshold and ``b_safe``
  (Eq. 20-22) by a grid search maximising the balanced accuracy of the MOBIL decision rule.
* :func:`calibrate` runs everything; :func:`write_calibration` writes a YAML file whose ``env:`` block is a
  valid :func:`kddrl_trl.envs.make_config` override (``drivers:``) plus ``idm:`` and ``mobil:`` blocks.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import time
from typing import Any, Hashable, Mapping, Sequence

import numpy as np
import pandas as pd
import torch
from tensordict import TensorDict
from torch import Tensor

from kddrl_trl import keys as K
from kddrl_trl.io import write_text_atomic
from kddrl_trl.physics.idm import IDMParams, idm_acceleration
from kddrl_trl.physics.mobil import MOBILParams, mobil_utilities

#: fitted IDM parameters, in the order of the optimiser's parameter vector (names as in ``DriverClass``)
IDM_FIELDS = ("v0", "T", "s0", "a", "b")
#: default box constraints of the fit (SI units): v0 m/s, T s, s0 m, a and b m/s²
DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {
    "v0": (15.0, 60.0),
    "T": (0.3, 4.0),
    "s0": (0.5, 15.0),
    "a": (0.3, 10.0),
    "b": (0.5, 10.0),
}
#: MOBIL grid searched by default: politeness (-), threshold (m/s²), b_safe (m/s²)
DEFAULT_MOBIL_GRID: dict[str, Sequence[float]] = {
    "politeness": tuple(np.round(np.linspace(0.0, 1.0, 11), 3)),
    "threshold": tuple(np.round(np.linspace(0.0, 1.0, 11), 3)),
    "b_safe": (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0),
}
_NEIGHBOR_COLUMNS = (
    "left_preceding_id",
    "preceding_id",
    "right_preceding_id",
    "left_following_id",
    "following_id",
    "right_following_id",
)  # slots a..f
_DTYPE = torch.float64


# ------------------------------------------------------------------------------------------ segments
def car_following_segments(
    tracks: pd.DataFrame,
    min_duration_s: float = 5.0,
    hz: float = 10.0,
    max_duration_s: float | None = 60.0,
) -> TensorDict:
    """Maximal car-following runs of a tracks10 table.

    A run is a sequence of consecutive frames of one vehicle in which it keeps its lane and its
    ``preceding_id`` is the same, non-zero vehicle whose own row is present at every frame. Runs shorter
    than ``min_duration_s`` (duration = (frames - 1) / hz) are dropped; runs longer than ``max_duration_s``
    are cut into consecutive pieces of at most that duration (pieces shorter than the minimum dropped) to
    bound the padding and the closed-loop horizon of :func:`fit_idm`.

    Returns:
        TensorDict with batch size ``[N]`` (segments), time padded to the longest segment ``F``:
        ``y``, ``v`` ``[N, F]`` observed follower front-bumper position (m, shifted so that the follower
        starts at 0) and speed; ``leader_y``, ``leader_v`` ``[N, F]`` (same shift; padding extrapolates the
        leader at its last speed); ``leader_length`` ``[N]``; ``valid`` ``[N, F]`` bool; ``num_frames``,
        ``recording_id``, ``vehicle_id``, ``leader_id``, ``lane``, ``frame0``, ``driver_class`` ``[N]``
        int64. Non-tensor entries: ``driver_types`` (tuple of names indexed by ``driver_class``) and ``hz``.
    """
    need = int(math.floor(min_duration_s * hz + 1e-9)) + 1
    cut = None if max_duration_s is None else max(int(math.floor(max_duration_s * hz + 1e-9)) + 1, need)
    cols = ["recording_id", "vehicle_id", "frame", "y", "v", "lane", "preceding_id", "driver_type"]
    df = tracks[cols]
    df = df[df["preceding_id"].to_numpy() != 0]
    lead = tracks[["recording_id", "vehicle_id", "frame", "y", "v", "length"]].rename(
        columns={"vehicle_id": "preceding_id", "y": "leader_y", "v": "leader_v", "length": "leader_length"}
    )
    m = df.merge(lead, on=["recording_id", "preceding_id", "frame"], how="inner")
    m = m.sort_values(["recording_id", "vehicle_id", "frame"], kind="stable").reset_index(drop=True)
    type_names = tuple(sorted(set(str(t) for t in tracks["driver_type"].unique())))
    n_rows = len(m)
    if n_rows:
        rec, vid, frame = (m[c].to_numpy() for c in ("recording_id", "vehicle_id", "frame"))
        pid, lane = m["preceding_id"].to_numpy(), m["lane"].to_numpy()
        brk = np.ones(n_rows, dtype=bool)
        brk[1:] = (
            (rec[1:] != rec[:-1])
            | (vid[1:] != vid[:-1])
            | (frame[1:] != frame[:-1] + 1)
            | (pid[1:] != pid[:-1])
            | (lane[1:] != lane[:-1])
        )
        run = np.cumsum(brk) - 1
        pos = np.arange(n_rows) - np.flatnonzero(brk)[run]  # index inside the run
        if cut is not None:  # split long runs into pieces of at most `cut` frames
            run = run * (n_rows + 1) + pos // cut
            pos = pos % cut
            _, run = np.unique(run, return_inverse=True)
        sizes = np.bincount(run)
        keep_run = sizes >= need
        keep = keep_run[run]
        new_id = np.cumsum(keep_run) - 1
        seg, pos, m = new_id[run[keep]], pos[keep], m[keep]
        sizes = sizes[keep_run]
    else:
        seg = pos = np.zeros(0, dtype=np.int64)
        sizes = np.zeros(0, dtype=np.int64)
    n, f = len(sizes), int(sizes.max()) if len(sizes) else 0

    def grid(col: str) -> np.ndarray:
        out = np.zeros((n, f))
        out[seg, pos] = m[col].to_numpy(dtype=float)
        return out

    y, v, ly, lv = grid("y"), grid("v"), grid("leader_y"), grid("leader_v")
    valid = np.zeros((n, f), dtype=bool)
    valid[seg, pos] = True
    first = np.zeros(n, dtype=np.int64)
    if n:
        first = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])  # rows are grouped by segment, pos 0 first
        y0 = y[:, :1].copy()
        y, ly = y - y0, ly - y0
        # pad the leader at constant speed past the end (the follower keeps following; masked in the loss)
        last = sizes - 1
        k = np.arange(f)[None, :]
        ly_last, lv_last = ly[np.arange(n), last][:, None], lv[np.arange(n), last][:, None]
        ly = np.where(valid, ly, ly_last + lv_last * (k - last[:, None]) / hz)
        lv = np.where(valid, lv, lv_last)
        y = np.where(valid, y, 0.0)
        v = np.where(valid, v, 0.0)
    meta = m.iloc[first] if n else m

    def ints(col: str) -> Tensor:
        return torch.tensor(meta[col].to_numpy(dtype=np.int64)) if n else torch.zeros(0, dtype=torch.long)

    codes = [type_names.index(str(t)) for t in meta["driver_type"]] if n else []
    td = TensorDict(
        {
            "y": torch.as_tensor(y, dtype=_DTYPE),
            "v": torch.as_tensor(v, dtype=_DTYPE),
            "leader_y": torch.as_tensor(ly, dtype=_DTYPE),
            "leader_v": torch.as_tensor(lv, dtype=_DTYPE),
            "leader_length": torch.tensor(
                meta["leader_length"].to_numpy(dtype=float) if n else np.zeros(0), dtype=_DTYPE
            ),
            "valid": torch.as_tensor(valid),
            "num_frames": torch.as_tensor(sizes.astype(np.int64)),
            "recording_id": ints("recording_id"),
            "vehicle_id": ints("vehicle_id"),
            "leader_id": ints("preceding_id"),
            "lane": ints("lane"),
            "frame0": ints("frame"),
            "driver_class": torch.as_tensor(codes, dtype=torch.long),
        },
        batch_size=[n],
    )
    td.set_non_tensor("driver_types", type_names)
    td.set_non_tensor("hz", float(hz))
    return td


# ----------------------------------------------------------------------------------------- IDM fit
def _group_labels(segments: TensorDict, groups: Any) -> list[Hashable]:
    n = segments.batch_size[0]
    if groups is None or groups == "vehicle":
        rec, vid = segments["recording_id"].tolist(), segments["vehicle_id"].tolist()
        return list(zip(rec, vid))
    if groups in ("driver_type", "class"):
        names = segments.get_non_tensor("driver_types")
        return [names[i] for i in segments["driver_class"].tolist()]
    if groups == "all":
        return ["all"] * n
    labels = list(groups)
    if len(labels) != n:
        raise ValueError(f"groups: need one label per segment ({n}), got {len(labels)}")
    return labels


def simulate_following(segments: TensorDict, params: IDMParams, dt: float | None = None) -> Tensor:
    """Closed-loop IDM follower behind the observed leader; returns the simulated gaps ``[..., N, F]``.

    The follower starts at its observed position and speed and is integrated with IDM (Eq. 11-12) and
    semi-implicit Euler as SUMO does: ``v' = max(v + a dt, 0)``, ``y' = y + v' dt``. Gap (m) =
    ``leader_y - leader_length - y`` (front-bumper positions). ``params`` fields broadcast against ``[N]``.
    """
    dt = 1.0 / segments.get_non_tensor("hz") if dt is None else dt
    ly, lv, length = segments["leader_y"], segments["leader_v"], segments["leader_length"]
    y, v = segments["y"][..., 0], segments["v"][..., 0]
    f = ly.shape[-1]
    gaps = [ly[:, 0] - length - y]
    for k in range(f - 1):
        gap = ly[:, k] - length - y
        acc = idm_acceleration(v, lv[:, k], gap, params)
        v = (v + acc * dt).clamp(min=0.0)
        y = y + v * dt
        gaps.append(ly[:, k + 1] - length - y)
    return torch.stack(torch.broadcast_tensors(*gaps), dim=-1)


def _idm_partials(v: Tensor, v_lead: Tensor, gap: Tensor, theta: Tensor, delta: float) -> tuple[Tensor, ...]:
    """IDM acceleration (:func:`idm_acceleration`, Eq. 11-12) and its exact partial derivatives.

    ``theta`` ``[..., 5]`` = (v0, T, s0, a_max, b). The partials come from autograd through
    :func:`idm_acceleration` itself (the equation lives in one place); since IDM acts elementwise, the
    gradient of the sum is the elementwise partial. Returns ``a``, ``da/dv``, ``da/dgap``, ``da/dtheta``
    ``[..., 5]``, all detached.
    """
    with torch.enable_grad():
        v = v.detach().requires_grad_(True)
        gap = gap.detach().requires_grad_(True)
        th = [t.detach().requires_grad_(True) for t in theta.unbind(-1)]
        p = IDMParams(v0=th[0], T=th[1], s0=th[2], a_max=th[3], b=th[4], delta=delta)
        a = idm_acceleration(v, v_lead, gap, p)
        grads = torch.autograd.grad(a.sum(), [v, gap, *th])
    return a.detach(), grads[0], grads[1], torch.stack(grads[2:], dim=-1)


def _simulate_sensitivities(segments: TensorDict, theta: Tensor, dlog: Tensor, delta: float) -> tuple[Tensor, Tensor]:
    """:func:`simulate_following` plus forward sensitivities of the simulated gaps to the fit variables.

    ``theta`` ``[R, N, 5]`` per-segment parameters; ``dlog`` ``[5]`` = d(log theta)/d(fit variable). The
    integrator is differentiated exactly (``v' = max(v + a dt, 0)`` included). Returns gaps ``[R, N, F]``
    and their Jacobian ``[R, N, F, 5]``.
    """
    dt = 1.0 / segments.get_non_tensor("hz")
    ly, lv, length = segments["leader_y"], segments["leader_v"], segments["leader_length"]
    r = theta.shape[0]
    n, f = ly.shape
    y = segments["y"][:, 0].expand(r, n).clone()
    v = segments["v"][:, 0].expand(r, n).clone()
    s_y = torch.zeros(r, n, 5, dtype=theta.dtype)
    s_v = torch.zeros_like(s_y)
    dth = theta * dlog  # d theta / d fit variable
    gaps, sens = [ly[:, 0] - length - y], [s_y]
    for k in range(f - 1):
        a, a_v, a_g, a_th = _idm_partials(v, lv[:, k], ly[:, k] - length - y, theta, delta)
        da = a_v[..., None] * s_v - a_g[..., None] * s_y + a_th * dth
        v_new = v + a * dt
        moving = (v_new > 0).to(theta.dtype)[..., None]
        v = v_new.clamp(min=0.0)
        s_v = moving * (s_v + dt * da)
        y = y + v * dt
        s_y = s_y + dt * s_v
        gaps.append(ly[:, k + 1] - length - y)
        sens.append(s_y)
    gap = torch.stack(torch.broadcast_tensors(*gaps), dim=-1)
    jac = -torch.stack(sens, dim=-2)
    return gap, jac


def fit_idm(
    segments: TensorDict,
    groups: Any = None,
    steps: int = 40,
    lr: float = 1.0,
    restarts: int = 2,
    init: IDMParams = IDMParams(),
    bounds: Mapping[str, tuple[float, float]] | None = None,
    prior_weight: float = 1e-3,
    tol: float = 1e-6,
    seed: int = 0,
    progress: bool = False,
) -> pd.DataFrame:
    """Fit IDM (v0, T, s0, a, b; delta fixed at ``init.delta``) to car-following segments, all groups at once.

    Objective per group: mean squared gap error of the closed-loop :func:`simulate_following` over all
    valid frames of the group's segments (the reported ``rmse`` is that spacing RMSE, m). Each parameter
    is fitted as ``u`` in [0, 1] with ``x = lo (hi/lo)^u`` (log space, box ``bounds``). The optimiser is
    Levenberg-Marquardt (Gauss-Newton with Marquardt damping, projected on the box), every group and
    restart solved in one batch: exact forward sensitivities of the simulated gaps give each group's
    5 x 5 normal equations. ``steps`` is the maximum number of LM iterations (each one batched simulation
    with sensitivities); a group stops improving when its relative cost decrease stays below ``tol``.
    ``lr`` scales the LM step (1 = full step). Restart 0 starts at ``init`` (Table A.1), the others at
    random points of the box; the best per group wins. A weak quadratic pull toward ``init``
    (``prior_weight`` m² per unit u²) keeps parameters the data do not excite (``v0`` without free flow,
    ``b`` without strong braking) at their Table A.1 value instead of wandering; it is negligible against
    the gap error of identifiable ones.

    Args:
        segments: output of :func:`car_following_segments`.
        groups: ``None``/``"vehicle"`` one parameter set per (recording, vehicle); ``"driver_type"`` one
            per driver class; ``"all"`` one for the population; or a sequence with one label per segment.

    Returns:
        one row per group: ``group``, ``driver_type`` (most common among its segments), ``v0``, ``T``,
        ``s0``, ``a``, ``b``, ``delta``, ``rmse`` (fitted), ``rmse_init`` (with ``init``), ``n_segments``,
        ``seconds`` (valid following time), ``restart`` (which start won). ``attrs`` holds
        ``fit_seconds``, ``segments_per_second`` and ``iterations``.
    """
    t_start = time.perf_counter()
    labels = _group_labels(segments, groups)
    codes, uniques = pd.factorize(pd.Series(labels, dtype=object), sort=False)
    n_groups, n_seg = len(uniques), len(labels)
    columns = ["group", "driver_type", *IDM_FIELDS, "delta", "rmse", "rmse_init", "n_segments", "seconds", "restart"]
    if n_seg == 0:
        return pd.DataFrame(columns=columns)
    bnd = {**DEFAULT_BOUNDS, **(bounds or {})}
    lo = torch.tensor([math.log(bnd[k][0]) for k in IDM_FIELDS], dtype=_DTYPE)
    hi = torch.tensor([math.log(bnd[k][1]) for k in IDM_FIELDS], dtype=_DTYPE)
    start = torch.tensor(
        [float(init.v0), float(init.T), float(init.s0), float(init.a_max), float(init.b)], dtype=_DTYPE
    )
    u_init = ((start.log() - lo) / (hi - lo)).clamp(0.0, 1.0)
    gen = torch.Generator().manual_seed(seed)
    u = u_init.expand(restarts, n_groups, 5).clone()
    if restarts > 1:
        u[1:] = 0.1 + 0.8 * torch.rand(restarts - 1, n_groups, 5, generator=gen, dtype=_DTYPE)
    gidx = torch.as_tensor(codes, dtype=torch.long)
    valid = segments["valid"].to(_DTYPE)
    obs_gap = segments["leader_y"] - segments["leader_length"][:, None] - segments["y"]
    cnt = torch.zeros(n_groups, dtype=_DTYPE).index_add_(0, gidx, valid.sum(-1)).clamp(min=1.0)
    delta = float(init.delta)
    eye = torch.eye(5, dtype=_DTYPE)

    def params_of(uu: Tensor) -> Tensor:
        return (lo + (hi - lo) * uu).exp()

    def evaluate(uu: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """cost (0.5 mse + prior), gradient, Gauss-Newton Hessian per (restart, group); and the mse."""
        sim, jac = _simulate_sensitivities(segments, params_of(uu)[:, gidx, :], hi - lo, delta)
        res = (sim - obs_gap) * valid
        bad = ~torch.isfinite(res).all(-1) | ~torch.isfinite(jac).all(-1).all(-1)  # [R, N]
        res = torch.nan_to_num(res, nan=1e6, posinf=1e6, neginf=-1e6)
        jac = torch.nan_to_num(jac, nan=0.0, posinf=0.0, neginf=0.0) * valid[..., None]
        r_ = uu.shape[0]
        sse = torch.zeros(r_, n_groups, dtype=_DTYPE).index_add_(1, gidx, (res**2).sum(-1))
        jtr = torch.zeros(r_, n_groups, 5, dtype=_DTYPE).index_add_(1, gidx, torch.einsum("rnfi,rnf->rni", jac, res))
        jtj = torch.zeros(r_, n_groups, 5, 5, dtype=_DTYPE).index_add_(
            1, gidx, torch.einsum("rnfi,rnfj->rnij", jac, jac)
        )
        nbad = torch.zeros(r_, n_groups, dtype=_DTYPE).index_add_(1, gidx, bad.to(_DTYPE))
        mse = sse / cnt
        du = uu - u_init
        cost = 0.5 * mse + 0.5 * prior_weight * (du**2).sum(-1)
        cost = torch.where(nbad > 0, torch.full_like(cost, float("inf")), cost)
        grad = jtr / cnt[:, None] + prior_weight * du
        hess = jtj / cnt[:, None, None] + prior_weight * eye
        return cost, grad, hess, mse

    cost, grad, hess, mse = evaluate(u)
    mse_init = mse[0].clone()
    lam = torch.full((restarts, n_groups), 1e-2, dtype=_DTYPE)
    active = torch.ones(restarts, n_groups, dtype=torch.bool)
    iterations = 0
    for _ in _progress(range(steps), progress, "fit IDM"):
        if not bool(active.any()):
            break
        iterations += 1
        diag = torch.diagonal(hess, dim1=-2, dim2=-1)
        damped = hess + torch.diag_embed(lam[..., None] * diag + 1e-9)
        step = -torch.linalg.solve(damped, grad[..., None])[..., 0]
        step = torch.nan_to_num(step, nan=0.0).clamp(-0.5, 0.5) * lr
        cand = (u + step).clamp(0.0, 1.0)
        c_cost, c_grad, c_hess, c_mse = evaluate(cand)
        ok = (c_cost < cost) & active
        gain = torch.where(torch.isfinite(cost), (cost - c_cost) / cost.clamp(min=1e-12), torch.ones_like(cost))
        u = torch.where(ok[..., None], cand, u)
        grad = torch.where(ok[..., None], c_grad, grad)
        hess = torch.where(ok[..., None, None], c_hess, hess)
        mse = torch.where(ok, c_mse, mse)
        cost = torch.where(ok, c_cost, cost)
        lam = torch.where(ok, (lam * 0.3).clamp(min=1e-7), (lam * 5.0).clamp(max=1e8))
        active = active & ~(ok & (gain < tol)) & (lam < 1e8)
    final = torch.where(torch.isfinite(cost), mse, torch.full_like(mse, float("inf")))
    winner = final.argmin(0)  # [G]
    g_ar = torch.arange(n_groups)
    theta = params_of(u[winner, g_ar])
    rmse = final[winner, g_ar].sqrt()
    rmse_init = mse_init.sqrt()
    dtypes = segments.get_non_tensor("driver_types")
    seg_type = pd.Series([dtypes[i] for i in segments["driver_class"].tolist()])
    mode_type = seg_type.groupby(codes).agg(lambda s: s.value_counts().index[0])
    hz = segments.get_non_tensor("hz")
    frames = segments["num_frames"].to(_DTYPE)
    seconds = torch.zeros(n_groups, dtype=_DTYPE).index_add_(0, gidx, (frames - 1) / hz)
    out = pd.DataFrame(
        {
            "group": list(uniques),
            "driver_type": mode_type.reindex(range(n_groups)).to_numpy(),
            **{k: theta[:, i].numpy() for i, k in enumerate(IDM_FIELDS)},
            "delta": delta,
            "rmse": rmse.numpy(),
            "rmse_init": rmse_init.numpy(),
            "n_segments": np.bincount(codes, minlength=n_groups),
            "seconds": seconds.numpy(),
            "restart": winner.numpy(),
        }
    )
    out.attrs["fit_seconds"] = time.perf_counter() - t_start
    out.attrs["segments_per_second"] = n_seg / max(out.attrs["fit_seconds"], 1e-9)
    out.attrs["iterations"] = iterations
    return out


def _progress(it, enabled: bool, desc: str):
    if not enabled:
        return it
    try:
        from tqdm.auto import tqdm
    except ImportError:  # pragma: no cover
        return it
    return tqdm(it, desc=desc, leave=False)


# ----------------------------------------------------------------------------------- MOBIL decisions
def decision_points(
    tracks: pd.DataFrame,
    horizon_s: float = 1.0,
    hz: float = 10.0,
    cooldown_s: float = 1.0,
    num_lanes: int | None = None,
) -> TensorDict:
    """One lane-change decision point per vehicle and 10 Hz frame, with the observed decision.

    The label is ``LEFT`` (0) / ``RIGHT`` (2) when the vehicle's lane index changes to the left (+1) /
    right (-1) within the next ``horizon_s`` (the first crossing counts), else ``KEEP`` (1). Frames whose
    future is not observed for ``horizon_s`` without a crossing, and frames within ``cooldown_s`` after a
    crossing (the manoeuvre is still completing), are dropped. Neighbour slots a..f come from
    ``left_preceding_id, preceding_id, right_preceding_id, left_following_id, following_id,
    right_following_id``; a slot is present when the id is non-zero and that vehicle has a row at the same
    frame. ``num_lanes`` defaults to ``max(lane) + 1`` of each recording.

    Returns:
        TensorDict ``[N]``: ``ego_y``, ``ego_v``, ``ego_length`` (float64); ``("neighbors", "kin")``
        ``[N, 6, 3]`` (y, v, a); ``("neighbors", "mask")`` ``[N, 6]`` bool; ``("neighbors", "length")``
        ``[N, 6]``; ``lane``, ``num_lanes``, ``label``, ``recording_id``, ``vehicle_id``, ``frame`` int64.
    """
    df = tracks.sort_values(["recording_id", "vehicle_id", "frame"], kind="stable").reset_index(drop=True)
    rec, vid, frame = (df[c].to_numpy(dtype=np.int64) for c in ("recording_id", "vehicle_id", "frame"))
    lane = df["lane"].to_numpy(dtype=np.int64)
    n = len(df)
    h, cool = int(round(horizon_s * hz)), int(round(cooldown_s * hz))
    same = np.zeros(n, dtype=bool)
    same[1:] = (rec[1:] == rec[:-1]) & (vid[1:] == vid[:-1])
    chg = np.zeros(n, dtype=bool)
    chg[1:] = same[1:] & (lane[1:] != lane[:-1])
    step = np.zeros(n, dtype=np.int64)
    step[1:] = np.sign(lane[1:] - lane[:-1])
    chg_pos = np.flatnonzero(chg)
    idx = np.arange(n)
    # next crossing strictly after the row, within the same vehicle and the horizon
    j = np.searchsorted(chg_pos, idx, side="right")
    has_next = j < len(chg_pos)
    nxt = np.where(has_next, chg_pos[np.minimum(j, max(len(chg_pos) - 1, 0))] if len(chg_pos) else 0, -1)
    in_h = (
        has_next
        & (rec[np.maximum(nxt, 0)] == rec)
        & (vid[np.maximum(nxt, 0)] == vid)
        & (frame[np.maximum(nxt, 0)] - frame <= h)
    )
    label = np.full(n, K.KEEP, dtype=np.int64)
    label[in_h & (step[np.maximum(nxt, 0)] > 0)] = K.LEFT
    label[in_h & (step[np.maximum(nxt, 0)] < 0)] = K.RIGHT
    # last frame of each vehicle: future observed for the horizon?
    last_frame = pd.Series(frame).groupby([rec, vid]).transform("max").to_numpy()
    observed = (last_frame - frame) >= h
    # previous crossing at or before the row (cooldown)
    jp = np.searchsorted(chg_pos, idx, side="right") - 1
    has_prev = jp >= 0
    prv = chg_pos[np.maximum(jp, 0)] if len(chg_pos) else np.zeros(n, dtype=np.int64)
    recent = (
        has_prev & (rec[prv] == rec) & (vid[prv] == vid) & (frame - frame[prv] < cool)
        if len(chg_pos)
        else np.zeros(n, dtype=bool)
    )
    keep = (in_h | observed) & ~recent

    # neighbour lookup by a packed (recording, vehicle, frame) key
    def pack(r, v_, f_):
        return (r.astype(np.int64) << 44) | (v_.astype(np.int64) << 24) | f_.astype(np.int64)

    index = pd.Index(pack(rec, vid, frame))
    kin = np.zeros((n, 6, 3))
    mask = np.zeros((n, 6), dtype=bool)
    lengths = np.zeros((n, 6))
    yva = df[["y", "v", "a"]].to_numpy(dtype=float)
    length = df["length"].to_numpy(dtype=float)
    for s, col in enumerate(_NEIGHBOR_COLUMNS):
        nid = df[col].to_numpy(dtype=np.int64)
        pos = index.get_indexer(pack(rec, nid, frame))
        ok = (nid != 0) & (pos >= 0)
        kin[ok, s] = yva[pos[ok]]
        lengths[ok, s] = length[pos[ok]]
        mask[:, s] = ok
    if num_lanes is None:
        nl = pd.Series(lane).groupby(rec).transform("max").to_numpy() + 1
    else:
        nl = np.full(n, int(num_lanes))
    sel = np.flatnonzero(keep)
    return TensorDict(
        {
            "ego_y": torch.as_tensor(yva[sel, 0], dtype=_DTYPE),
            "ego_v": torch.as_tensor(yva[sel, 1], dtype=_DTYPE),
            "ego_length": torch.as_tensor(length[sel], dtype=_DTYPE),
            K.NEIGHBORS_KIN: torch.as_tensor(kin[sel], dtype=_DTYPE),
            K.NEIGHBORS_MASK: torch.as_tensor(mask[sel]),
            ("neighbors", "length"): torch.as_tensor(lengths[sel], dtype=_DTYPE),
            "lane": torch.as_tensor(lane[sel]),
            "num_lanes": torch.as_tensor(nl[sel].astype(np.int64)),
            "label": torch.as_tensor(label[sel]),
            "recording_id": torch.as_tensor(rec[sel]),
            "vehicle_id": torch.as_tensor(vid[sel]),
            "frame": torch.as_tensor(frame[sel]),
        },
        batch_size=[len(sel)],
    )


def mobil_decision(U: Tensor, safe: Tensor, threshold: Tensor | float) -> Tensor:
    """MOBIL decision rule: change to d iff safe, ``U_d > threshold`` and ``U_d`` beats the other direction.

    ``U``, ``safe``: ``[..., 3]`` ordered (left, keep, right) as from :func:`mobil_utilities`; ``threshold``
    broadcasts against ``[...]``. Returns int64 labels 0 left / 1 keep / 2 right (ties go left).
    """
    ul, ur = U[..., K.LEFT], U[..., K.RIGHT]
    ok_l = safe[..., K.LEFT] & (ul > threshold)
    ok_r = safe[..., K.RIGHT] & (ur > threshold)
    go_l = ok_l & (~ok_r | (ul >= ur))
    go_r = ok_r & ~go_l
    out = torch.full(go_l.shape, K.KEEP, dtype=torch.long)
    out = torch.where(go_l, torch.full_like(out, K.LEFT), out)
    return torch.where(go_r, torch.full_like(out, K.RIGHT), out)


def balanced_accuracy(pred: Tensor, label: Tensor) -> tuple[float, list[float]]:
    """Mean per-class recall over the classes present in ``label``; also the recalls (left, keep, right)."""
    recalls = []
    for c in (K.LEFT, K.KEEP, K.RIGHT):
        m = label == c
        recalls.append(float((pred[..., m] == c).double().mean()) if bool(m.any()) else float("nan"))
    present = [r for r in recalls if not math.isnan(r)]
    return (float(np.mean(present)) if present else float("nan")), recalls


def _pair_lengths(decisions: TensorDict, default: float) -> Tensor | float:
    """Leader length of each of the 9 IDM pairs of :func:`mobil_utilities` (leaders b, ego, b, a, a, ego, c, c, ego)."""
    if ("neighbors", "length") not in decisions.keys(include_nested=True) or "ego_length" not in decisions.keys():
        return default
    nl, ego = decisions["neighbors", "length"], decisions["ego_length"]
    a, b, c = nl[:, K.SLOT["a"]], nl[:, K.SLOT["b"]], nl[:, K.SLOT["c"]]
    return torch.stack([b, ego, b, a, a, ego, c, c, ego], dim=-1)


def fit_mobil(
    decisions: TensorDict,
    grid: Mapping[str, Sequence[float]] | None = None,
    idm: IDMParams | None = None,
    table: MOBILParams = MOBILParams(),
    max_keep: int | None = 200_000,
    seed: int = 0,
) -> dict[str, Any]:
    """Grid search of MOBIL's politeness ``p``, threshold ``Δa_th`` and ``b_safe`` (Eq. 20-22).

    For every grid point the MOBIL decision rule (:func:`mobil_decision` on :func:`mobil_utilities` with
    IDM ``idm``, default Table A.1, and the observed leader lengths where ``decisions`` has them) is
    compared with the observed labels; the point with the highest balanced accuracy (mean recall over
    left / keep / right) wins. Ties are broken by taking the tied point nearest (in grid-normalised units)
    to the centroid of all tied points. ``U`` is linear in ``p``, so each ``b_safe`` costs two utility
    evaluations. At most ``max_keep`` randomly chosen keep decisions are used (recall is unbiased under
    that subsampling).

    Returns:
        dict with ``politeness``, ``threshold``, ``b_safe``, ``balanced_accuracy``, ``recall`` (left, keep,
        right), ``n_ties``, ``n_decisions`` (per class), and ``table_a1`` (the same metrics for ``table``).
    """
    g = {**DEFAULT_MOBIL_GRID, **(grid or {})}
    idm = IDMParams() if idm is None else idm
    label = decisions["label"]
    sel = torch.arange(len(label))
    if max_keep is not None and int((label == K.KEEP).sum()) > max_keep:
        gen = torch.Generator().manual_seed(seed)
        keep_idx = torch.nonzero(label == K.KEEP).squeeze(-1)
        keep_idx = keep_idx[torch.randperm(len(keep_idx), generator=gen)[:max_keep]]
        sel = torch.cat([torch.nonzero(label != K.KEEP).squeeze(-1), keep_idx]).sort().values
    d = decisions[sel]
    label = d["label"]
    lengths = _pair_lengths(d, float(idm.length))
    idm_l = IDMParams(v0=idm.v0, T=idm.T, s0=idm.s0, a_max=idm.a_max, b=idm.b, delta=idm.delta, length=lengths)
    args = (d["ego_y"], d["ego_v"], d[K.NEIGHBORS_KIN], d[K.NEIGHBORS_MASK], d["lane"], d["num_lanes"])

    def utilities(p: float, b_safe: float) -> tuple[Tensor, Tensor]:
        mp = MOBILParams(politeness=p, threshold=0.0, b_safe=b_safe, y_safe=table.y_safe)
        return mobil_utilities(*args, idm=idm_l, mobil=mp)

    P = torch.as_tensor(g["politeness"], dtype=_DTYPE)
    TH = torch.as_tensor(g["threshold"], dtype=_DTYPE)
    B = torch.as_tensor(g["b_safe"], dtype=_DTYPE)
    scores = torch.empty(len(P), len(TH), len(B), dtype=_DTYPE)
    classes = [c for c in (K.LEFT, K.KEEP, K.RIGHT) if bool((label == c).any())]
    counts = torch.bincount(label, minlength=3).to(_DTYPE)
    with torch.no_grad():
        for ib, b in enumerate(B.tolist()):
            u0, safe = utilities(0.0, b)
            u1, _ = utilities(1.0, b)
            for ip, p in enumerate(P.tolist()):
                U = u0 + p * (u1 - u0)
                pred = mobil_decision(U.unsqueeze(0), safe.unsqueeze(0), TH[:, None])  # [TH, N]
                hit = (pred == label).to(_DTYPE)
                per_class = torch.stack([(hit * (label == c)).sum(-1) / counts[c] for c in classes], -1)
                scores[ip, :, ib] = per_class.mean(-1)
        best = scores.max()
        tied = torch.nonzero(scores >= best - 1e-12)  # [M, 3] grid indices
        span = torch.tensor([max(len(P) - 1, 1), max(len(TH) - 1, 1), max(len(B) - 1, 1)], dtype=_DTYPE)
        pts = tied.to(_DTYPE) / span
        i = int(((pts - pts.mean(0)) ** 2).sum(-1).argmin())
        ip, it, ib = tied[i].tolist()
        chosen = (float(P[ip]), float(TH[it]), float(B[ib]))

        def evaluate(p: float, th: float, b: float) -> tuple[float, list[float]]:
            u0, safe = utilities(p, b)
            return balanced_accuracy(mobil_decision(u0, safe, th), label)

        ba, rec = evaluate(*chosen)
        ba_t, rec_t = evaluate(float(table.politeness), float(table.threshold), float(table.b_safe))
    return {
        "politeness": chosen[0],
        "threshold": chosen[1],
        "b_safe": chosen[2],
        "balanced_accuracy": ba,
        "recall": rec,
        "n_ties": int(len(tied)),
        "n_decisions": {name: int((decisions["label"] == c).sum()) for name, c in zip(K.LC_ACTIONS, range(3))},
        "table_a1": {
            "politeness": float(table.politeness),
            "threshold": float(table.threshold),
            "b_safe": float(table.b_safe),
            "balanced_accuracy": ba_t,
            "recall": rec_t,
        },
    }


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


# --------------------------------------------------------------------------------------- end to end
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
    spread otherwise) are those of the default class of the same name (``DriverClass`` defaults otherwise). ``idm:`` holds the population fit, ``mobil:`` the MOBIL fit.
    """
    import yaml

    from kddrl_trl.envs.config import DriverClass, default_drivers

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
