"""IDM calibration of the background drivers from naturalistic tracks (paper §IV.A, Eqs. 11-12).

Input is the 10 Hz longitudinal track table described in ``TRACKS10.md``.

* :func:`car_following_segments` cuts the table into maximal car-following runs (same lane, same present
  leader every frame).
* :func:`fit_idm` fits IDM (``delta`` = 4 fixed) per vehicle, per driver class or for the whole population by
  minimising the gap RMSE of a closed-loop simulation of the follower behind the observed leader; all groups
  at once, batched in torch, Levenberg-Marquardt on bounded log-parameters.

:mod:`kddrl_trl.data.calibrate` runs it with the MOBIL calibration (:mod:`kddrl_trl.data.calibrate_mobil`).
"""

from __future__ import annotations

import math
import time
from typing import Any, Hashable, Mapping

import numpy as np
import pandas as pd
import torch
from tensordict import TensorDict
from torch import Tensor

from kddrl_trl.physics.idm import IDMParams, idm_acceleration

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
#: every calibration tensor is float64 (closed-loop simulations over minutes of 10 Hz frames)
_DTYPE = torch.float64


def _following_rows(tracks: pd.DataFrame) -> pd.DataFrame:
    """The rows of a tracks10 table whose vehicle has a leader with a row at the same frame, joined with that
    row's ``leader_y``, ``leader_v``, ``leader_length``; sorted by (recording, vehicle, frame)."""
    cols = ["recording_id", "vehicle_id", "frame", "y", "v", "lane", "preceding_id", "driver_type"]
    df = tracks[cols]
    df = df[df["preceding_id"].to_numpy() != 0]
    lead = tracks[["recording_id", "vehicle_id", "frame", "y", "v", "length"]].rename(
        columns={"vehicle_id": "preceding_id", "y": "leader_y", "v": "leader_v", "length": "leader_length"}
    )
    m = df.merge(lead, on=["recording_id", "preceding_id", "frame"], how="inner")
    return m.sort_values(["recording_id", "vehicle_id", "frame"], kind="stable").reset_index(drop=True)


def _runs(m: pd.DataFrame, need: int, cut: int | None):
    """The car-following runs of the sorted rows ``m`` (same vehicle, consecutive frames, same leader, same lane),
    cut into pieces of at most ``cut`` frames, those of at least ``need`` frames kept: (segment of each kept row,
    its index inside the segment, the kept rows, the segments' sizes)."""
    n_rows = len(m)
    if not n_rows:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), m, np.zeros(0, dtype=np.int64)
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
    return new_id[run[keep]], pos[keep], m[keep], sizes[keep_run]


def _segment_grids(m: pd.DataFrame, seg: np.ndarray, pos: np.ndarray, sizes: np.ndarray, hz: float):
    """The segments as ``[N, F]`` grids, positions shifted so that each follower starts at 0, the leader padded
    at its last speed past the segment's end: (y, v, leader_y, leader_v, valid, each segment's first row)."""
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
    return y, v, ly, lv, valid, first


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
    m = _following_rows(tracks)
    type_names = tuple(sorted(set(str(t) for t in tracks["driver_type"].unique())))
    seg, pos, m, sizes = _runs(m, need, cut)
    n = len(sizes)
    y, v, ly, lv, valid, first = _segment_grids(m, seg, pos, sizes, hz)
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


def _idm_objective(
    segments: TensorDict,
    gidx: Tensor,
    n_groups: int,
    lo: Tensor,
    hi: Tensor,
    u_init: Tensor,
    delta: float,
    prior_weight: float,
):
    """The objective of :func:`fit_idm`: ``evaluate(u)`` of box coordinates ``u`` ``[R, G, 5]`` gives per
    (restart, group) the cost (half the gap's mse plus the pull toward ``u_init``), its gradient, the
    Gauss-Newton Hessian, and the mse; a group whose simulation is not finite costs ``inf``."""
    valid = segments["valid"].to(_DTYPE)
    obs_gap = segments["leader_y"] - segments["leader_length"][:, None] - segments["y"]
    cnt = torch.zeros(n_groups, dtype=_DTYPE).index_add_(0, gidx, valid.sum(-1)).clamp(min=1.0)
    eye = torch.eye(5, dtype=_DTYPE)

    def evaluate(uu: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        sim, jac = _simulate_sensitivities(segments, (lo + (hi - lo) * uu).exp()[:, gidx, :], hi - lo, delta)
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

    return evaluate


def _levenberg_marquardt(evaluate, u: Tensor, steps: int, lr: float, tol: float, progress: bool):
    """At most ``steps`` Levenberg-Marquardt iterations on every (restart, group) of ``u`` at once (Marquardt
    damping, steps clamped to 0.5 and projected on the box [0, 1]); a pair stops once its relative cost
    decrease falls below ``tol``. Returns (u, cost, mse, the mse at the start, iterations run)."""
    cost, grad, hess, mse = evaluate(u)
    mse_init = mse[0].clone()
    lam = torch.full(u.shape[:2], 1e-2, dtype=_DTYPE)
    active = torch.ones(u.shape[:2], dtype=torch.bool)
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
    return u, cost, mse, mse_init, iterations


def _idm_fit_table(segments, codes, uniques, gidx: Tensor, params: Tensor, cost, mse, mse_init, delta: float):
    """:func:`fit_idm` 's result: per group, the restart with the lowest finite mse wins."""
    n_groups = len(uniques)
    final = torch.where(torch.isfinite(cost), mse, torch.full_like(mse, float("inf")))
    winner = final.argmin(0)  # [G]
    g_ar = torch.arange(n_groups)
    theta = params[winner, g_ar]
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
    return out


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
    delta = float(init.delta)
    evaluate = _idm_objective(segments, gidx, n_groups, lo, hi, u_init, delta, prior_weight)
    u, cost, mse, mse_init, iterations = _levenberg_marquardt(evaluate, u, steps, lr, tol, progress)
    out = _idm_fit_table(segments, codes, uniques, gidx, (lo + (hi - lo) * u).exp(), cost, mse, mse_init, delta)
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
