"""MOBIL calibration of the background drivers from naturalistic tracks (paper §IV.A, Eqs. 20-22).

Input is the 10 Hz longitudinal track table described in ``TRACKS10.md``.

* :func:`decision_points` gives one lane-change decision per vehicle and frame, with the observed label.
* :func:`fit_mobil` grid-searches MOBIL's politeness, threshold and ``b_safe`` for the highest balanced
  accuracy of the MOBIL decision rule.

:mod:`kddrl_trl.data.calibrate` runs it with the IDM calibration (:mod:`kddrl_trl.data.calibrate_idm`).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
import torch
from tensordict import TensorDict
from torch import Tensor

from kddrl_trl import keys as K
from kddrl_trl.physics.idm import IDMParams
from kddrl_trl.physics.mobil import MOBILParams, mobil_utilities

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
#: every calibration tensor is float64 (closed-loop simulations over minutes of 10 Hz frames)
_DTYPE = torch.float64


def _decision_labels(rec: np.ndarray, vid: np.ndarray, frame: np.ndarray, lane: np.ndarray, h: int, cool: int):
    """Of each row (sorted by recording, vehicle, frame): its label (the first lane crossing within ``h``
    frames, else ``KEEP``) and whether it is kept (its future observed for ``h`` frames or a crossing within
    them, and no crossing in the ``cool`` frames before)."""
    n = len(rec)
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
    return label, keep


def _neighbour_slots(df: pd.DataFrame, rec: np.ndarray, vid: np.ndarray, frame: np.ndarray):
    """The six neighbour slots of each row: (y, v, a) ``[N, 6, 3]``, presence ``[N, 6]``, lengths ``[N, 6]``;
    and the rows' own (y, v, a) and length. A slot is present when its id is non-zero and that vehicle has a
    row at the same frame."""
    n = len(df)

    # lookup by a packed (recording, vehicle, frame) key
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
    return kin, mask, lengths, yva, length


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
    label, keep = _decision_labels(rec, vid, frame, lane, int(round(horizon_s * hz)), int(round(cooldown_s * hz)))
    kin, mask, lengths, yva, length = _neighbour_slots(df, rec, vid, frame)
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


def _subsample_keeps(decisions: TensorDict, max_keep: int | None, seed: int) -> TensorDict:
    """``decisions`` with at most ``max_keep`` of its keep decisions, chosen at random (all the others kept,
    order kept)."""
    label = decisions["label"]
    sel = torch.arange(len(label))
    if max_keep is not None and int((label == K.KEEP).sum()) > max_keep:
        gen = torch.Generator().manual_seed(seed)
        keep_idx = torch.nonzero(label == K.KEEP).squeeze(-1)
        keep_idx = keep_idx[torch.randperm(len(keep_idx), generator=gen)[:max_keep]]
        sel = torch.cat([torch.nonzero(label != K.KEEP).squeeze(-1), keep_idx]).sort().values
    return decisions[sel]


def _grid_scores(utilities, P: Tensor, TH: Tensor, B: Tensor, label: Tensor) -> Tensor:
    """The balanced accuracy of MOBIL's decision at every grid point ``[P, TH, B]``. ``U`` is linear in the
    politeness, so each ``b_safe`` costs two evaluations of ``utilities(p, b_safe)``."""
    scores = torch.empty(len(P), len(TH), len(B), dtype=_DTYPE)
    classes = [c for c in (K.LEFT, K.KEEP, K.RIGHT) if bool((label == c).any())]
    counts = torch.bincount(label, minlength=3).to(_DTYPE)
    for ib, b in enumerate(B.tolist()):
        u0, safe = utilities(0.0, b)
        u1, _ = utilities(1.0, b)
        for ip, p in enumerate(P.tolist()):
            U = u0 + p * (u1 - u0)
            pred = mobil_decision(U.unsqueeze(0), safe.unsqueeze(0), TH[:, None])  # [TH, N]
            hit = (pred == label).to(_DTYPE)
            per_class = torch.stack([(hit * (label == c)).sum(-1) / counts[c] for c in classes], -1)
            scores[ip, :, ib] = per_class.mean(-1)
    return scores


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
    d = _subsample_keeps(decisions, max_keep, seed)
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
    with torch.no_grad():
        scores = _grid_scores(utilities, P, TH, B, label)
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
