"""lcGAN training (paper Eq. 18-19) as a :class:`~kddrl_trl.generative.pretraining.GANTask`: its config, one
step of D and G with the class-balanced share, seeded prediction for validation, and the test evaluation
(see the package docstring for the losses, the class imbalance and the model selection)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from tensordict import TensorDict
from torch import Tensor, nn

from kddrl_trl import keys as K

from ..pretraining import PretrainConfig
from .figures import plot_confusion, plot_shares
from .losses import class_weights, focal_loss
from .metrics import classification_metrics, mobil_probabilities
from .model import KIND, NUM_ACTIONS, LCDiscriminator, LCGenerator, condition_size


@dataclass
class LCGANConfig:
    """Every tunable of lcGAN (Hydra: ``conf/gan/lcgan.yaml``)."""

    seed: int = 0  # seeds the weights (at construction), noise and balanced sampling
    noise_dim: int = 8  # size of Z ~ N(0, 1) (Eq. 16)
    hidden: int = 64  # width of the hidden layers of G and D
    layers: int = 2  # hidden layers of G and D
    adversarial: bool = True  # False: the same generator trained as a plain focal-loss classifier
    omega: float = 1.0  # ω, weight of the supervised focal term in L_g (Eq. 19)
    gamma: float = 2.0  # γ, focal-loss focusing parameter (Eq. 19)
    alpha: Any = "inv_sqrt"  # α_k: "inv_sqrt" | "inv" | "none" | [left, keep, right]
    balanced_fraction: float = 0.25  # share of each mini-batch drawn class-balanced from train lane changes
    lr_g: float = 1e-3  # Adam learning rate of G
    lr_d: float = 1e-3  # Adam learning rate of D
    eval_draws: int = 1  # noise draws averaged by validation / evaluation (seeded, deterministic)
    eval_batch: int = 16384  # samples per forward pass in validation / evaluation

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
        self.opt_d = (
            torch.optim.Adam(self.discriminator.parameters(), lr=c.lr_d, betas=(0.5, 0.999))
            if self.discriminator is not None
            else None
        )
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
        return {
            "noise_dim": c.noise_dim,
            "hidden": c.hidden,
            "layers": c.layers,
            "adversarial": c.adversarial,
            "condition_size": condition_size(),
            "actions": list(K.LC_ACTIONS),
        }

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
        return {"alpha": self.alpha.clone(), "class_counts": self.class_counts.clone(), "rng": self.rng.get_state()}

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
        plot_confusion(metrics, out_dir / "lcgan_confusion.png")
        plot_shares(metrics, out_dir / "lcgan_shares.png")
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
        return self.generator.condition(
            samples["s_av"].float().to(dev),
            samples["rel"].float().to(dev),
            samples["lane_offset"].float().to(dev),
            samples["mask"].to(dev),
            samples["key_gaps"].float().to(dev),
            samples["key_gaps_mask"].to(dev),
            samples["num_lanes"].to(dev),
        )

    @torch.no_grad()
    def predict(self, samples: TensorDict) -> Tensor:
        """``[N, 3]`` P_lcGAN of ``lane_changes`` samples, averaged over ``eval_draws`` noise draws from a
        generator seeded with ``cfg.seed`` (deterministic, independent of the training state)."""
        self.generator.eval()
        gen = torch.Generator().manual_seed(self.cfg.seed)
        n, out = samples.batch_size[0], []
        for start in range(0, n, self.cfg.eval_batch):
            part = samples[start : start + self.cfg.eval_batch]
            c, avail = self._condition(part)
            p = torch.zeros(c.shape[0], NUM_ACTIONS, device=self.device)
            for _ in range(self.cfg.eval_draws):
                z = torch.randn(c.shape[0], self.cfg.noise_dim, generator=gen).to(self.device)
                p += self.generator(c, z, avail)
            out.append((p / self.cfg.eval_draws).cpu())
        return torch.cat(out) if out else torch.zeros(0, NUM_ACTIONS)
