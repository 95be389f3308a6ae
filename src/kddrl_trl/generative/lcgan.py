"""lcGAN: the data-driven lane-change prior P_lcGAN (paper §III.C.1, Eq. 16-19).

A conditional GAN whose generator ``G(Z, C)`` (Eq. 16) outputs a probability vector over the lane-change
actions (left, keep, right) and whose discriminator ``D(P, C)`` (Eq. 17) scores whether a probability
vector is a real human action (one-hot) or a generated one, both conditioned on ``C = {S_AV, S_SV, y_pre}``.

Condition C (:meth:`LCGenerator.condition`), assembled from the ``lane_changes`` samples of
:mod:`kddrl_trl.data.extract` (or, at RL time, from the raw observation, see :class:`LCGANPredictor`):

=================  ====  =====================================================================
part               size  content
=================  ====  =====================================================================
S_AV               3     ego speed v, lateral speed (+ = left), lane index as float; normalised
lane availability  2     1.0 where a left (lane < num_lanes - 1) / right (lane > 0) lane exists
S_SV               24+6  ``rel`` of slots a..f (dx, dy, dvx, dvy), normalised per slot and feature
                         over *present* slots, 0 where absent; plus the 6 presence flags
y_pre              6+3   key gaps of leaders a, b, c at steps 10 and 20 (m), normalised per slot and
                         step over present leaders, 0 where absent; plus the 3 presence flags
=================  ====  =====================================================================

``y_pre`` is the *true* future of the leaders during pretraining (teacher forcing, as the extractor saves
it); at RL time it is the trajGAN prediction ``keys.PRED_KEY_GAPS``. The normalisation statistics are
computed once from the train split and kept as buffers of :class:`LCGenerator`, so every checkpoint (and
the predictor built from one) carries them. Standard deviations are floored at 0.1 (m or m/s) so that
near-constant features (lateral relative speeds) cannot blow up.

Impossible directions (left from the leftmost lane, right from lane 0) get probability exactly 0: their
logits are masked before the softmax, during training and inference alike.

Losses (:meth:`LCGANTask.train_batch`):

* D, Eq. 18: binary cross-entropy of D on real one-hot actions (target 1) and on generated probability
  vectors (target 0), computed with ``BCEWithLogitsLoss`` on D's logit (numerically safe form of the
  ``log D`` / ``log(1 - D)`` terms).
* G, Eq. 19: the non-saturating adversarial term ``-log D(G(Z, C), C)`` (again ``BCEWithLogitsLoss``) plus
  ``ω`` times the focal loss ``-α_k (1 - p_k)^γ log p_k`` of the true class k (:func:`focal_loss`), γ = 2.

Class imbalance (≈0.3 % left, ≈0.4 % right) is handled by two knobs: the class weights ``α`` and
class-balanced mini-batches (``balanced_fraction``: that share of every mini-batch is drawn, with
replacement and half per class, from the train split's left and right samples). ``α`` is computed from the
class frequencies of the mini-batch stream the model actually sees (train frequencies mixed with the
balanced share), so the two knobs never double count: ``"inv_sqrt"`` (default) = ``1 / sqrt(freq)``
normalised to mean 1, ``"inv"`` = ``1 / freq`` normalised to mean 1, ``"none"`` = 1, or 3 explicit numbers.
Default: a 25 % balanced share plus ``"inv_sqrt"``. On the SUMO baseline dataset, α alone (no balanced
share, even with ``"inv"``) reached a validation balanced accuracy of 0.68 against 0.79 with the share: with
~3 lane changes per mini-batch of 512 the rare-class gradient is too noisy, whatever its weight.

With ``adversarial=False`` the same generator network is trained as a plain classifier with the focal loss
only (the comparison baseline of the issue); the checkpoint then holds no discriminator.

Model selection: :meth:`LCGANTask.validation_loss` is ``1 - balanced accuracy`` (mean per-class recall of
``argmax P``), so early stopping looks at the rare classes, not at the 99 % of lane keeping.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from tensordict import TensorDict
from tensordict.nn import TensorDictModuleBase
from torch import Tensor, nn

from kddrl_trl import keys as K
from kddrl_trl.physics.mobil import mobil_prior

from .checkpoint import CheckpointError, load_checkpoint, read_checkpoint
from .pretraining import PretrainConfig

__all__ = [
    "KIND",
    "LCDiscriminator",
    "LCGANConfig",
    "LCGANPredictor",
    "LCGANTask",
    "LCGenerator",
    "class_weights",
    "classification_metrics",
    "condition_size",
    "focal_loss",
    "lane_availability",
    "mobil_probabilities",
]

KIND = "lcgan"
NUM_ACTIONS = len(K.LC_ACTIONS)
_STD_FLOOR = 0.1
_MASKED_LOGIT = -1e4  # exp(-1e4) == 0 in float32: impossible directions get probability exactly 0


@dataclass
class LCGANConfig:
    """Every tunable of lcGAN (Hydra: ``conf/gan/lcgan.yaml``)."""

    seed: int = 0                # seeds the weights (at construction), noise and balanced sampling
    noise_dim: int = 8           # size of Z ~ N(0, 1) (Eq. 16)
    hidden: int = 64             # width of the hidden layers of G and D
    layers: int = 2              # hidden layers of G and D
    adversarial: bool = True     # False: the same generator trained as a plain focal-loss classifier
    omega: float = 1.0           # ω, weight of the supervised focal term in L_g (Eq. 19)
    gamma: float = 2.0           # γ, focal-loss focusing parameter (Eq. 19)
    alpha: Any = "inv_sqrt"      # α_k: "inv_sqrt" | "inv" | "none" | [left, keep, right]
    balanced_fraction: float = 0.25  # share of each mini-batch drawn class-balanced from train lane changes
    lr_g: float = 1e-3           # Adam learning rate of G
    lr_d: float = 1e-3           # Adam learning rate of D
    eval_draws: int = 1          # noise draws averaged by validation / evaluation (seeded, deterministic)
    eval_batch: int = 16384      # samples per forward pass in validation / evaluation

    @classmethod
    def from_any(cls, cfg: Any) -> LCGANConfig:
        """From an :class:`LCGANConfig`, a mapping or a Hydra ``DictConfig``.

        Keys of :class:`~kddrl_trl.generative.pretraining.PretrainConfig` (epochs, batch_size, ...) are
        ignored, so one ``conf/gan/lcgan.yaml`` group can hold both; any other unknown key is an error."""
        if isinstance(cfg, cls):
            return dataclasses.replace(cfg)
        if cfg is None:
            return cls()
        items = {str(k): cfg[k] for k in cfg}
        names = {f.name for f in dataclasses.fields(cls)}
        loop = {f.name for f in dataclasses.fields(PretrainConfig)} - names
        unknown = sorted(set(items) - names - loop)
        if unknown:
            raise ValueError(f"unknown lcGAN config key(s) {unknown}; known: {sorted(names)}")
        out = cls(**{k: v for k, v in items.items() if k in names})
        if not isinstance(out.alpha, str):
            out.alpha = [float(a) for a in out.alpha]
        return out


# ------------------------------------------------------------------------------------------- condition
def condition_size() -> int:
    """Length of the assembled condition vector C (see the module docstring)."""
    return 3 + 2 + 6 * 4 + 6 + 3 * 2 + 3


def lane_availability(lane: Tensor, num_lanes: int | Tensor) -> Tensor:
    """``[..., 3]`` bool over (left, keep, right): which directions exist (lane 0 = rightmost)."""
    lane = torch.as_tensor(lane).long()
    num_lanes = torch.as_tensor(num_lanes, device=lane.device)
    left, right = lane < num_lanes - 1, lane > 0
    left, right = torch.broadcast_tensors(left, right)
    return torch.stack([left, torch.ones_like(left), right], dim=-1)


def _mlp(n_in: int, hidden: int, layers: int, n_out: int) -> nn.Sequential:
    mods: list[nn.Module] = []
    for i in range(layers):
        mods += [nn.Linear(n_in if i == 0 else hidden, hidden), nn.LeakyReLU(0.2)]
    mods.append(nn.Linear(hidden if layers else n_in, n_out))
    return nn.Sequential(*mods)


def _masked_moments(x: Tensor, present: Tensor) -> tuple[Tensor, Tensor]:
    """Mean and std (floored) of ``x [N, ..., F]`` over the rows where ``present [N, ...]``, per slot/feature."""
    w = present.unsqueeze(-1).to(torch.float64)
    x = x.to(torch.float64) * w
    n = w.sum(0).clamp(min=1.0)
    mean = x.sum(0) / n
    var = ((x - mean * w) ** 2).sum(0) / n
    return mean.float(), var.sqrt().clamp(min=_STD_FLOOR).float()


class LCGenerator(nn.Module):
    """G(Z, C) -> P over (left, keep, right), paper Eq. 16. Holds the condition's normalisation buffers."""

    def __init__(self, noise_dim: int = 8, hidden: int = 64, layers: int = 2):
        super().__init__()
        self.noise_dim = noise_dim
        self.net = _mlp(condition_size() + noise_dim, hidden, layers, NUM_ACTIONS)
        self.register_buffer("s_av_mean", torch.zeros(3))
        self.register_buffer("s_av_std", torch.ones(3))
        self.register_buffer("rel_mean", torch.zeros(6, 4))
        self.register_buffer("rel_std", torch.ones(6, 4))
        self.register_buffer("gap_mean", torch.zeros(3, 2))
        self.register_buffer("gap_std", torch.ones(3, 2))

    @torch.no_grad()
    def fit_normalisation(self, samples: TensorDict) -> None:
        """Normalisation statistics from the train split's ``lane_changes`` samples."""
        s_av = samples["s_av"].float()
        self.s_av_mean.copy_(s_av.mean(0))
        self.s_av_std.copy_(s_av.std(0).nan_to_num(1.0).clamp(min=_STD_FLOOR))
        for name, x, m in (("rel", samples["rel"], samples["mask"]), ("gap", samples["key_gaps"],
                                                                       samples["key_gaps_mask"])):
            mean, std = _masked_moments(x, m.bool())
            getattr(self, f"{name}_mean").copy_(mean)
            getattr(self, f"{name}_std").copy_(std)

    def condition(self, s_av: Tensor, rel: Tensor, mask: Tensor, key_gaps: Tensor, key_gaps_mask: Tensor,
                  num_lanes: int | Tensor) -> tuple[Tensor, Tensor]:
        """Assemble and normalise C; returns ``(C [..., condition_size()], available [..., 3] bool)``.

        Absent slots (mask False) contribute zeros whatever their raw values (even NaN)."""
        mask, key_gaps_mask = mask.bool(), key_gaps_mask.bool()
        avail = lane_availability(s_av[..., 2].round(), num_lanes)
        z_s = (s_av - self.s_av_mean) / self.s_av_std
        z_rel = torch.where(mask.unsqueeze(-1), (rel - self.rel_mean) / self.rel_std, torch.zeros_like(rel))
        z_gap = torch.where(key_gaps_mask.unsqueeze(-1), (key_gaps - self.gap_mean) / self.gap_std,
                            torch.zeros_like(key_gaps))
        c = torch.cat([z_s, avail[..., [0, 2]].to(z_s.dtype), z_rel.flatten(-2), mask.to(z_s.dtype),
                       z_gap.flatten(-2), key_gaps_mask.to(z_s.dtype)], dim=-1)
        return c, avail

    def logits(self, c: Tensor, z: Tensor, available: Tensor) -> Tensor:
        """Action logits with impossible directions masked to a large negative value."""
        out = self.net(torch.cat([c, z], dim=-1))
        return out.masked_fill(~available, _MASKED_LOGIT)

    def forward(self, c: Tensor, z: Tensor, available: Tensor) -> Tensor:
        """P_lcGAN = G(Z, C) (Eq. 16): ``[..., 3]`` probabilities, exactly 0 on impossible directions."""
        return torch.softmax(self.logits(c, z, available), dim=-1)


