"""Training curves (PNG) from the training-episode history: the paper's Fig. 8 (rewards over episodes) plus
speed and collision rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_training_curves(history: list[dict], path: str | Path, window: int = 50, title: str = "") -> Path:
    """Four panels: lane-change return, car-following return, mean speed, collision rate (trailing mean over
    ``window`` episodes, raw values faint). Written atomically to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd

    from ..atomic_files import write_atomic

    if not history:
        raise ValueError("plot_training_curves: no training episodes to plot")
    ep = np.arange(1, len(history) + 1)
    panels = [
        ("return_lc", "lane-change return (Eq. 26-29)"),
        ("return_cf", "car-following return (Eq. 32-33)"),
        ("mean_speed_kmh", "mean speed (km/h)"),
        ("collision", "collision rate"),
    ]
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for ax, (key, label) in zip(axes.flat, panels):
        y = np.asarray([float(h[key]) for h in history])
        if key != "collision":
            ax.plot(ep, y, color="tab:blue", alpha=0.2, lw=0.8, label="each episode")
        mean = f"trailing mean over {window} episodes" + (" (the share that collided)" if key == "collision" else "")
        ax.plot(ep, pd.Series(y).rolling(window, min_periods=1).mean(), color="tab:red", lw=1.6, label=mean)
        ax.set_title(label, fontsize=10)
        ax.legend(fontsize=8, loc="best")
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("training episode")
    fig.suptitle(f"{title or 'training curves'} (red: trailing mean over {window} episodes)")
    fig.tight_layout()
    path = Path(path)
    write_atomic(path, lambda fh: fig.savefig(fh, format="png", dpi=110), binary=True)
    plt.close(fig)
    return path
