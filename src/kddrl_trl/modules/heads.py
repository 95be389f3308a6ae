"""Networks of the two agents on top of their states (paper §II.E): the D3QN dueling Q head (Eq. 1-3), the
TD3 actor (Eq. 8, action bounds of Eq. 31) and critic (Eq. 7), and the hybrid actor / critic of the PASAC comparison
system (discrete lane command + continuous acceleration). Plain ``nn.Module`` s; the TorchRL wrappers
(``QValueActor``, ``TensorDictModule``) are made in :mod:`kddrl_trl.objectives`."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn
from torchrl.modules import MLP


def mlp(in_features: int, out_features: int, hidden: Sequence[int]) -> MLP:
    """ReLU MLP ``in_features -> hidden... -> out_features`` (the torso of every head here)."""
    return MLP(in_features=in_features, out_features=out_features, num_cells=list(hidden), activation_class=nn.ReLU)


class DuelingQNet(nn.Module):
    """``Q(s, a) = V(s) + A(s, a) - mean_a' A(s, a')`` — paper Eq. 3 (Wang et al., 2016).

    A shared torso (``hidden[:-1]``, parameters θ) feeds a value stream V(s; β) (Eq. 1) and an advantage
    stream A(s, a; α) (Eq. 2), each with one hidden layer of ``hidden[-1]`` units. ``dueling=False`` gives a
    plain MLP Q network of the same depth (DDQN of Ni et al.).
    """

    def __init__(
        self, in_features: int, num_actions: int = 3, hidden: Sequence[int] = (256, 256), dueling: bool = True
    ):
        super().__init__()
        hidden = list(hidden)
        if not hidden:
            raise ValueError("hidden must list at least one layer width")
        self.dueling = bool(dueling)
        if not self.dueling:
            self.q = mlp(in_features, num_actions, hidden)
            return
        torso = hidden[:-1]
        self.torso = nn.Sequential(mlp(in_features, torso[-1], torso[:-1]), nn.ReLU()) if torso else nn.Identity()
        width = torso[-1] if torso else in_features
        self.value = mlp(width, 1, hidden[-1:])
        self.advantage = mlp(width, num_actions, hidden[-1:])

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        if not self.dueling:
            return self.q(obs)
        h = self.torso(obs)
        adv = self.advantage(h)
        return self.value(h) + adv - adv.mean(-1, keepdim=True)


class BoundedActor(nn.Module):
    """Deterministic policy ``mu(s; φ)`` (Eq. 8) with outputs in ``[low, high]`` (tanh, rescaled; Eq. 31)."""

    def __init__(
        self,
        in_features: int,
        action_dim: int = 1,
        hidden: Sequence[int] = (256, 256),
        low: float = -5.0,
        high: float = 5.0,
    ):
        super().__init__()
        if not high > low:
            raise ValueError(f"action bounds must satisfy low < high, got [{low}, {high}]")
        self.net = mlp(in_features, action_dim, hidden)
        self.register_buffer("loc", torch.tensor((high + low) / 2.0), persistent=False)
        self.register_buffer("scale", torch.tensor((high - low) / 2.0), persistent=False)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.loc + self.scale * torch.tanh(self.net(obs))


class StateActionCritic(nn.Module):
    """``Q_k(s, a; φ_k)`` (Eq. 7): an MLP on ``[s, a / action_scale]``."""

    def __init__(
        self, in_features: int, action_dim: int = 1, hidden: Sequence[int] = (256, 256), action_scale: float = 5.0
    ):
        super().__init__()
        self.net = mlp(in_features + action_dim, 1, hidden)
        self.action_scale = float(action_scale)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs, action / self.action_scale], dim=-1))


#: logit of a lane command that cannot be executed (``keys.LC_ACTION_MASK`` False): probability exactly 0, and
#: ``p log p`` exactly 0 (a finite number, unlike -inf, so no NaN reaches the entropy or the soft values)
MASKED_LOGIT = -1.0e9


class HybridActor(nn.Module):
    """Policy of a parameterised-action agent (PASAC, ``algo=pasac_unified``): from one torso, the logits of a
    categorical over ``num_choices`` lane commands (invalid ones masked to :data:`MASKED_LOGIT`) and, for each
    command k, the mean and standard deviation of the pre-tanh Gaussian of its ``param_dim`` continuous parameters
    (the acceleration x_k), shaped ``[*, num_choices, param_dim]``: the acceleration is conditioned on the lane
    command, as in P-DQN (Xiong et al. 2018) and hybrid SAC (Delalleau et al. 2019). ``log_std`` is clamped to
    [``log_std_min``, ``log_std_max``] (SAC's usual [-5, 2])."""

    def __init__(
        self,
        in_features: int,
        num_choices: int = 3,
        param_dim: int = 1,
        hidden: Sequence[int] = (256, 256),
        log_std_min: float = -5.0,
        log_std_max: float = 2.0,
    ):
        super().__init__()
        self.num_choices, self.param_dim = int(num_choices), int(param_dim)
        self.net = mlp(in_features, self.num_choices * (1 + 2 * self.param_dim), hidden)
        self.log_std_min, self.log_std_max = float(log_std_min), float(log_std_max)

    def forward(self, obs: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        k, p = self.num_choices, self.param_dim
        logits, loc, log_std = self.net(obs).split([k, k * p, k * p], dim=-1)
        logits = logits.masked_fill(~mask.bool(), MASKED_LOGIT)
        shape = (*loc.shape[:-1], k, p)
        return logits, loc.reshape(shape), log_std.clamp(self.log_std_min, self.log_std_max).exp().reshape(shape)


class HybridCritic(nn.Module):
    """Soft ``Q(s, k, x)`` of a parameterised action: an MLP on ``[s, one-hot k, x / param_scale]``."""

    def __init__(
        self,
        in_features: int,
        num_choices: int = 3,
        param_dim: int = 1,
        hidden: Sequence[int] = (256, 256),
        param_scale: float = 5.0,
    ):
        super().__init__()
        self.net = mlp(in_features + num_choices + param_dim, 1, hidden)
        self.param_scale = float(param_scale)

    def forward(self, obs: torch.Tensor, choice: torch.Tensor, param: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([obs, choice.to(obs.dtype), param / self.param_scale], dim=-1))