class LCDiscriminator(nn.Module):
    """D(P, C) -> logit of "real human action", paper Eq. 17 (``s = sigmoid(logit)``)."""

    def __init__(self, hidden: int = 64, layers: int = 2):
        super().__init__()
        self.net = _mlp(NUM_ACTIONS + condition_size(), hidden, layers, 1)

    def forward(self, p: Tensor, c: Tensor) -> Tensor:
        return self.net(torch.cat([p, c], dim=-1)).squeeze(-1)


# ---------------------------------------------------------------------------------------------- losses
def focal_loss(log_p: Tensor, target: Tensor, alpha: Tensor, gamma: float = 2.0) -> Tensor:
    """Supervised term of Eq. 19: ``mean_i -α_k (1 - p_{i,k})^γ log p_{i,k}`` for the true class ``k``.

    Args:
        log_p: ``[N, 3]`` log-probabilities (masked log-softmax of G).
        target: ``[N]`` int64 true class (``keys.LEFT / KEEP / RIGHT``).
        alpha: ``[3]`` class weights α_k.
    """
    lp = log_p.gather(-1, target.unsqueeze(-1)).squeeze(-1)
    return (-alpha.to(lp)[target] * (1.0 - lp.exp()).pow(gamma) * lp).mean()


def class_weights(freq: Tensor, mode: Any = "inv_sqrt") -> Tensor:
    """α_k from class frequencies ``freq [3]``: "inv_sqrt", "inv", "none" or 3 explicit numbers.

    The inverse modes are normalised to mean 1 over the classes (a class never seen gets the largest
    weight of the others rather than infinity)."""
    if not isinstance(mode, str):
        a = torch.as_tensor([float(x) for x in mode], dtype=torch.float32)
        if a.shape != (NUM_ACTIONS,) or (a < 0).any():
            raise ValueError(f"alpha must be 3 non-negative numbers (left, keep, right), got {mode!r}")
        return a
    freq = torch.as_tensor(freq, dtype=torch.float64)
    if mode == "none":
        return torch.ones(NUM_ACTIONS)
    power = {"inv_sqrt": 0.5, "inv": 1.0}.get(mode)
    if power is None:
        raise ValueError(f"alpha must be 'inv_sqrt', 'inv', 'none' or 3 numbers, got {mode!r}")
    seen = freq > 0
    w = torch.where(seen, freq.clamp(min=1e-12).pow(-power), torch.zeros_like(freq))
    w = torch.where(seen, w, w.max())
    return (w / w.mean()).float()


