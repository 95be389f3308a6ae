"""DDPG for the car-following agent of Peng et al. (2022) (``algo=peng``): TorchRL ``DDPGLoss`` + ``SoftUpdate``
+ ``AdditiveGaussianModule`` exploration, actions bounded to [-5, 5] m/s² (paper Eq. 31). The same actor and critic
heads and the same state (Eq. 30) as TD3 (:mod:`kddrl_trl.objectives.td3`): only the loss differs (one critic, no
target smoothing, the actor updated with every critic step)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from tensordict.nn import TensorDictModule
from torchrl.modules import AdditiveGaussianModule
from torchrl.objectives import DDPGLoss, SoftUpdate

from .. import keys as K
from .td3 import CarFollowingLosses, car_following_heads


@dataclass
class DDPGParts(CarFollowingLosses):
    actor: TensorDictModule  # mu(s; φ)
    explore: AdditiveGaussianModule  # a = mu(s) + N(0, σ), clipped to the bounds
    critic: TensorDictModule  # Q(s, a; φ)
    loss: DDPGLoss  # owns the target actor and critic (delay_actor, delay_value)
    target_updater: SoftUpdate  # Polyak averaging of both targets
    policy_delay: int = 1  # DDPG updates the actor with every critic step

    _value, _actor, _critic = "loss_value", "loss_actor", "value_network_params"  # DDPGLoss's names


def make_ddpg(
    obs_dim: int,
    *,
    low: float = -5.0,
    high: float = 5.0,
    hidden: Sequence[int] = (256, 256),
    gamma: float = 0.99,
    tau: float = 0.005,
    exploration_sigma: float = 0.5,
    exploration_clip: float | None = 2.5,
    loss_function: str = "l2",
    obs_key=K.CF_OBS,
) -> DDPGParts:
    """The car-following agent of Peng et al. on ``obs_key`` (``keys.CF_OBS``, Eq. 30).

    Exploration is Gaussian, ``exploration_sigma`` m/s² (Lillicrap et al. used an Ornstein-Uhlenbeck process;
    TorchRL's ``OrnsteinUhlenbeckProcessModule`` keeps its noise state in the rollout's TensorDict, which the
    two-clock policy does not carry from frame to frame, and Fujimoto et al. found uncorrelated Gaussian noise
    as good); its noise is clipped to ``±exploration_clip`` as KDDRL's (Algorithm 1 line 32; ``None``: unclipped),
    so both hierarchical systems explore alike. Target actor and critic (``delay_actor=True``, ``delay_value=True``), as
    in DDPG.
    """
    actor, critic, explore = car_following_heads(
        obs_dim, low, high, hidden, exploration_sigma, obs_key, exploration_clip=exploration_clip
    )
    loss = DDPGLoss(actor, critic, loss_function=loss_function, delay_actor=True, delay_value=True)
    loss.set_keys(state_action_value=K.CF_STATE_ACTION_VALUE, reward=K.CF_REWARD, done="done", terminated="terminated")
    loss.make_value_estimator(gamma=gamma)
    return DDPGParts(actor, explore, critic, loss, SoftUpdate(loss, tau=tau))
