"""D3QN for the lane-change agent (paper §II.E.1, Eq. 1-5): TorchRL ``QValueActor`` + ``DQNLoss(double_dqn)``
+ ``SoftUpdate`` + ``EGreedyModule``."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from tensordict.nn import TensorDictModule
from torchrl.data import OneHot
from torchrl.modules import EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, SoftUpdate

from .. import keys as K
from ..modules.heads import DuelingQNet


@dataclass
class D3QNParts:
    actor: QValueActor  # greedy argmax Q over the valid actions (keys.LC_ACTION_MASK)
    explore: EGreedyModule  # ε-greedy among the valid actions (Algorithm 1 line 24)
    loss: DQNLoss  # Eq. 4 (double DQN target); owns the target copy θ'
    target_updater: SoftUpdate  # Eq. 5


def make_d3qn(
    obs_dim: int,
    *,
    num_actions: int = 3,
    hidden: Sequence[int] = (256, 256),
    dueling: bool = True,
    double: bool = True,
    gamma: float = 0.99,
    tau: float = 0.005,
    loss_function: str = "l2",
    eps_init: float = 1.0,
    eps_end: float = 0.05,
    eps_decisions: int = 5000,
    semi_mdp: bool = False,
    obs_key=K.LC_OBS,
    mask_key=K.LC_ACTION_MASK,
    action_key=K.LC_ACTION,
    action_value_key=K.LC_ACTION_VALUE,
    chosen_value_key=K.LC_CHOSEN_VALUE,
    reward_key=K.LC_REWARD,
    frames_key=("next", *K.LC_MACRO_FRAMES),
) -> D3QNParts:
    """The lane-change agent on ``obs_key`` (``keys.LC_OBS``, Eq. 24).

    The ``*_key`` arguments wire the same agent to another subtree: the unified D3QN of ``algo=d3qn_unified``
    (:class:`~kddrl_trl.training.JointD3QNLearner`) acts on ``keys.JOINT_ACTION`` over ``num_actions`` = 3 lane
    commands x acceleration levels, with ``keys.JOINT_ACTION_MASK`` and ``keys.JOINT_REWARD``.

    ``dueling=False, double=True`` is the DDQN of Ni et al. Invalid commands (``mask_key`` False: no lane
    there, a manoeuvre in progress and, with ``algo.mobil_safety_mask``, an unsafe gap by MOBIL's Eq. 20-21:
    :class:`~kddrl_trl.transforms.MOBILSafetyMask`) are never chosen, greedily or at random; in the double-DQN
    target the argmax over next actions is masked with the next state's mask, which ``DQNLoss`` hands the Q actor
    through ``step_mdp`` (tested in ``tests/training/test_learner.py``).
    ε decays linearly from ``eps_init`` to ``eps_end`` over ``eps_decisions`` decisions (call
    ``explore.step(n)`` with the number of decisions taken).

    ``semi_mdp``: the bootstrap of Eq. 4 is discounted by ``gamma ** k``, k = the frames the macro-transition spans
    (``frames_key``, written by :class:`~kddrl_trl.collectors.MacroTransitionWriter`), ``gamma`` then being per
    frame (TorchRL's TD(0) estimator reads it as ``steps_to_next_obs``); the interval's reward stays the sum of
    Algorithm 1 line 35. Default False: one ``gamma`` per decision, as Eq. 4 is written (a macro-transition cut
    short by the episode's end is then discounted as a whole decision).
    """
    spec = OneHot(num_actions, dtype=torch.float32)
    net = DuelingQNet(obs_dim, num_actions, hidden, dueling=dueling)
    actor = QValueActor(
        TensorDictModule(net, in_keys=[obs_key], out_keys=[action_value_key]),
        in_keys=[obs_key],
        spec=spec,
        action_space="one_hot",
        action_key=action_key,
        action_value_key=action_value_key,
        chosen_action_value_key=chosen_value_key,
        action_mask_key=mask_key,
    )
    explore = EGreedyModule(
        spec,
        eps_init=eps_init,
        eps_end=eps_end,
        annealing_num_steps=int(eps_decisions),
        action_key=action_key,
        action_mask_key=mask_key,
    )
    loss = DQNLoss(actor, double_dqn=double, delay_value=True, loss_function=loss_function, action_space=spec)
    loss.set_keys(
        action=action_key,
        action_value=action_value_key,
        value=chosen_value_key,
        reward=reward_key,
        done="done",
        terminated="terminated",
    )
    loss.make_value_estimator(gamma=gamma)
    if semi_mdp:
        loss.value_estimator.set_keys(steps_to_next_obs=frames_key)
    return D3QNParts(actor, explore, loss, SoftUpdate(loss, tau=tau))