# --------------------------------------------------------------------------------------------- metrics
def mobil_probabilities(samples: TensorDict) -> Tensor:
    """P_MOBIL (Eq. 22, :func:`~kddrl_trl.physics.mobil.mobil_prior`) of ``lane_changes`` samples.

    Ego at y = 0 with speed ``s_av[:, 0]``; neighbour kinematics from ``rel``: y = dy, v = v_ego + dvy,
    a = 0; lane = ``s_av[:, 2]``; the sample's own ``num_lanes``."""
    s_av, rel, mask = samples["s_av"].float(), samples["rel"].float(), samples["mask"].bool()
    v = s_av[:, 0]
    kin = torch.stack([rel[..., 1], v.unsqueeze(-1) + rel[..., 3], torch.zeros_like(rel[..., 1])], dim=-1)
    return mobil_prior(torch.zeros_like(v), v, kin, mask, s_av[:, 2].round().long(),
                       num_lanes=samples["num_lanes"].long())


def classification_metrics(pred: Tensor, true: Tensor) -> dict:
    """Accuracy, per-class recall, balanced accuracy, row-normalised confusion (rows = true class),
    true / predicted class shares and counts, for class indices ordered (left, keep, right)."""
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
    out["balanced_accuracy"] = float(recall[present].mean()) if present.any() else float("nan")
    out["confusion"] = conf.tolist()
    out["true_shares"] = (n / total).tolist()
    out["pred_shares"] = (counts.sum(0) / total).tolist()
    out["n_per_class"] = [int(x) for x in n]
    return out


