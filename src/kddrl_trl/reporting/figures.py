"""The report's figures (paper Figs. 8-10, 12-17) from run records (:class:`~kddrl_trl.reporting.records.RunRecord`).

Every function writes one PNG and returns its path; a figure with nothing to draw is not written (None).

Readability rules, the same in every figure: each system has one colour, drawn solid (:func:`style`; a system's
option variants are dashed, in colours of their own), an axes draws at most :data:`MAX_SERIES` series (more are
split into panels, :func:`series_panels`, each with the system's plain run as the reference), bands of the spread
over seeds only where an axes has few series, and legends sit outside the data, right of the axes.
"""

from __future__ import annotations

import re
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: the systems in the paper's order; each has its colour (matplotlib's tab10) in every figure
SYSTEMS = (
    "kddrl",
    "ni",
    "peng",
    "d3qn_unified",
    "pasac_unified",
    "d3qn_td3",
    "d3qn_td3_lg",
    "kddrl_same_clock",
    "idm_mobil",
)
#: the most series one axes draws
MAX_SERIES = 8
#: at most this many series in an axes get the band of their spread over seeds
MAX_BANDS = 3


def system_of(label: str) -> str:
    """The system of a report label: ``"kddrl [algo.shield=idm]"``, ``"kddrl @abc1234"`` and
    ``"kddrl (trained on mixed)"`` are all ``kddrl``."""
    return re.split(r" \[| @| \(", label, maxsplit=1)[0]


def style(label: str, labels) -> dict:
    """``color``, ``linestyle`` and ``lw`` of ``label`` among all ``labels`` of a report: a system (its plain run) in
    its own colour of tab10, solid; an option variant of it dashed, in the colour of its rank among the system's
    variants in Dark2 (dash-dotted from the ninth on)."""
    from matplotlib import colormaps

    system = system_of(label)
    if label == system:
        index = SYSTEMS.index(system) if system in SYSTEMS else len(SYSTEMS)
        return {"color": colormaps["tab10"].colors[index % 10], "linestyle": "-", "lw": 1.8}
    variants = sorted({lab for lab in labels if system_of(lab) == system and lab != system})
    rank = variants.index(label)
    return {"color": colormaps["Dark2"].colors[rank % 8], "linestyle": "--" if rank < 8 else "-.", "lw": 1.1}


def _order(label: str):
    system = system_of(label)
    return (SYSTEMS.index(system) if system in SYSTEMS else len(SYSTEMS), system, label != system, label)


def series_panels(labels, limit: int = MAX_SERIES) -> list[list[str]]:
    """``labels`` split into panels of at most ``limit`` series: all in one when they fit; otherwise every system
    with option variants gets panels of its own (its plain run in each, as the reference), and the systems without
    variants fill the room left, then panels of their own."""
    labels = sorted(set(labels), key=_order)
    if len(labels) <= limit:
        return [labels]
    by_system: dict[str, list[str]] = defaultdict(list)
    for lab in labels:
        by_system[system_of(lab)].append(lab)
    plain, panels = [], []
    for system, group in by_system.items():
        if len(group) == 1:
            plain += group
            continue
        variants = [lab for lab in group if lab != system]
        head = [system] if system in group else []
        size = limit - len(head)
        panels += [head + variants[i : i + size] for i in range(0, len(variants), size)]
    for lab in plain:
        room = next((p for p in panels if len(p) < limit), None)
        if room is None:
            room = []
            panels.append(room)
        room.append(lab)
    return [p for p in panels if p]


def _tight(fig) -> None:
    """``tight_layout`` leaving room for the suptitle (about 0.4 inch at the top)."""
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.4 / fig.get_figheight()))


def seed_count(n: int) -> str:
    """A count of seeds as the figures' legends and the report's rows write it: "1 seed", "n seeds"."""
    return f"{n} seed" if n == 1 else f"{n} seeds"


