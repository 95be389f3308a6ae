"""A plain-PyTorch reference of the KDDRL learner's update (Algorithm 1: the TD3 update of Eqs. 8-10 with the
D3QN's greedy next lane command in its target, the D3QN update of Eqs. 5-7, Polyak updates of every target):
the same network modules and arithmetic on plain tensors, no TensorDict, no TorchRL.

Two uses: ``benchmarks/update_speed.py`` times it as the ``plain`` arm, and
``tests/training/test_learner_update.py`` checks that :class:`~kddrl_trl.training.HierarchicalLearner` reaches the same
parameters from the same weights and batches (a test oracle, not part of the pipeline).
"""

from __future__ import annotations

import copy

import torch
import torch.nn.functional as F

from kddrl_trl import keys as K
from kddrl_trl.training import HierarchicalLearner
from kddrl_trl.training.learner import adam


def _loaded(module: torch.nn.Module, params, prefix: str) -> torch.nn.Module:
    """A deep copy of ``module`` holding copies of the weights in ``params`` (a TorchRL loss's ``TensorDictParams``,
    its keys ``prefix`` + the module's ``state_dict`` names)."""
    out = copy.deepcopy(module)
    flat = params.flatten_keys(".")
    out.load_state_dict({name: flat[prefix + name].detach().clone() for name in out.state_dict()})
    return out


