"""Test metrics of lcGAN (paper §IV.F, Fig. 16-17): classification metrics and the MOBIL baseline ``P_MOBIL``."""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torch import Tensor

from kddrl_trl import keys as K
from kddrl_trl.physics.mobil import mobil_prior

from .model import NUM_ACTIONS


def mobil_probabilities(samples: TensorDict) -> Tensor:
    """P_MOBIL (Eq. 22, :func:`~kddrl_trl.physics.mobil.mobil_prior`) of ``lane_changes`` samples.

    Ego at y = 0 with speed ``s_av[:, 0]``; neighbour kinematics from ``rel``: y = dy, v = v_ego + dvy,
    a = 0; lane = ``s_av[:, 2]``; the sample's own ``num_lanes``."""
    s_av, rel, mask = samples["s_av"].float(), samples["rel"].float(), samples["mask"].bool()
    v = s_av[:, 0]
    kin = torch.stack([rel[..., 1], v.unsqueeze(-1) + rel[..., 3], torch.zeros_like(rel[..., 1])], dim=-1)
    return mobil_prior(
        torch.zeros_like(v), v, kin, mask, s_av[:, 2].round().long(), num_lanes=samples["num_lanes"].long()
    )


def classification_metrics(pred: Tensor, true: Tensor) -> dict:
    """Accuracy, per-class recall and precision, balanced accuracy, row-normalised confusion (rows = true class)
    and its counts, true / predicted class shares and counts, for class indices ordered (left, keep, right)."""
    pred, true = pred.long().flatten(), true.long().flatten()
    counts = torch.zeros(NUM_ACTIONS, NUM_ACTIONS, dtype=torch.float64)
    counts.index_put_((true, pred), torch.ones_like(true, dtype=torch.float64), accumulate=True)
    n = counts.sum(1)
    conf = counts / n.clamp(min=1.0).unsqueeze(1)
    recall = conf.diagonal()
    present = n > 0
    total = max(float(n.sum()), 1.0)
    out = {"accuracy": float(counts.diagonal().sum()) / total}
    for i, name in enumerate(K.LC_ACTIONS):
        out[f"recall_{name}"] = float(recall[i]) if present[i] else float("nan")
        predicted = float(counts[:, i].sum())
        out[f"precision_{name}"] = float(counts[i, i]) / predicted if predicted > 0 else float("nan")
    out["balanced_accuracy"] = float(recall[present].mean()) if present.any() else float("nan")
    out["confusion"] = conf.tolist()
    out["confusion_counts"] = [[int(x) for x in row] for row in counts.tolist()]
    out["true_shares"] = (n / total).tolist()
    out["pred_shares"] = (counts.sum(0) / total).tolist()
    out["n_per_class"] = [int(x) for x in n]
    return out
