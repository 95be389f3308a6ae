"""Figures of the lcGAN test evaluation: confusion matrices (paper Fig. 17) and class shares (Fig. 16)."""

from __future__ import annotations

from pathlib import Path

import torch

from kddrl_trl import keys as K

from .model import NUM_ACTIONS


def plot_confusion(metrics: dict, path: Path) -> None:
    """Row-normalised confusion matrices of lcGAN and MOBIL side by side (``lcgan_confusion.png``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("lcGAN" if metrics.get("adversarial", True) else "classifier", metrics), ("MOBIL", metrics["mobil"])]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.8))
    for ax, (title, m) in zip(axes, panels):
        conf = torch.tensor(m["confusion"]).numpy()
        ax.imshow(conf, cmap="Blues", vmin=0.0, vmax=1.0)
        for i in range(NUM_ACTIONS):
            for j in range(NUM_ACTIONS):
                ax.text(
                    j,
                    i,
                    f"{100 * conf[i, j]:.1f}%",
                    ha="center",
                    va="center",
                    color="white" if conf[i, j] > 0.5 else "black",
                    fontsize=9,
                )
        ax.set_xticks(range(NUM_ACTIONS), K.LC_ACTIONS)
        ax.set_yticks(range(NUM_ACTIONS), [f"{a}\n(n={n})" for a, n in zip(K.LC_ACTIONS, m["n_per_class"])])
        ax.set_xlabel("predicted")
        ax.set_ylabel("true")
        ax.set_title(f"{title}: acc {100 * m['accuracy']:.2f}%, bal. {100 * m['balanced_accuracy']:.1f}%", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_shares(metrics: dict, path: Path) -> None:
    """True and predicted class shares as pies (``lcgan_shares.png``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = ["tab:blue", "tab:gray", "tab:orange"]
    name = "lcGAN" if metrics.get("adversarial", True) else "classifier"
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.8))
    for ax, (title, shares) in zip(
        axes, [("true", metrics["true_shares"]), (f"predicted ({name})", metrics["pred_shares"])]
    ):
        ax.pie([max(s, 0.0) for s in shares], colors=colors, startangle=90, counterclock=False)
        ax.legend(
            [f"{a}: {100 * s:.2f}%" for a, s in zip(K.LC_ACTIONS, shares)],
            loc="lower center",
            bbox_to_anchor=(0.5, -0.25),
            ncol=1,
            fontsize=8,
        )
        ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