class PlainKDDRL:
    """The same update as ``HierarchicalLearner`` in plain PyTorch on tensors (no TensorDict, no TorchRL), on the
    learner's device (all its network copies and optimisers there). Item by item what the learner computes
    (``tests/training/test_learner_update.py`` checks that both reach the same parameters from the same weights and
    batches):

    - TD3 critic step (``TD3Loss.value_loss``, Eq. 6-7): the target action ``clip(mu'(s') + clip(eps, -c, c))``,
      ``eps ~ N(0, policy_noise)`` drawn first (``randn_like`` of the action, as ``TD3Loss`` does), the min of the two
      target critics, ``y = r_cf + gamma (1 - terminated) min Q'``; the loss is the sum over both critics of the
      batch-mean squared error; it trains the critics and the shared embedding (their own optimisers).
    - The next state's lane-change action in the TD3 target (``build_agent_states``): where the next
      frame is a decision frame (``("next", "lc", "decide")``), the D3QN's greedy choice (online Q, next state
      with the target s_e, next action mask, the one-hot of the max as TorchRL's ``QValueModule`` writes it); the
      held root action elsewhere.
    - Every ``policy_delay`` -th critic step: the actor step (``TD3Loss.actor_loss``, Eq. 8: ``-Q_1(s, mu(s))``,
      the first critic after its step, critic parameters and s_e detached), then the Polyak updates of the actor,
      both critics (TD3 tau) and the target embedding (embedding tau).
    - D3QN step (``DQNLoss(double_dqn=True)``, Eq. 4): argmax of the online Q on the next state (target s_e, masked
      by the next action mask), valued by the target Q; ``y = r_lc + gamma (1 - terminated) Q'(s', a*)``, the
      mean squared error on ``Q(s, a)`` of the stored one-hot action; trains Q and the embedding; then the Polyak
      updates of the target Q (D3QN tau) and the target embedding (every step).

    The networks are deep copies of the learner's, the learning rates and taus the learner's, the optimisers the
    learner's kind (:func:`kddrl_trl.training.learner.adam`, fused), but ``torch.optim.Adam`` itself (``lean=False``)."""

    def __init__(self, learner: HierarchicalLearner):
        L = learner
        device = L.device
        if L.embedding is None or len(L.embedding) != 2:
            raise ValueError("PlainKDDRL mirrors the KDDRL learner (priors and key gaps on): got another embedding")
        self.fusion = copy.deepcopy(L.embedding[0].module)  # PriorFusion net (Eq. 23)
        self.embed = copy.deepcopy(L.embedding[1].module)  # SharedEmbedding net (Eq. 24)
        self.t_fusion = copy.deepcopy(L.target_embedding[0].module)
        self.t_embed = copy.deepcopy(L.target_embedding[1].module)
        self.lc_state = copy.deepcopy(L.lc_state.module)
        self.cf_state = copy.deepcopy(L.cf_state.module)
        td3, d3 = L.cf_loss, L.lc_loss
        # the losses hold the networks' weights (TD3Loss re-samples its two critics, and keeps the targets): copy
        # the modules, then load every weight from the loss that owns it
        self.q = _loaded(L.d3qn.actor.module[0].module, d3.value_network_params, "module.0.module.")  # DuelingQNet
        self.q_t = _loaded(self.q, d3.target_value_network_params, "module.0.module.")
        self.actor = _loaded(L.td3.actor.module, td3.actor_network_params, "module.")
        self.actor_t = _loaded(self.actor, td3.target_actor_network_params, "module.")
        self.critics = [_loaded(L.td3.critic.module, td3.qvalue_network_params[k], "module.") for k in range(2)]
        self.critics_t = [
            _loaded(c, td3.target_qvalue_network_params[k], "module.") for k, c in enumerate(self.critics)
        ]
        for m in (
            self.fusion,
            self.embed,
            self.t_fusion,
            self.t_embed,
            self.lc_state,
            self.cf_state,
            self.q,
            self.q_t,
            self.actor,
            self.actor_t,
            *self.critics,
            *self.critics_t,
        ):
            m.to(device)
        for m in (self.t_fusion, self.t_embed, self.q_t, self.actor_t, *self.critics_t):
            m.requires_grad_(False)
        self.gamma_cf = float(td3.value_estimator.gamma)
        self.gamma_lc = float(d3.value_estimator.gamma)
        self.policy_noise, self.noise_clip = float(td3.policy_noise), float(td3.noise_clip)
        self.low, self.high = float(td3.min_action), float(td3.max_action)
        self.delay = L.td3.policy_delay
        self.tau_cf = 1.0 - float(L.td3.target_updater.eps)
        self.tau_lc = 1.0 - float(L.d3qn.target_updater.eps)
        self.tau_embed = L.embed_tau
        emb_params = [*self.fusion.parameters(), *self.embed.parameters()]
        # the learner's optimisers, as torch.optim.Adam itself
        self.opt_embed = adam(emb_params, L.opt_embed.param_groups[0]["lr"], device, lean=False)
        self.opt_q = adam(self.q.parameters(), L.lr_lc, device, lean=False)
        self.opt_actor = adam(self.actor.parameters(), L.lr_actor, device, lean=False)
        self.opt_critic = adam([p for c in self.critics for p in c.parameters()], L.lr_critic, device, lean=False)
        emb_pairs = [(self.t_fusion, self.fusion), (self.t_embed, self.embed)]
        self.soft_cf = [
            (self.tau_cf, [(self.actor_t, self.actor), *zip(self.critics_t, self.critics)]),
            (self.tau_embed, emb_pairs),
        ]
        self.soft_lc = [(self.tau_lc, [(self.q_t, self.q)]), (self.tau_embed, emb_pairs)]
        self.updates = 0

    def _s_e(self, x: dict, target: bool) -> torch.Tensor:
        fusion, embed = (self.t_fusion, self.t_embed) if target else (self.fusion, self.embed)
        p_lc = fusion(x["p_lcgan"], x["p_mobil"])
        return embed(p_lc, x["gaps"])

    @staticmethod
    @torch.no_grad()
    def _soft(groups) -> None:
        for tau, modules in groups:
            pairs = [(t, s) for a, b in modules for t, s in zip(a.parameters(), b.parameters())]
            torch._foreach_lerp_([t for t, _ in pairs], [s for _, s in pairs], tau)

    def _greedy_lc(self, obs: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """The D3QN's greedy one-hot action (online Q, invalid commands masked), as ``QValueModule`` writes it."""
        q = torch.where(mask, self.q(obs), torch.finfo(obs.dtype).min)
        return (q == q.max(-1, keepdim=True)[0]).to(obs.dtype)

    def update_cf(self, x: dict, nx: dict) -> None:
        noise = (torch.randn_like(x["cf_action"]) * self.policy_noise).clamp(-self.noise_clip, self.noise_clip)
        s_e = self._s_e(x, False)
        obs = self.cf_state(x["ego"], x["rel"], x["mask"], s_e, x["lc_action"], x["accel"])
        with torch.no_grad():
            s_e2 = self._s_e(nx, True)
            chosen = self._greedy_lc(self.lc_state(nx["ego"], nx["rel"], nx["mask"], s_e2), nx["action_mask"])
            lc2 = torch.where(nx["decide"], chosen, x["lc_action"])
            obs2 = self.cf_state(nx["ego"], nx["rel"], nx["mask"], s_e2, lc2, nx["accel"])
            a2 = (self.actor_t(obs2) + noise).clamp(self.low, self.high)
            q2 = torch.minimum(self.critics_t[0](obs2, a2), self.critics_t[1](obs2, a2))
            y = nx["r_cf"] + self.gamma_cf * (~nx["terminated"]).float() * q2
        loss = sum(F.mse_loss(c(obs, x["cf_action"]), y) for c in self.critics)
        self.opt_critic.zero_grad(set_to_none=True)
        self.opt_embed.zero_grad(set_to_none=True)
        loss.backward()
        self.opt_critic.step()
        self.opt_embed.step()
        self.updates += 1
        if self.updates % self.delay == 0:
            obs_d = self.cf_state(
                x["ego"], x["rel"], x["mask"], self._s_e(x, False).detach(), x["lc_action"], x["accel"]
            )
            for p in self.critics[0].parameters():
                p.requires_grad_(False)
            actor_loss = -self.critics[0](obs_d, self.actor(obs_d)).mean()
            self.opt_actor.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.opt_actor.step()
            for p in self.critics[0].parameters():
                p.requires_grad_(True)
            self._soft(self.soft_cf)

    def update_lc(self, x: dict, nx: dict) -> None:
        obs = self.lc_state(x["ego"], x["rel"], x["mask"], self._s_e(x, False))
        with torch.no_grad():
            obs2 = self.lc_state(nx["ego"], nx["rel"], nx["mask"], self._s_e(nx, True))
            best = self._greedy_lc(obs2, nx["action_mask"])
            q2 = (self.q_t(obs2) * best).sum(-1, keepdim=True)
            y = nx["r_lc"] + self.gamma_lc * (~nx["terminated"]).float() * q2
        q = (self.q(obs) * x["lc_action"]).sum(-1, keepdim=True)
        loss = F.mse_loss(q, y)
        self.opt_q.zero_grad(set_to_none=True)
        self.opt_embed.zero_grad(set_to_none=True)
        loss.backward()
        self.opt_q.step()
        self.opt_embed.step()
        self._soft(self.soft_lc)


def tensors(td, device: torch.device | str = "cpu") -> tuple[dict, dict]:
    """A replay-buffer sample as the plain reference's two dicts of tensors (root, ``"next"``), on ``device``."""
    td = td.to(device)

    def one(t):
        return {
            "ego": t[K.EGO_STATE],
            "rel": t[K.NEIGHBORS_REL],
            "mask": t[K.NEIGHBORS_MASK],
            "accel": t[K.EGO_ACCEL],
            "p_lcgan": t[K.PRIOR_P_LCGAN],
            "p_mobil": t[K.PRIOR_P_MOBIL],
            "gaps": t[K.PRED_KEY_GAPS],
            "action_mask": t[K.LC_ACTION_MASK],
        }

    x, nx = one(td), one(td["next"])
    x.update(lc_action=td[K.LC_ACTION].float(), cf_action=td[K.CF_ACTION])
    nx.update(
        r_cf=td["next", K.CF_REWARD],
        r_lc=td["next", K.LC_REWARD],
        terminated=td["next", "terminated"],
        decide=td["next", K.LC_DECIDE].reshape(*td.batch_size, 1).bool()
        if ("next", *K.LC_DECIDE) in td.keys(True)
        else None,
    )
    return x, nx
