"""``JointD3QNLearner``: the unified D3QN comparison system (``algo=d3qn_unified``; the paper's "D3QN (Unit)",
Table I, §II.B): ONE dueling double DQN over the joint discrete action (lane command x acceleration level), one
replay buffer, acting and learning every 0.1 s.

- Action: ``3 x num_levels`` joint commands (:mod:`kddrl_trl.modules.joint_action`; 7 levels by default: -5, -3.33,
  -1.67, 0, 1.67, 3.33, 5 m/s², the bounds of Eq. 31), split into the env's ``keys.LC_ACTION`` / ``keys.CF_ACTION``
  by :func:`~kddrl_trl.modules.joint_action.joint_action_split`; commands the env would not execute
  (``keys.LC_ACTION_MASK``) are masked with all their levels, greedily and at random.
- State: ``keys.JOINT_OBS`` = [s_AV, Δs_i, mask] (Eq. 24 without s_e) + the previous frame's lane command and
  acceleration (:func:`~kddrl_trl.modules.cf_state` reading ``keys.LC_HELD``): the car-following state of Eq. 30
  for an agent that chooses both actions at once.
- Reward: ``r_D3QN + r_TD3`` of the frame (:func:`~kddrl_trl.modules.joint_action.joint_reward`).
- Learning: the same D3QN as KDDRL's lane-change agent (:func:`~kddrl_trl.objectives.make_d3qn`: dueling head
  Eq. 3, double-DQN target Eq. 4, soft target update Eq. 5, ε-greedy), on buffer L (every frame), one update per
  collected frame.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential

from .. import keys as K
from ..modules import build_agent_states, cf_obs_dim, cf_state
from ..modules.joint_action import accel_levels, joint_action_mask, joint_action_split, joint_reward
from ..objectives import PolyakUpdate, make_d3qn, soft_update_tensors, td_priority
from .learner import STATE_KEYS, Learner, adam, transition_keys


def joint_state(extras=()):
    """``keys.JOINT_OBS`` of the unified agents: Eq. 30 without s_e, with the previous frame's lane command (and the
    state ``extras`` of ``algo.state_extras``, not in the paper)."""
    return cf_state(embed=False, lc_action_key=K.LC_HELD, out_key=K.JOINT_OBS, extras=extras)


#: what a unified agent stores per frame: the raw state, the previous frame's command (LC_HELD, root and next)
JOINT_STATE_KEYS = (*STATE_KEYS, K.LC_HELD)


class JointD3QNLearner(Learner):
    """One D3QN over (lane command x acceleration level) (module docstring).

    Args (the ``algo.learner`` node of ``conf/algo/d3qn_unified.yaml``):
        num_levels, low, high: acceleration levels, evenly spaced in [low, high] m/s².
        d3qn: keyword arguments of :func:`~kddrl_trl.objectives.make_d3qn` and ``lr``; ``eps_decisions`` counts
            decisions, i.e. frames here.
        compile: ``torch.compile`` the update function (the learner's one compile site).
        device, cudagraphs, state_extras: as :class:`~kddrl_trl.training.HierarchicalLearner`'s.
    """

    frame_loss_name = "q_loss"  # the loss of buffer L

    def __init__(
        self,
        *,
        num_levels: int = 7,
        low: float = -5.0,
        high: float = 5.0,
        d3qn: Mapping[str, Any] | None = None,
        compile: bool = False,
        device: torch.device | str | None = None,
        cudagraphs: bool = False,
        state_extras=(),
    ):
        super().__init__()
        kw = dict(d3qn or {})
        self.lr = float(kw.pop("lr", 1e-4))
        levels = accel_levels(num_levels, low, high)
        self.state = joint_state(tuple(state_extras))
        self.mask = joint_action_mask(len(levels))
        self.reward = joint_reward()
        self.d3qn = make_d3qn(
            cf_obs_dim(0, extras=tuple(state_extras)),
            num_actions=3 * len(levels),
            obs_key=K.JOINT_OBS,
            mask_key=K.JOINT_ACTION_MASK,
            action_key=K.JOINT_ACTION,
            action_value_key=K.JOINT_ACTION_VALUE,
            chosen_value_key=K.JOINT_CHOSEN_VALUE,
            reward_key=K.JOINT_REWARD,
            **kw,
        )
        self.split = joint_action_split(levels)
        # registered so that state_dict() holds the network, its target and the ε schedule
        self.q_loss, self.q_explore, self.q_actor = self.d3qn.loss, self.d3qn.explore, self.d3qn.actor
        self.register_buffer("counters", torch.zeros(1, dtype=torch.long))
        self.opt = adam(self.q_loss.parameters(), self.lr, self._place(device))
        self._soft = PolyakUpdate(soft_update_tensors(self.d3qn.target_updater))  # Eq. 5
        self._compile(compile, cudagraphs)

    def _policy(self, explore: bool = True) -> TensorDictSequential:
        """State -> valid joint actions -> greedy Q (+ ε-greedy) -> lane command and acceleration."""
        modules = [self.state, self.mask, self.q_actor] + ([self.q_explore] if explore else []) + [self.split]
        return TensorDictSequential(*modules, selected_out_keys=[K.JOINT_ACTION, K.LC_ACTION, K.CF_ACTION])

    def buffer_keys(self) -> list:
        return transition_keys(JOINT_STATE_KEYS, [K.JOINT_ACTION])

    def explore_step(self, decisions: int, frames: int) -> None:
        """Advances ε per frame (the agent decides on every frame)."""
        if frames:
            self.q_explore.step(frames)

    def exploration(self) -> dict[str, float]:
        return {"epsilon": float(self.q_explore.eps)}

    def loss(self, name: str, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """``"joint"``: the double-DQN loss (Eq. 4) of a buffer-L sample on the joint reward, and each transition's
        ``|δ|`` (prioritized replay)."""
        if name != "joint":
            raise ValueError(f"JointD3QNLearner.loss: unknown loss {name!r}; known: joint")
        states = self.reward(build_agent_states(batch, None, self.state, self.mask))
        loss = self.q_loss(states)["loss"]  # DQNLoss writes the squared TD errors into ``states``
        return loss, td_priority(states.get(self.q_loss.tensor_keys.priority), states.numel())

    def update_functions(self) -> dict:
        return {"joint": self._step}

    def _step(self, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """The double-DQN step (Eq. 4), then the soft target update (Eq. 5)."""
        loss, priority = self._descend("joint", batch, self.opt)
        self._soft()
        return loss.reshape(1), priority

    def update_frame(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        loss = self._run("joint", batch)[0]
        self.counters[0] += 1
        return {"loss_joint": loss}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"joint": self.opt}
