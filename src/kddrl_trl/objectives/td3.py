"""TD3 for the car-following agent (paper §II.E.2, Eq. 6-10): TorchRL ``TD3Loss`` + ``SoftUpdate`` +
``AdditiveGaussianModule`` exploration, actions bounded to [-5, 5] m/s² (Eq. 31)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from tensordict.nn import TensorDictModule
from torchrl.data import Bounded, Composite
from torchrl.modules import AdditiveGaussianModule
from torchrl.objectives import SoftUpdate, TD3Loss

from .. import keys as K
from ..modules.heads import BoundedActor, StateActionCritic
from .priority import td_priority


class ClippedGaussianModule(AdditiveGaussianModule):
    """Acting noise of Algorithm 1 line 32: ``a = mu(s) + clip(eps, -c, c)``, ``eps ~ N(0, sigma)``, then projected
    onto the action bounds (Eq. 31). TorchRL's ``AdditiveGaussianModule`` adds unclipped noise; this one clips the
    noise itself (not only the action) to ``±noise_clip`` (m/s²). Like its parent, it acts only under
    ``ExplorationType.RANDOM``."""

    def __init__(self, *args, noise_clip: float, **kwargs):
        super().__init__(*args, **kwargs)
        if not noise_clip > 0:
            raise ValueError(f"noise_clip must be > 0, got {noise_clip!r}")
        self.noise_clip = float(noise_clip)

    def _add_noise(self, action: torch.Tensor) -> torch.Tensor:
        eps = torch.randn(action.shape, device=action.device, dtype=action.dtype)
        noise = (self.mean.to(action) + self.std.to(action) * eps) * self.sigma.to(action)
        return self.spec[self.action_key].project(action + noise.clamp(-self.noise_clip, self.noise_clip))


class CarFollowingLosses:
    """The two losses and the critic parameters of a car-following agent's TorchRL loss ``self.loss``, under one
    name whatever the loss calls them (:class:`TD3Parts`; ``DDPGParts`` of :mod:`.ddpg`)."""

    _value, _actor, _critic = "value_loss", "actor_loss", "qvalue_network_params"  # TD3Loss's names

    def critic_params(self):
        """The critics' parameters (the critic optimiser's)."""
        return getattr(self.loss, self._critic)

    def value_loss(self, td) -> tuple[torch.Tensor, torch.Tensor]:
        """Critic loss (TD3: twin critics, Eq. 6-7) of a batch holding the agent's states (weighted by its
        ``keys.PRIORITY_WEIGHT`` when it has them), and each transition's ``|δ|`` (the largest over the critics:
        prioritized replay's priority, :mod:`.priority`)."""
        loss, metadata = getattr(self.loss, self._value)(td)
        return loss, td_priority(metadata["td_error"], td.numel())

    def actor_loss(self, td):
        """Deterministic policy-gradient loss ``-Q(s, mu(s))`` (Eq. 8), critic parameters detached."""
        return getattr(self.loss, self._actor)(td)[0]


@dataclass
class TD3Parts(CarFollowingLosses):
    actor: TensorDictModule  # mu(s; φ), Eq. 8
    explore: AdditiveGaussianModule  # a = mu(s) + clip(N(0, σ), -c, c), then the bounds (Algorithm 1 line 32)
    critic: TensorDictModule  # Q_k(s, a; φ_k), Eq. 7 (TD3Loss makes the twin copies and targets)
    loss: TD3Loss  # Eq. 6-8
    target_updater: SoftUpdate  # Eq. 9-10
    policy_delay: int  # actor and targets updated every ``policy_delay`` critic updates


def car_following_heads(
    obs_dim: int,
    low: float,
    high: float,
    hidden: Sequence[int],
    exploration_sigma: float,
    obs_key=K.CF_OBS,
    exploration_clip: float | None = None,
) -> tuple[TensorDictModule, TensorDictModule, AdditiveGaussianModule]:
    """Actor ``mu(s)`` -> ``keys.CF_ACTION`` in [low, high], critic ``Q(s, a)`` -> ``keys.CF_STATE_ACTION_VALUE`` and
    Gaussian exploration of σ = ``exploration_sigma`` m/s², its noise clipped to ``±exploration_clip`` when given
    (:class:`ClippedGaussianModule`, Algorithm 1 line 32): the heads TD3 and DDPG (:mod:`.ddpg`) share."""
    spec = Composite(cf=Composite(action=Bounded(low, high, shape=(1,), dtype=torch.float32)))
    actor = TensorDictModule(BoundedActor(obs_dim, 1, hidden, low, high), in_keys=[obs_key], out_keys=[K.CF_ACTION])
    critic = TensorDictModule(
        StateActionCritic(obs_dim, 1, hidden, action_scale=max(abs(low), abs(high))),
        in_keys=[obs_key, K.CF_ACTION],
        out_keys=[K.CF_STATE_ACTION_VALUE],
    )
    noise = dict(sigma_init=exploration_sigma, sigma_end=exploration_sigma, action_key=K.CF_ACTION)
    explore = (
        AdditiveGaussianModule(spec, **noise)
        if exploration_clip is None
        else ClippedGaussianModule(spec, noise_clip=exploration_clip, **noise)
    )
    return actor, critic, explore


def make_td3(
    obs_dim: int,
    *,
    low: float = -5.0,
    high: float = 5.0,
    hidden: Sequence[int] = (256, 256),
    gamma: float = 0.99,
    tau: float = 0.005,
    policy_noise: float = 1.0,
    noise_clip: float = 2.5,
    policy_delay: int = 2,
    exploration_sigma: float = 0.5,
    exploration_clip: float | None = 2.5,
    loss_function: str = "l2",
    obs_key=K.CF_OBS,
) -> TD3Parts:
    """The car-following agent on ``obs_key`` (``keys.CF_OBS``, Eq. 30).

    Noise scales are in m/s² (Fujimoto et al.'s defaults 0.1 / 0.2 / 0.5 of the action bound 5 m/s²):
    ``exploration_sigma`` for acting, its noise clipped to ``±exploration_clip`` (Algorithm 1 line 32, the c of
    ``clip(ε, -c, c)``; ``None``: unclipped, TorchRL's ``AdditiveGaussianModule``), ``policy_noise`` clipped to
    ``±noise_clip`` for target smoothing (Eq. 6).
    """
    actor, critic, explore = car_following_heads(
        obs_dim, low, high, hidden, exploration_sigma, obs_key, exploration_clip=exploration_clip
    )
    loss = TD3Loss(
        actor,
        critic,
        bounds=(low, high),
        num_qvalue_nets=2,
        policy_noise=policy_noise,
        noise_clip=noise_clip,
        loss_function=loss_function,
    )
    loss.set_keys(
        action=K.CF_ACTION,
        state_action_value=K.CF_STATE_ACTION_VALUE,
        reward=K.CF_REWARD,
        done="done",
        terminated="terminated",
    )
    loss.make_value_estimator(gamma=gamma)
    return TD3Parts(actor, explore, critic, loss, SoftUpdate(loss, tau=tau), int(policy_delay))
