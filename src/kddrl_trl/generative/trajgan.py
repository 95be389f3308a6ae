"""trajGAN: intention-aware trajectories of the leading vehicles (paper §III.B, Eq. 13-15).

The IDM prior ``TC`` (Eq. 11-12, ``prior`` of the ``leaders`` samples, ``keys.PRED_PRIOR_TRAJ`` in the
environment) is refined by a conditional GAN: the generator ``G(Z, TC)`` (Eq. 13) outputs the 20 future
positions as a *residual on the prior*, ``TG = TC + G``, and the discriminator ``D(trajectory, TC)`` tells
real futures ``TR`` from generated ones.

Condition (all positions RELATIVE to the leader's current position ``y0 = history[:, -1, 0]``, speeds as
they are, each feature standardised with train-split statistics):

* ``prior - y0`` [horizon] (always);
* with ``use_history`` (default): the leader history positions ``history[:, :-1, 0] - y0`` [H-1] (the last
  one is 0 by construction), its speeds ``history[:, :, 1]`` [H], and the vehicle ahead of the leader:
  ``present * (y_ahead - y0)``, ``present * v_ahead``, ``present`` [3].

Generator output and discriminator input live in the standardised residual space
``r = (future - prior - res_mean) / res_std`` (per horizon step, train statistics), a bijection of
``future - y0`` given ``TC``; the statistics are buffers of the generator, so every checkpoint carries them.

Losses (``BCEWithLogitsLoss`` on logits instead of ``log`` of a sigmoid output, for numerical stability):

* Eq. 14, discriminator: ``BCE(D(TR, TC), 1) + BCE(D(TG, TC), 0)``;
* Eq. 15, generator: the non-saturating adversarial term ``BCE(D(TG, TC), 1) = -log D(TG)`` (Eq. 15 as
  printed has a double minus sign, which we read as a typo) plus ``omega * MAE(TR, TG)`` in metres.

:class:`TrajGANTask` plugs into :func:`kddrl_trl.generative.pretraining.run_pretraining`;
:class:`TrajGANPredictor` is the batched, gradient-free inference module used in the environment.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor, nn

from kddrl_trl import keys as K
from kddrl_trl.data.extract import DRIVER_TYPES
from kddrl_trl.generative.checkpoint import (
    CheckpointError,
    load_checkpoint,
    read_checkpoint,
)

__all__ = [
    "FEATURES_VERSION",
    "KIND",
    "RECOMMENDED_PRETRAIN",
    "TrajDiscriminator",
    "TrajGANConfig",
    "TrajGANPredictor",
    "TrajGANTask",
    "TrajGenerator",
    "condition_features",
]

KIND = "trajgan"
#: identifies the condition layout (part of the checkpoint architecture)
FEATURES_VERSION = "trajgan-cond/1: prior-y0[T], hist_y-y0[H-1], hist_v[H], ahead(p*(y-y0), p*v, p)[3]"
#: ``PretrainConfig`` values for one hour of traffic (340k samples: ~5-8 s per epoch on a 2-core CPU)
RECOMMENDED_PRETRAIN = {"epochs": 20, "batch_size": 256, "max_train_samples": 0, "patience": 5}
STEP_A, STEP_B = 10, 20  # key steps (1-based), paper §III.B


# ------------------------------------------------------------------------------------------- config
@dataclass
class TrajGANConfig:
    """Every tunable of trajGAN (``conf/gan/trajgan.yaml``)."""

    g_hidden: list[int] = field(default_factory=lambda: [128, 128])  # generator MLP widths
    d_hidden: list[int] = field(default_factory=lambda: [128, 128])  # discriminator MLP widths
    noise_dim: int = 8            # size of Z (Eq. 13)
    omega: float = 10.0           # weight of the MAE reconstruction term (Eq. 15), MAE in metres
    lr_g: float = 1e-3
    lr_d: float = 1e-3
    betas: list[float] = field(default_factory=lambda: [0.5, 0.999])  # Adam betas of both optimisers
    use_history: bool = True      # condition on leader history and vehicle ahead, not only on the prior
    num_eval_samples: int = 8     # K futures per input for min-of-K / spread metrics
    dt: float = 0.1               # s per step (10 Hz data), for the constant-velocity baseline
    eval_batch_size: int = 8192   # inputs per generator call in validation / evaluation
    num_figure_cases: int = 4     # test cases drawn in trajgan_samples.png
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


# ----------------------------------------------------------------------------------------- features
def condition_features(history: Tensor, ahead: Tensor, prior: Tensor, use_history: bool = True) -> Tensor:
    """Raw (unstandardised) condition of each leader: ``[N, H, 2]``, ``[N, 3]``, ``[N, T]`` -> ``[N, C]``.

    Everything is relative to ``y0 = history[:, -1, 0]`` (see the module docstring)."""
    y0 = history[:, -1, 0:1]
    parts = [prior - y0]
    if use_history:
        present = (ahead[:, 2:3] > 0).to(prior.dtype)
        parts += [history[:, :-1, 0] - y0, history[:, :, 1],
                  present * (ahead[:, 0:1] - y0), present * ahead[:, 1:2], present]
    return torch.cat(parts, dim=-1)


def _cond_dim(history_len: int, horizon: int, use_history: bool) -> int:
    return horizon + (2 * history_len - 1 + 3 if use_history else 0)


def _mlp(sizes: Sequence[int], act: type[nn.Module]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(act())
    return nn.Sequential(*layers)


# ----------------------------------------------------------------------------------------- networks
class TrajGenerator(nn.Module):
    """``G(Z, TC)`` (Eq. 13): an MLP on ``[condition, noise]`` plus a linear skip from the condition.

    Returns the standardised residual on the prior; the normalisation statistics are buffers (saved in
    the state dict). The output layers start at zero, so an untrained generator returns
    ``TC + mean residual``."""

    def __init__(self, cond_dim: int, horizon: int, noise_dim: int, hidden: Sequence[int]):
        super().__init__()
        self.cond_dim, self.horizon, self.noise_dim = cond_dim, horizon, noise_dim
        self.net = _mlp([cond_dim + noise_dim, *hidden, horizon], nn.SiLU)
        self.skip = nn.Linear(cond_dim, horizon)
        for lin in (self.net[-1], self.skip):
            nn.init.zeros_(lin.weight)
            nn.init.zeros_(lin.bias)
        self.register_buffer("cond_mean", torch.zeros(cond_dim))
        self.register_buffer("cond_std", torch.ones(cond_dim))
        self.register_buffer("res_mean", torch.zeros(horizon))
        self.register_buffer("res_std", torch.ones(horizon))

    def normalize(self, cond_raw: Tensor) -> Tensor:
        return (cond_raw - self.cond_mean) / self.cond_std

    def forward(self, cond: Tensor, z: Tensor) -> Tensor:
        """Standardised condition ``[N, C]``, noise ``[N, noise_dim]`` -> standardised residual ``[N, T]``."""
        return self.net(torch.cat([cond, z], dim=-1)) + self.skip(cond)

    def to_metres(self, r: Tensor) -> Tensor:
        """Standardised residual -> residual on the prior in metres."""
        return r * self.res_std + self.res_mean

    def to_standard(self, residual: Tensor) -> Tensor:
        return (residual - self.res_mean) / self.res_std


class TrajDiscriminator(nn.Module):
    """``D(trajectory, TC)``: an MLP on ``[standardised residual, standardised condition]`` -> one logit."""

    def __init__(self, cond_dim: int, horizon: int, hidden: Sequence[int]):
        super().__init__()
        self.net = _mlp([horizon + cond_dim, *hidden, 1], lambda: nn.LeakyReLU(0.2))

    def forward(self, r: Tensor, cond: Tensor) -> Tensor:
        return self.net(torch.cat([r, cond], dim=-1)).squeeze(-1)


def _architecture(cfg: TrajGANConfig, history_len: int, horizon: int) -> dict:
    return {
        "features": FEATURES_VERSION, "history_len": int(history_len), "horizon": int(horizon),
        "use_history": bool(cfg.use_history), "cond_dim": _cond_dim(history_len, horizon, cfg.use_history),
        "noise_dim": int(cfg.noise_dim), "g_hidden": [int(h) for h in cfg.g_hidden],
        "d_hidden": [int(h) for h in cfg.d_hidden],
    }


def _generator_from_architecture(arch: Mapping[str, Any]) -> TrajGenerator:
    return TrajGenerator(int(arch["cond_dim"]), int(arch["horizon"]), int(arch["noise_dim"]),
                         [int(h) for h in arch["g_hidden"]])


def _refine(gen: TrajGenerator, cond: Tensor, prior: Tensor, z: Tensor) -> Tensor:
    """Eq. 13 on ``m`` rows: ``prior + G(z, cond)`` for each of the ``k`` noise draws ``z`` ``[k, m, noise_dim]``
    (``cond`` normalised ``[m, cond_dim]``, ``prior`` ``[m, T]``) -> ``[k, m, T]`` absolute positions."""
    k, m = z.shape[0], z.shape[1]
    r = gen(cond.unsqueeze(0).expand(k, m, -1).reshape(k * m, -1), z.reshape(k * m, -1))
    return prior.unsqueeze(0) + gen.to_metres(r).reshape(k, m, -1)


@torch.no_grad()
def _sample(gen: TrajGenerator, history: Tensor, ahead: Tensor, prior: Tensor, k: int, use_history: bool,
            generator: torch.Generator | None, chunk: int = 0) -> Tensor:
    """``k`` absolute future positions per input: ``[N, H, 2]``, ``[N, 3]``, ``[N, T]`` -> ``[N, k, T]``.

    The noise of all chunks is drawn up front (CPU generator), so the result does not depend on ``chunk``."""
    n, dev = prior.shape[0], prior.device
    z = torch.randn(k, n, gen.noise_dim, generator=generator).to(dev)
    cond = gen.normalize(condition_features(history, ahead, prior, use_history))
    out = torch.empty(n, k, prior.shape[-1], dtype=prior.dtype, device=dev)
    step = chunk if chunk > 0 else max(n, 1)
    for s in range(0, n, step):
        sl = slice(s, s + step)
        out[sl] = _refine(gen, cond[sl], prior[sl], z[:, sl]).transpose(0, 1)
    return out


# ------------------------------------------------------------------------------------------- task
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
        self._arch = _architecture(self.cfg, self.history_len, self.horizon)
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
            b = train[s:s + chunk]
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
        return {"loss_d": loss_d.item(), "loss_g": loss_g.item(), "loss_adv": adv.item(), "mae": mae.item(),
                "d_real": torch.sigmoid(logit_real).mean().item(), "d_fake": torch.sigmoid(logit_fake).mean().item()}

    def sample(self, cond: TensorDictBase, k: int = 1, generator: torch.Generator | None = None) -> Tensor:
        """``k`` absolute future positions per input of ``cond`` (fields ``history``, ``ahead``, ``prior``):
        ``[N, k, horizon]``. ``generator`` (CPU) draws the noise (global RNG if None)."""
        self.generator.eval()
        history, ahead, prior = self._inputs(cond)
        return _sample(self.generator, history, ahead, prior, int(k), self.cfg.use_history, generator,
                       self.cfg.eval_batch_size)

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
        spread20 = many[..., STEP_B - 1].std(dim=1, unbiased=False) if k > 1 else torch.zeros(len(future))
        metrics["min_of_k"] = {"k": k, "mae": float(best_err.mean()), "mae_step20": float(best_err[:, STEP_B - 1].mean())}
        metrics["spread_step20"] = float(spread20.mean())
        drivers = test["leader_driver"].cpu() if "leader_driver" in test.keys() else None  # noqa: SIM118
        per_driver = {}
        if drivers is not None:
            for code, name in enumerate(DRIVER_TYPES):
                sel = drivers == code
                n = int(sel.sum())
                if n == 0:
                    continue
                per_driver[name] = {
                    "n": n, "mae_step20": float(err["trajgan"][sel, STEP_B - 1].abs().mean()),
                    "idm_prior_mae_step20": float(err["idm_prior"][sel, STEP_B - 1].abs().mean()),
                    "min_of_k_mae_step20": float(best_err[sel, STEP_B - 1].mean()),
                    "spread_step20": float(spread20[sel].mean())}
        metrics["per_driver"] = per_driver
        metrics["n"] = len(future)
        metrics["mae_per_step"] = {name: e.abs().mean(0).tolist() for name, e in err.items()}
        _plot_errors(metrics["mae_per_step"], out_dir / "trajgan_errors.png")
        _plot_samples(history, prior, many, future, cfg.num_figure_cases, cfg.dt, cfg.seed,
                      out_dir / "trajgan_samples.png")
        return metrics


def _error_metrics(err: Tensor) -> dict[str, float]:
    """MAE / RMSE (m) over all steps and at the key steps 10 and 20 of an error tensor ``[N, T]``."""
    out = {"mae": float(err.abs().mean()), "rmse": float(err.pow(2).mean().sqrt())}
    for s in (STEP_A, STEP_B):
        if s <= err.shape[-1]:
            out[f"mae_step{s}"] = float(err[:, s - 1].abs().mean())
            out[f"rmse_step{s}"] = float(err[:, s - 1].pow(2).mean().sqrt())
    return out


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _plot_errors(per_step: Mapping[str, Sequence[float]], path: Path) -> None:
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


def _plot_samples(history: Tensor, prior: Tensor, many: Tensor, future: Tensor, cases: int, dt: float,
                  seed: int, path: Path) -> None:
    n = len(future)
    cases = max(1, min(cases, n))
    idx = torch.randperm(n, generator=torch.Generator().manual_seed(seed))[:cases] if n else torch.zeros(0, dtype=torch.long)
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
            ax.plot(tf, many[i, s] - y0 - v0 * tf, color="tab:blue", alpha=0.35, lw=1,
                    label="trajGAN samples" if s == 0 else None)
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


# -------------------------------------------------------------------------------------- predictor
class TrajGANPredictor(TensorDictModuleBase):
    """Batched trajGAN inference in the environment: ``PRED_PRIOR_TRAJ`` -> ``PRED_TRAJ`` (absolute m).

    Reads ``LEADERS_HISTORY`` [*B, 3, H, 2], ``LEADERS_AHEAD`` [*B, 3, 3], ``NEIGHBORS_MASK`` [*B, 6] (slots 0..2
    = leaders a, b, c) and ``PRED_PRIOR_TRAJ`` [*B, 3, T]; writes ``PRED_TRAJ`` [*B, 3, T]. All present leaders
    of all environments go through ONE generator call. ``reduce="sample"`` returns the first of
    ``num_samples`` draws (only one is drawn), ``"mean"`` the mean of ``num_samples`` draws. An absent
    leader (mask False or non-finite inputs) gets its prior, or zeros where the prior is not finite either;
    the output is never NaN. The noise comes from ``self.generator`` (a CPU ``torch.Generator`` seeded with
    ``seed``; :meth:`reset` re-seeds it), drawn for every leader slot, present or not, so the stream does not
    depend on who is present. No gradients. ``compile=True`` (or ``"auto"``) runs the dense inference through
    ``torch.compile`` (one fused kernel per call on a CPU, after a one-off compile).
    """

    in_keys = [K.LEADERS_HISTORY, K.LEADERS_AHEAD, K.NEIGHBORS_MASK, K.PRED_PRIOR_TRAJ]  # noqa: RUF012
    out_keys = [K.PRED_TRAJ]  # noqa: RUF012

    def __init__(self, generator_net: TrajGenerator, architecture: Mapping[str, Any], num_samples: int = 1,
                 reduce: str = "sample", seed: int = 0, compile: bool | str = False):
        super().__init__()
        if reduce not in ("sample", "mean"):
            raise ValueError(f"reduce must be 'sample' or 'mean', got {reduce!r}")
        if int(num_samples) < 1:
            raise ValueError(f"num_samples must be >= 1, got {num_samples!r}")
        self.net = generator_net.eval()
        self.net.requires_grad_(False)
        self.architecture = dict(architecture)
        self.history_len, self.horizon = int(architecture["history_len"]), int(architecture["horizon"])
        self.use_history = bool(architecture["use_history"])
        self.num_samples, self.reduce, self.seed = int(num_samples), reduce, int(seed)
        self.generator = torch.Generator().manual_seed(self.seed)
        from ..compiling import maybe_compile

        self._predict = maybe_compile(self.predict, compile)

    def reset(self, seed: int | None = None) -> None:
        """Re-seed the noise generator (with ``seed``, or the constructor's)."""
        self.seed = self.seed if seed is None else int(seed)
        self.generator.manual_seed(self.seed)

    def _refine_impl(self, hist: Tensor, ahead: Tensor, prior: Tensor, mask: Tensor, z: Tensor) -> Tensor:
        """Dense inference on every row ``[N, ...]`` with noise ``z`` ``[k, N, noise_dim]``: rows that are
        absent or not finite get their prior (zeros where it is not finite), never NaN. No data-dependent
        shapes, so ``torch.compile`` fuses it whole."""
        prior_ok = torch.isfinite(prior).all(-1)
        present = mask & prior_ok & torch.isfinite(hist).flatten(1).all(-1) & torch.isfinite(ahead).all(-1)
        zero = torch.zeros((), dtype=prior.dtype, device=prior.device)
        base = torch.where(prior_ok.unsqueeze(-1), prior, zero)
        hist = torch.where(present[:, None, None], hist, zero)
        ahead = torch.where(present[:, None], ahead, zero)
        p = torch.where(present[:, None], prior, zero)
        s = _refine(self.net, self.net.normalize(condition_features(hist, ahead, p, self.use_history)), p, z)
        s = s.mean(0) if self.reduce == "mean" else s[0]
        return torch.where(present.unsqueeze(-1), s, base)

    @classmethod
    def from_task(cls, task: TrajGANTask, **kwargs) -> TrajGANPredictor:
        """A predictor sharing a COPY of ``task``'s trained generator (later training does not leak in)."""
        net = _generator_from_architecture(task.architecture())
        net.load_state_dict(task.generator.state_dict())
        return cls(net.to(task.device), task.architecture(), **kwargs)

    @classmethod
    def from_checkpoint(cls, path: str | Path, dataset_hash: str | None = None,
                        architecture: Mapping[str, Any] | None = None, **kwargs) -> TrajGANPredictor:
        """Rebuild the generator from a trajGAN checkpoint (``best.pt``). ``architecture`` / ``dataset_hash``,
        if given, must match the checkpoint (:class:`CheckpointError` otherwise)."""
        payload = read_checkpoint(path)
        if payload["kind"] != KIND:
            raise CheckpointError(f"{path} holds a {payload['kind']!r} model, not {KIND!r}")
        arch = dict(payload["architecture"]) if architecture is None else dict(architecture)
        if arch.get("features") != FEATURES_VERSION:
            raise CheckpointError(f"{path}: condition layout {arch.get('features')!r} is not {FEATURES_VERSION!r}")
        net = _generator_from_architecture(arch)
        load_checkpoint(path, kind=KIND, architecture=arch, modules={"generator": net}, dataset_hash=dataset_hash)
        return cls(net, arch, **kwargs)

    def noise(self, rows: int) -> Tensor:
        """The noise of one call on ``rows`` leader rows (``[k, rows, noise_dim]``, k = ``num_samples`` for
        ``reduce="mean"``, else 1), drawn from ``self.generator`` on the CPU and moved to the net's device."""
        k = self.num_samples if self.reduce == "mean" else 1
        return torch.randn(k, int(rows), self.net.noise_dim, generator=self.generator).to(self.net.res_std.device)

    def predict(self, hist: Tensor, ahead: Tensor, mask: Tensor, prior: Tensor, z: Tensor) -> Tensor:
        """Eq. 13 as a pure tensor function: ``TG = prior + G(Z, C(hist, ahead, prior))`` for leaders a, b, c.

        Args: ``hist`` ``[*B, 3, H, 2]``, ``ahead`` ``[*B, 3, 3]``, ``mask`` ``[*B, 3]`` (leader present),
        ``prior`` ``[*B, 3, T]``, ``z`` = :meth:`noise` of ``prod(B) * 3`` rows. Returns ``[*B, 3, T]`` float32
        absolute positions (m) on the device of ``prior``, never NaN. No data-dependent shapes, so
        ``torch.compile`` fuses it (alone, or inside the fused transform stack)."""
        batch = hist.shape[:-3]
        h, t = hist.shape[-2], prior.shape[-1]
        if t != self.horizon or (self.use_history and h != self.history_len):
            raise ValueError(f"trajGAN was trained with history {self.history_len} / horizon {self.horizon}, "
                             f"got history {h} / horizon {t}")
        dev, out_dev = self.net.res_std.device, prior.device
        out = self._refine_impl(hist.reshape(-1, h, 2).to(dev, torch.float32),
                                ahead.reshape(-1, 3).to(dev, torch.float32),
                                prior.reshape(-1, t).to(dev, torch.float32),
                                mask.reshape(-1).to(dev, torch.bool), z)
        out = torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)
        return out.reshape(*batch, 3, t).to(out_dev)

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        hist = tensordict.get(K.LEADERS_HISTORY)
        z = self.noise(hist.shape[:-3].numel() * 3)
        tensordict.set(K.PRED_TRAJ, self._predict(hist, tensordict.get(K.LEADERS_AHEAD),
                                                  tensordict.get(K.NEIGHBORS_MASK)[..., :3].bool(),
                                                  tensordict.get(K.PRED_PRIOR_TRAJ), z))
        return tensordict