def _legend(ax) -> None:
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, frameon=False)


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
    fig, axes = plt.subplots(len(scenarios), 2, figsize=(14, 3.4 * len(scenarios)), squeeze=False)
    agents = (("return_lc", "lane-change return"), ("return_cf", "car-following return"))
    return (
        plt,
        fig,
        [(scenario, [(ax, *agent) for ax, agent in zip(row, agents)]) for scenario, row in zip(scenarios, axes)],
    )


def training_curves(runs, path: Path, window: int = 50) -> Path | None:
    """Fig. 8: per scenario, both agents' training returns (rolling mean over ``window`` episodes), the mean over
    seeds as a line and, where drawn, the range over seeds (min to max) as a band."""
    learning = [r for r in runs if r.training is not None]
    if not learning:
        return None
    labels = sorted({r.algo for r in learning})
    rows = [
        (scenario, panel)
        for scenario in sorted({r.scenario for r in learning})
        for panel in series_panels({r.algo for r in learning if r.scenario == scenario})
    ]
    plt, fig, grid = _agent_grid([scenario for scenario, _ in rows])
    for (scenario, panel), (_, axes) in zip(rows, grid):
        for ax, key, title in axes:
            groups = _by([r for r in learning if r.scenario == scenario and r.algo in panel], "algo")
            for algo in panel:
                group = groups[(algo,)]
                n = min(len(r.training) for r in group)
                curves = np.stack([r.training[key].rolling(window, min_periods=1).mean().to_numpy()[:n] for r in group])
                x = np.arange(1, n + 1)
                look = style(algo, labels)
                ax.plot(x, curves.mean(0), label=f"{algo} ({seed_count(len(group))})", **look)
                if len(panel) <= MAX_BANDS:
                    ax.fill_between(x, curves.min(0), curves.max(0), color=look["color"], alpha=0.15, lw=0)
            ax.set_title(f"{scenario}: {title}", fontsize=10)
            ax.set_xlabel("training episode")
            ax.set_ylabel(f"return (rolling mean, {window} ep)")
        _legend(axes[-1][0])
    fig.suptitle("Training curves: mean over seeds, band = min..max over seeds (paper Fig. 8)", fontsize=10)
    _tight(fig)
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
        groups = sorted(groups, key=lambda kv: _order(kv[0][0]))
        labels = [a for (a,), _ in groups]
        for ax, key, title in panels:
            data = [np.concatenate([r.episodes[key].to_numpy() for r in g]) for _, g in groups]
            boxes = ax.boxplot(data, showfliers=False, patch_artist=True)
            for box, label in zip(boxes["boxes"], labels):
                box.set_facecolor((*style(label, labels)["color"], 0.35))
            ax.set_xticks(range(1, len(groups) + 1), labels, fontsize=7, rotation=30, ha="right")
            ax.set_title(f"{scenario}: {title} per evaluation episode", fontsize=10)
    fig.suptitle("Evaluation returns (paper Figs. 9 / 15; whiskers 1.5 IQR, outliers hidden)", fontsize=10)
    _tight(fig)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def distributions(runs, scenario: str, path: Path) -> Path | None:
    """Figs. 10 / 12 / 13: per algo, the distribution of the evaluation episodes' mean speed and mean
    acceleration on ``scenario`` (density over episodes; the band, where drawn, is the range of the per-seed
    densities)."""
    runs = [r for r in runs if r.scenario == scenario]
    if not runs:
        return None
    plt = _plt()
    labels = sorted({r.algo for r in runs})
    panels = series_panels(labels)
    fig, grid = plt.subplots(len(panels), 2, figsize=(14, 3.6 * len(panels)), squeeze=False)
    groups = _by(runs, "algo")
    for panel, axes in zip(panels, grid):
        for ax, key, label in zip(
            axes, ("mean_speed_kmh", "mean_accel"), ("mean speed (km/h)", "mean acceleration (m/s²)")
        ):
            values = np.concatenate([r.episodes[key].to_numpy() for r in runs])
            bins = np.linspace(values.min(), values.max() + 1e-9, 31)
            centres = 0.5 * (bins[1:] + bins[:-1])
            for algo in panel:
                group = groups[(algo,)]
                dens = np.stack([np.histogram(r.episodes[key], bins=bins, density=True)[0] for r in group])
                look = style(algo, labels)
                ax.plot(centres, dens.mean(0), label=f"{algo} ({seed_count(len(group))})", **look)
                if len(panel) <= MAX_BANDS:
                    ax.fill_between(centres, dens.min(0), dens.max(0), color=look["color"], alpha=0.15, lw=0)
            ax.set_xlabel(f"{label} of an episode")
            ax.set_ylabel("density")
        _legend(axes[-1])
    fig.suptitle(f"{scenario}: speed and acceleration per evaluation episode (paper Figs. 10 / 12 / 13)", fontsize=10)
    _tight(fig)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def space_time_title(scenario: str) -> str:
    return f"Fig. 14: {scenario}, space-time diagrams"


