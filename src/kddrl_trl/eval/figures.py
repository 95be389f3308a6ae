"""The report's figures (paper Figs. 8-10, 12-17) from run records (:class:`~kddrl_trl.eval.records.RunRecord`).

Every function writes one PNG and returns its path; a figure with nothing to draw is not written (None).
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _by(runs, *keys) -> dict:
    out = defaultdict(list)
    for r in runs:
        out[tuple(getattr(r, k) for k in keys)].append(r)
    return dict(out)


def _agent_grid(scenarios: list[str]):
    """One row per scenario, one column per agent (lane change, car following)."""
    plt = _plt()
    fig, axes = plt.subplots(len(scenarios), 2, figsize=(11, 3.4 * len(scenarios)), squeeze=False)
    agents = (("return_lc", "lane-change return"), ("return_cf", "car-following return"))
    return plt, fig, [(scenario, [(ax, *agent) for ax, agent in zip(row, agents)])
                      for scenario, row in zip(scenarios, axes)]


def training_curves(runs, path: Path, window: int = 50) -> Path | None:
    """Fig. 8: per scenario, both agents' training returns (rolling mean over ``window`` episodes), the mean over
    seeds as a line and the range over seeds (min to max) as a band."""
    learning = [r for r in runs if r.training is not None]
    if not learning:
        return None
    plt, fig, grid = _agent_grid(sorted({r.scenario for r in learning}))
    for scenario, panels in grid:
        for ax, key, title in panels:
            for (algo,), group in sorted(_by([r for r in learning if r.scenario == scenario], "algo").items()):
                n = min(len(r.training) for r in group)
                curves = np.stack([r.training[key].rolling(window, min_periods=1).mean().to_numpy()[:n] for r in group])
                x = np.arange(1, n + 1)
                line, = ax.plot(x, curves.mean(0), label=f"{algo} ({len(group)} seeds)")
                ax.fill_between(x, curves.min(0), curves.max(0), color=line.get_color(), alpha=0.2, lw=0)
            ax.set_title(f"{scenario}: {title}", fontsize=10)
            ax.set_xlabel("training episode")
            ax.set_ylabel(f"return (rolling mean, {window} ep)")
            ax.legend(fontsize=8)
    fig.suptitle("Training curves: mean over seeds, band = min..max over seeds (paper Fig. 8)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def return_boxes(runs, path: Path) -> Path | None:
    """Figs. 9 / 15: box plots of the evaluation episodes' returns of both agents, per algo and scenario (episodes
    of all seeds pooled)."""
    if not runs:
        return None
    plt, fig, grid = _agent_grid(sorted({r.scenario for r in runs}))
    for scenario, panels in grid:
        groups = sorted(_by([r for r in runs if r.scenario == scenario], "algo").items())
        for ax, key, title in panels:
            data = [np.concatenate([r.episodes[key].to_numpy() for r in g]) for _, g in groups]
            ax.boxplot(data, showfliers=False)
            ax.set_xticks(range(1, len(groups) + 1), [a for (a,), _ in groups], fontsize=8)
            ax.set_title(f"{scenario}: {title} per evaluation episode", fontsize=10)
    fig.suptitle("Evaluation returns (paper Figs. 9 / 15; whiskers 1.5 IQR, outliers hidden)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def distributions(runs, scenario: str, path: Path) -> Path | None:
    """Figs. 10 / 12 / 13: per algo, the distribution of the evaluation episodes' mean speed and mean
    acceleration on ``scenario`` (density over episodes; the band is the range of the per-seed densities)."""
    runs = [r for r in runs if r.scenario == scenario]
    if not runs:
        return None
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    for ax, key, label in zip(axes, ("mean_speed_kmh", "mean_accel"), ("mean speed (km/h)", "mean acceleration (m/s²)")):
        values = np.concatenate([r.episodes[key].to_numpy() for r in runs])
        bins = np.linspace(values.min(), values.max() + 1e-9, 31)
        centres = 0.5 * (bins[1:] + bins[:-1])
        for (algo,), group in sorted(_by(runs, "algo").items()):
            dens = np.stack([np.histogram(r.episodes[key], bins=bins, density=True)[0] for r in group])
            line, = ax.plot(centres, dens.mean(0), label=f"{algo} ({len(group)} seeds)")
            ax.fill_between(centres, dens.min(0), dens.max(0), color=line.get_color(), alpha=0.2, lw=0)
        ax.set_xlabel(f"{label} of an episode")
        ax.set_ylabel("density")
        ax.legend(fontsize=8)
    fig.suptitle(f"{scenario}: speed and acceleration per evaluation episode (paper Figs. 10 / 12 / 13)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def space_time(runs, out_dir: Path, prefer: str = "kddrl") -> dict:
    """Fig. 14 per scenario: the space-time diagrams of two recorded episodes (``traces/*.json`` of a run, made
    with ``video=true``), one with a lane change and one without, of ``prefer``'s runs where they have traces."""
    import json

    from .render import plot_space_time

    out = {}
    for scenario in sorted({r.scenario for r in runs}):
        holders = sorted([r for r in runs if r.scenario == scenario and r.traces],
                         key=lambda r: (r.algo != prefer, r.algo, r.seed))
        title = f"Fig. 14: {scenario}, space-time diagrams"
        if not holders:
            out[title] = None
            continue
        run = holders[0]
        traces = [json.loads(p.read_text()) for p in run.traces]
        picked = [next((t for t in traces if bool(t.get("lane_changes")) == want), None) for want in (True, False)]
        picked = [(f"{run.algo} on {scenario}, seed {run.seed}", t) for t in picked if t is not None]
        out[title] = plot_space_time(picked, out_dir / f"fig14_space_time_{scenario}.png")
    return out


def lcgan(metrics: dict | None, out_dir: Path) -> dict:
    """Figs. 16 / 17 from the lcGAN test metrics (class shares and confusion), when given."""
    title = "Figs. 16 / 17: lcGAN class shares and confusion"
    if not metrics:
        return {title: None}
    from ..generative.lcgan.figures import plot_confusion, plot_shares

    plot_shares(metrics, out_dir / "fig16_lcgan_shares.png")
    plot_confusion(metrics, out_dir / "fig17_lcgan_confusion.png")
    return {"Fig. 16: lcGAN class shares": out_dir / "fig16_lcgan_shares.png",
            "Fig. 17: lcGAN confusion": out_dir / "fig17_lcgan_confusion.png"}
