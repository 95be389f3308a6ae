"""``PASACLearner``: the parameterised-action SAC comparison system (``algo=pasac_unified``; the paper's
"PASAC (Unit)", Table I, §II.B): one agent choosing the lane command (discrete) and the acceleration (continuous)
every 0.1 s, from one replay buffer, with :class:`~kddrl_trl.objectives.PASACLoss`.

State ``keys.JOINT_OBS`` and reward ``r_D3QN + r_TD3`` as the unified D3QN (:mod:`.joint_d3qn`); the lane command
is masked by ``keys.LC_ACTION_MASK`` (probability 0 for a command the env would not execute).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential

from .. import keys as K
from ..modules import build_agent_states, cf_obs_dim
from ..modules.joint_action import joint_reward
from ..objectives import PolyakUpdate, make_pasac, soft_update_tensors, td_priority
from .joint_d3qn import JOINT_STATE_KEYS, joint_state
from .learner import Learner, adam, transition_keys

#: entries of :meth:`PASACLearner.loss` (the first four are the losses, the rest detached diagnostics)
LOSS_ENTRIES = (
    "loss_qvalue",
    "loss_actor",
    "loss_alpha_lane",
    "loss_alpha_param",
    "alpha_lane",
    "alpha_param",
    "entropy_lane",
    "log_prob_param",
)


class PASACLearner(Learner):
    """PASAC (module docstring).

    Args (the ``algo.learner`` node of ``conf/algo/pasac_unified.yaml``):
        pasac: keyword arguments of :func:`~kddrl_trl.objectives.make_pasac` and the learning rates ``actor_lr``,
            ``critic_lr``, ``alpha_lr`` (both temperatures).
        compile: ``torch.compile`` the update function (the learner's one compile site).
        device, cudagraphs, state_extras: as :class:`~kddrl_trl.training.HierarchicalLearner`'s.
    """

    frame_loss_name = "sac_loss"  # the loss of buffer L

    def __init__(
        self,
        *,
        pasac: Mapping[str, Any] | None = None,
        compile: bool = False,
        device: torch.device | str | None = None,
        cudagraphs: bool = False,
        state_extras=(),
    ):
        super().__init__()
        kw = dict(pasac or {})
        lr_actor, lr_critic, lr_alpha = (float(kw.pop(k, 3e-4)) for k in ("actor_lr", "critic_lr", "alpha_lr"))
        self.state = joint_state(tuple(state_extras))
        self.reward = joint_reward()
        self.pasac = make_pasac(cf_obs_dim(0, extras=tuple(state_extras)), obs_key=K.JOINT_OBS, **kw)
        self.sac_loss, self.sac_actor = self.pasac.loss, self.pasac.actor
        loss = self.sac_loss
        self.register_buffer("counters", torch.zeros(1, dtype=torch.long))
        dev = self._place(device)
        self.opt_critic = adam(loss.qvalue_network_params.flatten_keys().values(), lr_critic, dev)
        self.opt_actor = adam(loss.actor_network_params.flatten_keys().values(), lr_actor, dev)
        self.opt_alpha = adam([loss.log_alpha_lane, loss.log_alpha_param], lr_alpha, dev)
        self._soft = PolyakUpdate(soft_update_tensors(self.pasac.target_updater))
        self._compile(compile, cudagraphs)

    def _policy(self, explore: bool = True) -> TensorDictSequential:
        """State -> categorical + tanh-Gaussian heads -> sampled (``explore``) or modal lane command and
        acceleration."""
        return TensorDictSequential(
            self.state, self.sac_actor, self.pasac.sampler(explore), selected_out_keys=[K.LC_ACTION, K.CF_ACTION]
        )

    def buffer_keys(self) -> list:
        return transition_keys(JOINT_STATE_KEYS, [K.LC_ACTION, K.CF_ACTION])

    def exploration(self) -> dict[str, float]:
        return {"alpha_lane": float(self.sac_loss.alpha_lane), "alpha_param": float(self.sac_loss.alpha_param)}

    def loss(self, name: str, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """``"pasac"``: the :data:`LOSS_ENTRIES` of :class:`~kddrl_trl.objectives.PASACLoss` on a buffer-L sample,
        stacked into one tensor (what ``torch.compile`` handles best), and each transition's ``|δ|`` (prioritized
        replay)."""
        if name != "pasac":
            raise ValueError(f"PASACLearner.loss: unknown loss {name!r}; known: pasac")
        out = self.sac_loss(self.reward(build_agent_states(batch, None, self.state)))
        priority = td_priority(out[self.sac_loss.tensor_keys.priority], batch.numel())
        return torch.stack([out[k] for k in LOSS_ENTRIES]), priority

    def _objective(self, name: str, losses: torch.Tensor) -> torch.Tensor:
        """The sum of the four losses (the critics', both policy heads', both temperatures'), not the diagnostics."""
        return losses[:4].sum()

    def update_functions(self) -> dict:
        return {"pasac": self._step}

    def _step(self, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """One SAC step: critics, both policy heads and both temperatures, then the critics' soft target update."""
        out, priority = self._descend("pasac", batch, self.opt_critic, self.opt_actor, self.opt_alpha)
        self._soft()
        return out[:4], priority

    def update_frame(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        out = self._run("pasac", batch)
        self.counters[0] += 1
        return dict(zip(LOSS_ENTRIES[:4], out.unbind(), strict=True))

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"critic": self.opt_critic, "actor": self.opt_actor, "alpha": self.opt_alpha}
