"""Figures of the trajGAN test evaluation (paper §IV.F): error per horizon step and sampled futures."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch
from torch import Tensor


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def plot_errors(per_step: Mapping[str, Sequence[float]], path: Path) -> None:
    """MAE per horizon step of each predictor (``trajgan_errors.png``)."""
    fig = _figure(6, 4)
    ax = fig.add_subplot(1, 1, 1)
    labels = {"trajgan": "trajGAN", "idm_prior": "IDM prior", "const_velocity": "constant velocity"}
    for name, values in per_step.items():
        ax.plot(np.arange(1, len(values) + 1), values, marker="o", ms=3, label=labels.get(name, name))
    ax.set_xlabel("prediction step (0.1 s)")
    ax.set_ylabel("MAE (m)")
    ax.set_title("trajGAN test error per horizon step")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)


def plot_samples(
    history: Tensor, prior: Tensor, many: Tensor, future: Tensor, cases: int, dt: float, seed: int, path: Path
) -> None:
    """History, IDM prior, sampled futures and truth of ``cases`` seeded test cases (``trajgan_samples.png``),
    drawn relative to constant velocity."""
    n = len(future)
    cases = max(1, min(cases, n))
    idx = (
        torch.randperm(n, generator=torch.Generator().manual_seed(seed))[:cases]
        if n
        else torch.zeros(0, dtype=torch.long)
    )
    fig = _figure(4 * cases, 3.6)
    history, prior, many, future = (x.detach().cpu().double().numpy() for x in (history, prior, many, future))
    h, t = history.shape[1], future.shape[-1]
    th = (np.arange(h) - (h - 1)) * dt
    tf = np.arange(1, t + 1) * dt
    for j, i in enumerate(idx.tolist()):
        ax = fig.add_subplot(1, cases, j + 1)
        y0, v0 = float(history[i, -1, 0]), float(history[i, -1, 1])
        ax.plot(th, history[i, :, 0] - y0 - v0 * th, "k.-", label="history")
        for s in range(many.shape[1]):
            ax.plot(
                tf,
                many[i, s] - y0 - v0 * tf,
                color="tab:blue",
                alpha=0.35,
                lw=1,
                label="trajGAN samples" if s == 0 else None,
            )
        ax.plot(tf, prior[i] - y0 - v0 * tf, "--", color="tab:orange", label="IDM prior")
        ax.plot(tf, future[i] - y0 - v0 * tf, color="k", lw=2, label="truth")
        ax.axhline(0.0, color="tab:green", lw=1, ls=":", label="constant velocity")
        ax.set_xlabel("t (s)")
        ax.set_title(f"test case {i} (v0 = {v0:.1f} m/s)", fontsize=9)
        ax.grid(alpha=0.3)
        if j == 0:
            ax.set_ylabel("y - y0 - v0 t (m)")
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