def space_time(runs, out_dir: Path, prefer: str = "kddrl") -> dict:
    """Fig. 14 per scenario: the space-time diagrams of two recorded episodes (``traces/*.json`` of a run, made
    with ``video=true``), one with a lane change and one without, of ``prefer``'s runs where they have traces."""
    import json

    from ..eval.render import plot_space_time

    out = {}
    for scenario in sorted({r.scenario for r in runs}):
        holders = sorted(
            [r for r in runs if r.scenario == scenario and r.traces], key=lambda r: (r.algo != prefer, r.algo, r.seed)
        )
        title = space_time_title(scenario)
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
    return {
        "Fig. 16: lcGAN class shares": out_dir / "fig16_lcgan_shares.png",
        "Fig. 17: lcGAN confusion": out_dir / "fig17_lcgan_confusion.png",
    }


@dataclass(frozen=True)
class Drawn:
    """One of a report's figures: its title, its PNG (None where nothing was drawn) and, then, why not."""

    title: str
    path: Path | None
    missing: str = "nothing to draw"


#: the paper's figure number of each scenario's distributions (Figs. 10, 12, 13); others in the order of those
DISTRIBUTION_FIGURES = {"baseline": "10", "congested": "12", "congested_text": "12", "braking": "13"}


def draw_all(
    runs, scenarios: list[str], out_dir: Path, lcgan_metrics: dict | bool | None, space_time_figures: bool = True
) -> list[Drawn]:
    """Every figure of a report into ``out_dir``: Fig. 8, Figs. 9 / 15, the distributions of each scenario,
    Fig. 14 where runs have traces (unless ``space_time_figures`` is false) and Figs. 16 / 17 where the lcGAN metrics
    are given (``False``: not asked for)."""
    figs = [
        Drawn("Fig. 8: training curves", training_curves(runs, out_dir / "fig08_training_curves.png")),
        Drawn("Figs. 9 / 15: evaluation returns", return_boxes(runs, out_dir / "fig09_returns.png")),
    ]
    for s, fig_no in zip(scenarios, ("10", "12", "13")):
        number = DISTRIBUTION_FIGURES.get(s, fig_no)
        path = distributions(runs, s, out_dir / f"fig{number}_distributions_{s}.png")
        figs.append(Drawn(f"Fig. {number}: {s}, speed and acceleration", path))
    no_traces = (
        "no space-time traces in these runs (record them with `python -m kddrl_trl.evaluate run=<dir> video=true`)"
    )
    if space_time_figures:
        figs += [Drawn(title, path, no_traces) for title, path in space_time(runs, out_dir).items()]
    else:
        not_asked = "not asked for (`space_time_figures=false`: another report of these runs draws them)"
        figs += [Drawn(space_time_title(s), None, not_asked) for s in sorted({r.scenario for r in runs})]
    no_metrics = (
        "not asked for (`lcgan_figures=false`: they show the lcGAN's test metrics, not these runs)"
        if lcgan_metrics is False
        else "the shipped lcGAN weights carry no test metrics"
    )
    figs += [Drawn(title, path, no_metrics) for title, path in lcgan(lcgan_metrics or None, out_dir).items()]
    return figs
