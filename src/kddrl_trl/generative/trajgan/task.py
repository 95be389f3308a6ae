"""trajGAN training (paper Eq. 14-15) as a :class:`~kddrl_trl.generative.pretraining.GANTask`: its config, one
adversarial step, seeded sampling for validation, and the test metrics and figures.

Losses (``BCEWithLogitsLoss`` on logits instead of ``log`` of a sigmoid output, for numerical stability):

* Eq. 14, discriminator: ``BCE(D(TR, TC), 1) + BCE(D(TG, TC), 0)``;
* Eq. 15, generator: the non-saturating adversarial term ``BCE(D(TG, TC), 1) = -log D(TG)`` (Eq. 15 as
  printed has a double minus sign, which we read as a typo) plus ``omega * MAE(TR, TG)`` in metres.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import Tensor, nn

from kddrl_trl.generative.gan_inputs import DRIVER_TYPES, KEY_STEPS

from .figures import plot_errors, plot_samples
from .model import FEATURES_VERSION, KIND, TrajDiscriminator, TrajGenerator, cond_dim, condition_features, refine

#: ``PretrainConfig`` values for one hour of traffic (340k samples)
RECOMMENDED_PRETRAIN = {"epochs": 20, "batch_size": 256, "max_train_samples": 0, "patience": 5}
_LAST = KEY_STEPS[-1]  # the last key step (20): the per-driver and spread metrics are taken there
#: a test sample is a braking event when its leader decelerates at BRAKING_DECEL m/s² or harder at some step of
#: the true 2 s future (acceleration from second differences of the positions, the last history point included)
BRAKING_DECEL = 3.0


@dataclass
class TrajGANConfig:
    """Every tunable of trajGAN (``conf/gan/trajgan.yaml``)."""

    g_hidden: list[int] = field(default_factory=lambda: [128, 128])  # generator MLP widths
    d_hidden: list[int] = field(default_factory=lambda: [128, 128])  # discriminator MLP widths
    noise_dim: int = 8  # size of Z (Eq. 13)
    omega: float = 10.0  # weight of the MAE reconstruction term (Eq. 15), MAE in metres
    lr_g: float = 1e-3
    lr_d: float = 1e-3
    betas: list[float] = field(default_factory=lambda: [0.5, 0.999])  # Adam betas of both optimisers
    use_history: bool = True  # condition on leader history and vehicle ahead, not only on the prior
    num_eval_samples: int = 8  # K futures per input for min-of-K / spread metrics
    dt: float = 0.1  # s per step (10 Hz data), for the constant-velocity baseline
    eval_batch_size: int = 8192  # inputs per generator call in validation / evaluation
    num_figure_cases: int = 4  # test cases drawn in trajgan_samples.png
    seed: int = 0

    @classmethod
    def from_any(cls, cfg: Any = None) -> TrajGANConfig:
        """From a ``TrajGANConfig``, a mapping (dict, OmegaConf) or None; unknown keys are an error."""
        if cfg is None:
            return cls()
        if isinstance(cfg, cls):
            return dataclasses.replace(cfg)
        items = {str(k): cfg[k] for k in cfg} if hasattr(cfg, "keys") else dict(cfg)
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(items) - names)
        if unknown:
            raise ValueError(f"unknown trajGAN config key(s) {unknown}; known: {sorted(names)}")
        out = cls(**items)
        out.g_hidden = [int(h) for h in out.g_hidden]
        out.d_hidden = [int(h) for h in out.d_hidden]
        out.betas = [float(b) for b in out.betas]
        for name in ("noise_dim", "num_eval_samples", "eval_batch_size", "num_figure_cases"):
            if int(getattr(out, name)) < 1:
                raise ValueError(f"trajGAN config {name} must be >= 1, got {getattr(out, name)!r}")
        if not out.g_hidden or not out.d_hidden or min(out.g_hidden + out.d_hidden) < 1:
            raise ValueError("trajGAN config g_hidden / d_hidden must be non-empty lists of positive widths")
        if not (out.omega >= 0 and out.lr_g > 0 and out.lr_d > 0 and out.dt > 0):
            raise ValueError("trajGAN config needs omega >= 0, lr_g > 0, lr_d > 0, dt > 0")
        return out


def architecture(cfg: TrajGANConfig, history_len: int, horizon: int) -> dict:
    """What a trajGAN checkpoint must match to be loaded (condition layout and network sizes)."""
    return {
        "features": FEATURES_VERSION,
        "history_len": int(history_len),
        "horizon": int(horizon),
        "use_history": bool(cfg.use_history),
        "cond_dim": cond_dim(history_len, horizon, cfg.use_history),
        "noise_dim": int(cfg.noise_dim),
        "g_hidden": [int(h) for h in cfg.g_hidden],
        "d_hidden": [int(h) for h in cfg.d_hidden],
    }


@torch.no_grad()
def _sample(
    gen: TrajGenerator,
    history: Tensor,
    ahead: Tensor,
    prior: Tensor,
    k: int,
    use_history: bool,
    generator: torch.Generator | None,
    chunk: int = 0,
) -> Tensor:
    """``k`` absolute future positions per input: ``[N, H, 2]``, ``[N, 3]``, ``[N, T]`` -> ``[N, k, T]``.

    The noise of all chunks is drawn up front (CPU generator), so the result does not depend on ``chunk``."""
    n, dev = prior.shape[0], prior.device
    z = torch.randn(k, n, gen.noise_dim, generator=generator).to(dev)
    cond = gen.normalize(condition_features(history, ahead, prior, use_history))
    out = torch.empty(n, k, prior.shape[-1], dtype=prior.dtype, device=dev)
    step = chunk if chunk > 0 else max(n, 1)
    for s in range(0, n, step):
        sl = slice(s, s + step)
        out[sl] = refine(gen, cond[sl], prior[sl], z[:, sl]).transpose(0, 1)
    return out


class TrajGANTask:
    """trajGAN as a :class:`~kddrl_trl.generative.pretraining.GANTask` (kind ``"trajgan"``).

    Args:
        cfg: :class:`TrajGANConfig` fields (mapping or dataclass).
        train: the ``leaders`` train split (fields ``history``, ``ahead``, ``prior``, ``future``); the
            normalisation statistics are computed from it.
        device: torch device of the networks.
    """

    kind = KIND

    def __init__(self, cfg: Any, train: TensorDictBase, device: str | torch.device = "cpu"):
        self.cfg = TrajGANConfig.from_any(cfg)
        self.device = torch.device(device)
        torch.manual_seed(self.cfg.seed)
        history, prior = train["history"], train["prior"]
        self.history_len, self.horizon = int(history.shape[1]), int(prior.shape[-1])
        if len(train) < 2:
            raise ValueError("trajGAN needs at least 2 training samples")
        self._arch = architecture(self.cfg, self.history_len, self.horizon)
        c, t = self._arch["cond_dim"], self.horizon
        self.generator = TrajGenerator(c, t, self.cfg.noise_dim, self.cfg.g_hidden)
        self.discriminator = TrajDiscriminator(c, t, self.cfg.d_hidden)
        self._set_statistics(train)
        self.generator.to(self.device)
        self.discriminator.to(self.device)
        betas = tuple(self.cfg.betas)
        self.opt_g = torch.optim.Adam(self.generator.parameters(), lr=self.cfg.lr_g, betas=betas)
        self.opt_d = torch.optim.Adam(self.discriminator.parameters(), lr=self.cfg.lr_d, betas=betas)
        self.bce = nn.BCEWithLogitsLoss()
        self.noise = torch.Generator().manual_seed(self.cfg.seed + 1)  # training noise Z
        self.steps = 0

    # ------------------------------------------------------------------ statistics / inputs
    @torch.no_grad()
    def _set_statistics(self, train: TensorDictBase, chunk: int = 1 << 16) -> None:
        """Per-feature mean / std of the condition and per-step mean / std of ``future - prior``."""
        n = len(train)
        s1 = s2 = r1 = r2 = 0.0
        for s in range(0, n, chunk):
            b = train[s : s + chunk]
            x = condition_features(b["history"], b["ahead"], b["prior"], self.cfg.use_history).double()
            r = (b["future"] - b["prior"]).double()
            s1, s2 = s1 + x.sum(0), s2 + (x * x).sum(0)
            r1, r2 = r1 + r.sum(0), r2 + (r * r).sum(0)

        def stats(a, b):
            mean = a / n
            std = (b / n - mean * mean).clamp(min=0).sqrt()
            return mean.float(), std.float().clamp(min=1e-3)

        g = self.generator
        g.cond_mean.copy_(stats(s1, s2)[0]), g.cond_std.copy_(stats(s1, s2)[1])
        g.res_mean.copy_(stats(r1, r2)[0]), g.res_std.copy_(stats(r1, r2)[1])

    def _inputs(self, data: TensorDictBase) -> tuple[Tensor, Tensor, Tensor]:
        dev = self.device
        return data["history"].to(dev), data["ahead"].to(dev), data["prior"].to(dev)

    # ------------------------------------------------------------------ GANTask protocol
    def architecture(self) -> dict:
        return dict(self._arch)

    def modules(self) -> dict[str, nn.Module]:
        return {"generator": self.generator, "discriminator": self.discriminator}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"generator": self.opt_g, "discriminator": self.opt_d}

    def state(self) -> dict:
        # the normalisation statistics are buffers of the generator, saved with its state dict
        return {"noise_rng": self.noise.get_state(), "steps": self.steps}

    def load_state(self, state: Mapping[str, Any]) -> None:
        if "noise_rng" in state:
            self.noise.set_state(state["noise_rng"])
        self.steps = int(state.get("steps", 0))

    def train_batch(self, batch: TensorDictBase) -> dict[str, float]:
        """One discriminator step (Eq. 14), then one generator step (Eq. 15) on the same noise draw."""
        g, d = self.generator, self.discriminator
        g.train(), d.train()
        history, ahead, prior = self._inputs(batch)
        future = batch["future"].to(self.device)
        cond = g.normalize(condition_features(history, ahead, prior, self.cfg.use_history))
        residual = future - prior
        r_real = g.to_standard(residual)
        z = torch.randn(len(prior), self.cfg.noise_dim, generator=self.noise).to(self.device)
        r_fake = g(cond, z)

        logit_real, logit_fake = d(r_real, cond), d(r_fake.detach(), cond)
        loss_d = self.bce(logit_real, torch.ones_like(logit_real)) + self.bce(logit_fake, torch.zeros_like(logit_fake))
        self.opt_d.zero_grad(set_to_none=True)
        loss_d.backward()
        self.opt_d.step()

        logit = d(r_fake, cond)
        adv = self.bce(logit, torch.ones_like(logit))
        mae = (g.to_metres(r_fake) - residual).abs().mean()  # |TG - TR| in metres
        loss_g = adv + self.cfg.omega * mae
        self.opt_g.zero_grad(set_to_none=True)
        loss_g.backward()
        self.opt_g.step()
        self.steps += 1
        return {
            "loss_d": loss_d.item(),
            "loss_g": loss_g.item(),
            "loss_adv": adv.item(),
            "mae": mae.item(),
            "d_real": torch.sigmoid(logit_real).mean().item(),
            "d_fake": torch.sigmoid(logit_fake).mean().item(),
        }

    def sample(self, cond: TensorDictBase, k: int = 1, generator: torch.Generator | None = None) -> Tensor:
        """``k`` absolute future positions per input of ``cond`` (fields ``history``, ``ahead``, ``prior``):
        ``[N, k, horizon]``. ``generator`` (CPU) draws the noise (global RNG if None)."""
        self.generator.eval()
        history, ahead, prior = self._inputs(cond)
        return _sample(
            self.generator, history, ahead, prior, int(k), self.cfg.use_history, generator, self.cfg.eval_batch_size
        )

    def validation_loss(self, data: TensorDictBase) -> float:
        """MAE (m) over all horizon steps of ONE sample per input (noise seeded with ``seed``, so the value
        is reproducible)."""
        pred = self.sample(data, 1, torch.Generator().manual_seed(self.cfg.seed))[:, 0]
        return float((pred - data["future"].to(pred.device)).abs().mean())

    @torch.no_grad()
    def evaluate(self, test: TensorDictBase, out_dir: str | Path) -> dict:
        """Metrics on ``test`` (one seeded sample per input, plus K samples for min-of-K and spread) and the
        figures ``trajgan_errors.png`` / ``trajgan_samples.png`` in ``out_dir``."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        cfg, k = self.cfg, self.cfg.num_eval_samples
        history, _, prior = (x.cpu() for x in self._inputs(test))
        future = test["future"].cpu()
        y0, v0 = history[:, -1, 0:1], history[:, -1, 1:2]
        steps = torch.arange(1, self.horizon + 1, dtype=prior.dtype)
        const_vel = y0 + v0 * steps * cfg.dt
        one = self.sample(test, 1, torch.Generator().manual_seed(cfg.seed))[:, 0].cpu()
        many = self.sample(test, k, torch.Generator().manual_seed(cfg.seed + 2)).cpu()  # [N, K, T]

        err = {"trajgan": one - future, "idm_prior": prior - future, "const_velocity": const_vel - future}
        metrics: dict[str, Any] = _error_metrics(err["trajgan"])
        metrics["idm_prior"] = _error_metrics(err["idm_prior"])
        metrics["const_velocity"] = _error_metrics(err["const_velocity"])
        best = (many - future.unsqueeze(1)).abs().mean(-1).argmin(1)  # sample closest over the horizon
        best_err = (many[torch.arange(len(best)), best] - future).abs()
        last = _LAST - 1
        spread = many[..., last].std(dim=1, unbiased=False) if k > 1 else torch.zeros(len(future))
        metrics["min_of_k"] = {
            "k": k,
            "mae": float(best_err.mean()),
            f"mae_step{_LAST}": float(best_err[:, last].mean()),
        }
        metrics[f"spread_step{_LAST}"] = float(spread.mean())
        drivers = test["leader_driver"].cpu() if "leader_driver" in test.keys() else None  # noqa: SIM118
        per_driver = {}
        if drivers is not None:
            for code, name in enumerate(DRIVER_TYPES):
                sel = drivers == code
                n = int(sel.sum())
                if n == 0:
                    continue
                per_driver[name] = {
                    "n": n,
                    f"mae_step{_LAST}": float(err["trajgan"][sel, last].abs().mean()),
                    f"idm_prior_mae_step{_LAST}": float(err["idm_prior"][sel, last].abs().mean()),
                    f"min_of_k_mae_step{_LAST}": float(best_err[sel, last].mean()),
                    f"spread_step{_LAST}": float(spread[sel].mean()),
                }
        metrics["per_driver"] = per_driver
        braking = braking_events(history[:, -1, 0], future, cfg.dt)
        metrics["braking_decel_threshold"] = BRAKING_DECEL
        for name, sel in (("braking", braking), ("normal", ~braking)):
            metrics[name] = {"n": int(sel.sum()), **{k: _error_metrics(e[sel]) for k, e in err.items()}}
        metrics["n"] = len(future)
        metrics["mae_per_step"] = {name: e.abs().mean(0).tolist() for name, e in err.items()}
        plot_errors(metrics["mae_per_step"], out_dir / "trajgan_errors.png")
        plot_samples(
            history, prior, many, future, cfg.num_figure_cases, cfg.dt, cfg.seed, out_dir / "trajgan_samples.png"
        )
        return metrics


def braking_events(y0: Tensor, future: Tensor, dt: float) -> Tensor:
    """``[N]`` bool: the leader's deceleration reaches :data:`BRAKING_DECEL` (m/s²) within ``future [N, T]``
    (positions after ``y0 [N]``; speeds and accelerations by differences, as SUMO's Euler update makes them)."""
    y = torch.cat([y0.unsqueeze(-1), future], dim=-1)
    accel = torch.diff(y, n=2, dim=-1) / dt**2
    return (accel <= -BRAKING_DECEL).any(-1)


def _error_metrics(err: Tensor) -> dict[str, float]:
    """MAE / RMSE (m) over all steps and at the key steps (10 and 20) of an error tensor ``[N, T]``."""
    out = {"mae": float(err.abs().mean()), "rmse": float(err.pow(2).mean().sqrt())}
    for s in KEY_STEPS:
        if s <= err.shape[-1]:
            out[f"mae_step{s}"] = float(err[:, s - 1].abs().mean())
            out[f"rmse_step{s}"] = float(err[:, s - 1].pow(2).mean().sqrt())
    return out