# ------------------------------------------------------------------------------------------------ task
class LCGANTask:
    """lcGAN as a :class:`~kddrl_trl.generative.pretraining.GANTask` (kind ``"lcgan"``).

    Args:
        cfg: an :class:`LCGANConfig` or a mapping of its fields.
        train: the train split of the ``lane_changes`` samples (normalisation statistics, class
            frequencies and the pool of the class-balanced share come from it). ``None`` builds an
            untrained shell whose statistics must come from a checkpoint (:meth:`load_state` + modules).
        device: torch device of the networks.
    """

    kind = KIND

    def __init__(self, cfg: Any = None, train: TensorDict | None = None, device: str | torch.device = "cpu"):
        self.cfg = LCGANConfig.from_any(cfg)
        c = self.cfg
        if not 0.0 <= c.balanced_fraction < 1.0:
            raise ValueError(f"balanced_fraction must be in [0, 1), got {c.balanced_fraction}")
        if c.eval_draws < 1:
            raise ValueError(f"eval_draws must be >= 1, got {c.eval_draws}")
        self.device = torch.device(device)
        torch.manual_seed(c.seed)
        self.generator = LCGenerator(c.noise_dim, c.hidden, c.layers).to(self.device)
        self.discriminator = LCDiscriminator(c.hidden, c.layers).to(self.device) if c.adversarial else None
        self.opt_g = torch.optim.Adam(self.generator.parameters(), lr=c.lr_g, betas=(0.5, 0.999))
        self.opt_d = (torch.optim.Adam(self.discriminator.parameters(), lr=c.lr_d, betas=(0.5, 0.999))
                      if self.discriminator is not None else None)
        self.rng = torch.Generator().manual_seed(c.seed + 1)  # noise and balanced sampling (checkpointed)
        self.class_counts = torch.zeros(NUM_ACTIONS, dtype=torch.int64)
        self.alpha = torch.ones(NUM_ACTIONS)
        self._pool: dict[int, TensorDict] = {}
        if train is not None:
            self.generator.fit_normalisation(train)
            labels = train["label"].long()
            self.class_counts = torch.bincount(labels, minlength=NUM_ACTIONS)[:NUM_ACTIONS].cpu()
            for k in (K.LEFT, K.RIGHT):
                idx = (labels == k).nonzero().squeeze(-1)
                if len(idx):
                    self._pool[k] = train[idx].to_tensordict()
            self.alpha = class_weights(self.stream_frequencies(), c.alpha)

    # -- GANTask protocol -------------------------------------------------------------------------------
    def architecture(self) -> dict:
        c = self.cfg
        return {"noise_dim": c.noise_dim, "hidden": c.hidden, "layers": c.layers, "adversarial": c.adversarial,
                "condition_size": condition_size(), "actions": list(K.LC_ACTIONS)}

    def modules(self) -> dict[str, nn.Module]:
        mods: dict[str, nn.Module] = {"generator": self.generator}
        if self.discriminator is not None:
            mods["discriminator"] = self.discriminator
        return mods

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        opts = {"generator": self.opt_g}
        if self.opt_d is not None:
            opts["discriminator"] = self.opt_d
        return opts

    def state(self) -> dict:
        """α, the train class counts and the noise / sampling RNG (normalisation lives in G's buffers)."""
        return {"alpha": self.alpha.clone(), "class_counts": self.class_counts.clone(),
                "rng": self.rng.get_state()}

    def load_state(self, state: Mapping[str, Any]) -> None:
        self.alpha = torch.as_tensor(state["alpha"], dtype=torch.float32).clone()
        self.class_counts = torch.as_tensor(state["class_counts"], dtype=torch.int64).clone()
        if "rng" in state:
            self.rng.set_state(state["rng"])

    def train_batch(self, batch: TensorDict) -> dict[str, float]:
        """One step of D (Eq. 18, adversarial mode only) and one of G (Eq. 19) on ``batch`` plus its
        class-balanced share."""
        batch = self._with_balanced_share(batch)
        c, avail = self._condition(batch)
        label = batch["label"].long().to(self.device)
        z = torch.randn(label.shape[0], self.cfg.noise_dim, generator=self.rng).to(self.device)
        self.generator.train()
        logits = self.generator.logits(c, z, avail)
        log_p = torch.log_softmax(logits, dim=-1)
        out: dict[str, float] = {}
        if self.discriminator is not None:
            p_fake = log_p.exp()
            real = F.one_hot(label, NUM_ACTIONS).to(c.dtype)
            ones, zeros = torch.ones_like(label, dtype=c.dtype), torch.zeros_like(label, dtype=c.dtype)
            bce = nn.BCEWithLogitsLoss()
            self.opt_d.zero_grad(set_to_none=True)
            loss_d = bce(self.discriminator(real, c), ones) + bce(self.discriminator(p_fake.detach(), c), zeros)
            loss_d.backward()
            self.opt_d.step()
            adv = bce(self.discriminator(p_fake, c), ones)  # non-saturating -log D(G(Z, C), C)
            out.update(loss_d=loss_d.item(), loss_adv=adv.item())
        else:
            adv = torch.zeros((), device=self.device)
        focal = focal_loss(log_p, label, self.alpha.to(self.device), self.cfg.gamma)
        loss_g = adv + self.cfg.omega * focal if self.discriminator is not None else focal
        self.opt_g.zero_grad(set_to_none=True)
        loss_g.backward()
        self.opt_g.step()
        out.update(loss_g=loss_g.item(), loss_focal=focal.item())
        return out

    def validation_loss(self, data: TensorDict) -> float:
        """``1 - balanced accuracy`` (mean per-class recall of argmax P) on ``data``."""
        m = classification_metrics(self.predict(data).argmax(-1), data["label"])
        return 1.0 - m["balanced_accuracy"]

    def evaluate(self, test: TensorDict, out_dir: str | Path) -> dict:
        """Metrics of argmax P_lcGAN and of argmax P_MOBIL on ``test``; writes ``lcgan_confusion.png``
        (paper Fig. 17) and ``lcgan_shares.png`` (Fig. 16) into ``out_dir``."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        label = test["label"].long()
        metrics = classification_metrics(self.predict(test).argmax(-1), label)
        metrics["adversarial"] = bool(self.cfg.adversarial)
        metrics["mobil"] = classification_metrics(mobil_probabilities(test).argmax(-1), label)
        _plot_confusion(metrics, out_dir / "lcgan_confusion.png")
        _plot_shares(metrics, out_dir / "lcgan_shares.png")
        return metrics

    # -- helpers ---------------------------------------------------------------------------------------
    def stream_frequencies(self) -> Tensor:
        """Class frequencies of the mini-batch stream: train frequencies mixed with the balanced share."""
        n = self.class_counts.double()
        freq = n / n.sum().clamp(min=1.0)
        f = self.cfg.balanced_fraction if self._pool else 0.0
        share = torch.zeros(NUM_ACTIONS, dtype=torch.float64)
        for k in self._pool:
            share[k] = 1.0 / len(self._pool)
        return (1.0 - f) * freq + f * share

    def _with_balanced_share(self, batch: TensorDict) -> TensorDict:
        f = self.cfg.balanced_fraction
        if f <= 0.0 or not self._pool:
            return batch
        m = round(batch.batch_size[0] * f / (1.0 - f))  # so that the share is f of the final batch
        if m == 0:
            return batch
        classes = sorted(self._pool)
        which = torch.randint(len(classes), (m,), generator=self.rng)
        parts = [batch.select(*self._pool[classes[0]].keys()).to_tensordict()]
        for j, k in enumerate(classes):
            n_k = int((which == j).sum())
            if n_k:
                pool = self._pool[k]
                parts.append(pool[torch.randint(pool.batch_size[0], (n_k,), generator=self.rng)])
        return torch.cat(parts, dim=0)

    def _condition(self, samples: TensorDict) -> tuple[Tensor, Tensor]:
        dev = self.device
        return self.generator.condition(samples["s_av"].float().to(dev), samples["rel"].float().to(dev),
                                        samples["mask"].to(dev), samples["key_gaps"].float().to(dev),
                                        samples["key_gaps_mask"].to(dev), samples["num_lanes"].to(dev))

    @torch.no_grad()
    def predict(self, samples: TensorDict) -> Tensor:
        """``[N, 3]`` P_lcGAN of ``lane_changes`` samples, averaged over ``eval_draws`` noise draws from a
        generator seeded with ``cfg.seed`` (deterministic, independent of the training state)."""
        self.generator.eval()
        gen = torch.Generator().manual_seed(self.cfg.seed)
        n, out = samples.batch_size[0], []
        for start in range(0, n, self.cfg.eval_batch):
            part = samples[start:start + self.cfg.eval_batch]
            c, avail = self._condition(part)
            p = torch.zeros(c.shape[0], NUM_ACTIONS, device=self.device)
            for _ in range(self.cfg.eval_draws):
                z = torch.randn(c.shape[0], self.cfg.noise_dim, generator=gen).to(self.device)
                p += self.generator(c, z, avail)
            out.append((p / self.cfg.eval_draws).cpu())
        return torch.cat(out) if out else torch.zeros(0, NUM_ACTIONS)


# --------------------------------------------------------------------------------------------- figures
def _plot_confusion(metrics: dict, path: Path) -> None:
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
                ax.text(j, i, f"{100 * conf[i, j]:.1f}%", ha="center", va="center",
                        color="white" if conf[i, j] > 0.5 else "black", fontsize=9)
        ax.set_xticks(range(NUM_ACTIONS), K.LC_ACTIONS)
        ax.set_yticks(range(NUM_ACTIONS), [f"{a}\n(n={n})" for a, n in zip(K.LC_ACTIONS, m["n_per_class"])])
        ax.set_xlabel("predicted")
        ax.set_ylabel("true")
        ax.set_title(f"{title}: acc {100 * m['accuracy']:.2f}%, bal. {100 * m['balanced_accuracy']:.1f}%",
                     fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot_shares(metrics: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = ["tab:blue", "tab:gray", "tab:orange"]
    name = "lcGAN" if metrics.get("adversarial", True) else "classifier"
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.8))
    for ax, (title, shares) in zip(axes, [("true", metrics["true_shares"]), (f"predicted ({name})",
                                                                              metrics["pred_shares"])]):
        ax.pie([max(s, 0.0) for s in shares], colors=colors, startangle=90, counterclock=False)
        ax.legend([f"{a}: {100 * s:.2f}%" for a, s in zip(K.LC_ACTIONS, shares)], loc="lower center",
                  bbox_to_anchor=(0.5, -0.25), ncol=1, fontsize=8)
        ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------------------------------- predictor
class LCGANPredictor(TensorDictModuleBase):
    """Frozen lcGAN generator as a TensorDict module: the raw observation -> ``keys.PRIOR_P_LCGAN``.

    Reads ``keys.EGO_STATE`` ``[*B, 3]`` (y, v_y longitudinal, v_x lateral; S_AV uses v = ``[..., 1]``,
    lateral speed = ``[..., 2]``), ``keys.EGO_LANE`` ``[*B, 1]``, ``keys.NEIGHBORS_REL`` ``[*B, 6, 4]``,
    ``keys.NEIGHBORS_MASK`` ``[*B, 6]`` and ``keys.PRED_KEY_GAPS`` ``[*B, 3, 2]`` (trajGAN key gaps; a leader
    is absent where ``NEIGHBORS_MASK[..., :3]`` is False). Writes ``keys.PRIOR_P_LCGAN`` ``[*B, 3]``: a valid
    simplex over (left, keep, right), exactly 0 on directions without a lane. All environments go through
    ONE generator call, without gradients; the noise comes from ``self.rng`` (a ``torch.Generator`` seeded
    with ``seed``), one draw per call, or the mean of ``draws`` draws.

    Args:
        generator: a trained :class:`LCGenerator` (with its normalisation buffers).
        num_lanes: lanes of the road (left possible where lane < num_lanes - 1).
        seed: seed of the noise generator.
        draws: noise draws averaged per call.
    """

    def __init__(self, generator: LCGenerator, num_lanes: int = 3, seed: int = 0, draws: int = 1,
                 compile: bool | str = False):
        super().__init__()
        self.in_keys = [K.EGO_STATE, K.EGO_LANE, K.NEIGHBORS_REL, K.NEIGHBORS_MASK, K.PRED_KEY_GAPS]
        self.out_keys = [K.PRIOR_P_LCGAN]
        if draws < 1:
            raise ValueError(f"draws must be >= 1, got {draws}")
        self.net = generator.eval().requires_grad_(False)
        self.num_lanes = int(num_lanes)
        self.draws = int(draws)
        self.seed = int(seed)
        self.rng = torch.Generator(device=next(generator.parameters()).device).manual_seed(self.seed)
        from ..compiling import maybe_compile

        self._predict = maybe_compile(self.predict, compile)

    @classmethod
    def from_task(cls, task: LCGANTask, **kwargs) -> LCGANPredictor:
        """From a trained task (shares its generator's weights; ``seed`` defaults to the task's)."""
        kwargs.setdefault("seed", task.cfg.seed)
        return cls(task.generator, **kwargs)

    @classmethod
    def from_checkpoint(cls, path: str | Path, dataset_hash: str | None = None, device: str | torch.device = "cpu",
                        **kwargs) -> LCGANPredictor:
        """From a ``best.pt`` / ``last.pt`` of :func:`~kddrl_trl.generative.pretraining.run_pretraining`."""
        payload = read_checkpoint(path)
        arch = payload["architecture"]
        if payload["kind"] != KIND:
            raise CheckpointError(f"{path} holds a {payload['kind']!r} model, not {KIND!r}")
        if arch.get("condition_size") != condition_size() or arch.get("actions") != list(K.LC_ACTIONS):
            raise CheckpointError(f"{path} was trained with another condition layout ({arch})")
        gen = LCGenerator(int(arch["noise_dim"]), int(arch["hidden"]), int(arch["layers"]))
        load_checkpoint(path, kind=KIND, architecture=arch, modules={"generator": gen}, dataset_hash=dataset_hash)
        return cls(gen.to(device), **kwargs)

    def _probabilities_impl(self, state, lane, rel, mask, gaps, z):
        """Eq. 16 on ``[N, ...]`` rows with noise ``z`` ``[draws, N, noise_dim]`` (what ``compile`` fuses)."""
        n = state.shape[0]
        s_av = torch.stack([state[:, 1], state[:, 2], lane.float()], dim=-1)
        c, avail = self.net.condition(s_av, rel, mask, gaps, mask[:, :3], self.num_lanes)
        return self.net(c.expand(z.shape[0], n, c.shape[-1]), z, avail.expand(z.shape[0], n, NUM_ACTIONS)).mean(0)

    def noise(self, rows: int) -> Tensor:
        """The noise of one call on ``rows`` environments: ``[draws, rows, noise_dim]`` from ``self.rng``."""
        return torch.randn(self.draws, int(rows), self.net.noise_dim, generator=self.rng, device=self.rng.device)

    def predict(self, state: Tensor, lane: Tensor, rel: Tensor, mask: Tensor, gaps: Tensor, z: Tensor) -> Tensor:
        """Eq. 16 as a pure tensor function on ``[*B, ...]`` observations (see the class doc for the shapes)
        with ``z`` = :meth:`noise` of ``prod(B)`` rows -> ``P_lcGAN`` ``[*B, 3]``. No data-dependent shapes, so
        ``torch.compile`` fuses it (alone, or inside the fused transform stack)."""
        batch = state.shape[:-1]
        dev = state.device
        n = batch.numel()
        p = self._probabilities_impl(state.reshape(n, 3).float(), lane.reshape(n).to(dev),
                                     rel.reshape(n, 6, 4).float(), mask.reshape(n, 6).bool(),
                                     gaps.reshape(n, 3, 2).float(), z.to(dev))
        return p.reshape(*batch, NUM_ACTIONS)

    @torch.no_grad()
    def forward(self, tensordict: TensorDict) -> TensorDict:
        state = tensordict.get(K.EGO_STATE)
        z = self.noise(state.shape[:-1].numel())
        p = self._predict(state, tensordict.get(K.EGO_LANE), tensordict.get(K.NEIGHBORS_REL),
                          tensordict.get(K.NEIGHBORS_MASK), tensordict.get(K.PRED_KEY_GAPS), z)
        tensordict.set(K.PRIOR_P_LCGAN, p)
        return tensordict
