"""What a unified agent (``algo=d3qn_unified``, ``algo=pasac_unified``) needs to drive the hierarchical env: the
env takes a one-hot lane command (``keys.LC_ACTION``) and an acceleration (``keys.CF_ACTION``) every frame, the
unified agents choose both at once and learn from one reward.

- :func:`joint_action_mask`: ``keys.LC_ACTION_MASK`` [3] -> ``keys.JOINT_ACTION_MASK`` [3 x levels] (a joint action
  is valid when its lane command is);
- :func:`joint_action_split`: the one-hot joint action of the unified D3QN -> the lane command and the acceleration
  level (joint index = command x levels + level: the commands in (left, keep, right) order, the levels ascending);
- :func:`joint_reward`: ``("next", keys.JOINT_REWARD)`` = ``r_D3QN + r_TD3`` (Eq. 26 + Eq. 32), the sum of the two
  agents' rewards, as one agent that both changes lanes and follows would be rewarded;
- :func:`accel_levels`: the acceleration levels of the unified D3QN.
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torch import nn

from .. import keys as K


def accel_levels(num_levels: int = 7, low: float = -5.0, high: float = 5.0) -> torch.Tensor:
    """``num_levels`` evenly spaced accelerations from ``low`` to ``high`` m/s² (7: -5, -3.33, ..., 0, ..., 5)."""
    if int(num_levels) < 2:
        raise ValueError(f"num_levels must be >= 2 (the two bounds at least), got {num_levels!r}")
    return torch.linspace(float(low), float(high), int(num_levels))


class _RepeatMask(nn.Module):
    def __init__(self, num_levels: int):
        super().__init__()
        self.num_levels = int(num_levels)

    def forward(self, mask: torch.Tensor) -> torch.Tensor:
        return mask.bool().repeat_interleave(self.num_levels, dim=-1)


def joint_action_mask(num_levels: int) -> TensorDictModule:
    """``keys.LC_ACTION_MASK`` [*B, 3] -> ``keys.JOINT_ACTION_MASK`` [*B, 3 x num_levels]."""
    return TensorDictModule(_RepeatMask(num_levels), in_keys=[K.LC_ACTION_MASK], out_keys=[K.JOINT_ACTION_MASK])


class _Split(nn.Module):
    def __init__(self, levels: torch.Tensor, num_commands: int):
        super().__init__()
        self.register_buffer("levels", levels.clone(), persistent=False)
        self.num_commands = int(num_commands)

    def forward(self, joint: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        index = joint.argmax(-1)
        n = self.levels.numel()
        command = nn.functional.one_hot(index // n, self.num_commands).to(torch.float32)
        return command, self.levels[index % n].unsqueeze(-1)


def joint_action_split(levels: torch.Tensor, num_commands: int = 3) -> TensorDictModule:
    """``keys.JOINT_ACTION`` [*B, num_commands x len(levels)] one-hot -> ``keys.LC_ACTION`` [*B, 3] one-hot and
    ``keys.CF_ACTION`` [*B, 1] (the level's acceleration, m/s²)."""
    return TensorDictModule(_Split(levels, num_commands), in_keys=[K.JOINT_ACTION], out_keys=[K.LC_ACTION, K.CF_ACTION])


class _Sum(nn.Module):
    def forward(self, *rewards: torch.Tensor) -> torch.Tensor:
        return torch.stack(rewards).sum(0)


def joint_reward() -> TensorDictModule:
    """``("next", keys.JOINT_REWARD)`` = ``("next", keys.LC_REWARD)`` + ``("next", keys.CF_REWARD)`` of a sample:
    the reward of a unified agent, r_D3QN (Eq. 26-29) + r_TD3 (Eq. 32-33) of the same frame."""
    return TensorDictModule(
        _Sum(), in_keys=[("next", *K.LC_REWARD), ("next", *K.CF_REWARD)], out_keys=[("next", *K.JOINT_REWARD)]
    )
