"""``HierarchicalLearner``: the two agents of KDDRL and their updates (paper §III.G.3, Algorithm 1 lines 4-9,
27-29, 38-43), around one shared embedding (Eq. 23-24, trained as :mod:`kddrl_trl.modules.sharing` decides).

One class serves KDDRL and the configuration-only comparison systems of docs/design.md (``d3qn_td3``,
``d3qn_td3_lg``, ``kddrl_same_clock``, ``ni``, ``peng``): which embedding inputs exist, dueling or not, the
car-following agent (TD3, or DDPG for Peng et al.), MOBIL's criteria in the lane-change state (Peng et al.) and the
decision period are options. Everything that touches a tensor is a TorchRL loss / module or a TensorDict module.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential

from .. import keys as K
from ..collectors import MultiRatePolicy
from ..modules import (
    build_agent_states,
    cf_obs_dim,
    cf_state,
    detach_embedding,
    embedding_parameters,
    lc_obs_dim,
    lc_state,
    make_shared_embedding,
    make_target_embedding,
)
from ..modules.seed_batch import SeedRows, stack_seeds
from ..objectives import (
    PolyakUpdate,
    make_d3qn,
    make_ddpg,
    make_td3,
    module_tensors,
    soft_update_tensors,
    td_priority,
)
from .learner import STATE_KEYS, Learner, adam, transition_keys
from .seed_adam import seed_adam

log = logging.getLogger(__name__)

#: car-following agents of a hierarchical learner: their loss factories (TD3: KDDRL; DDPG: Peng et al.)
CF_LOSSES = {"td3": make_td3, "ddpg": make_ddpg}
#: besides the base's state keys, the decision flag: the TD3 target's next lane-change action is the D3QN's choice
#: where the next frame is a decision frame (``modules/sharing.py::build_agent_states``)
HIERARCHICAL_STATE_KEYS = (*STATE_KEYS, K.LC_DECIDE)


class HierarchicalLearner(Learner):
    """D3QN (lane change, buffer H) + TD3 or DDPG (car following, buffer L) + the shared embedding.

    Args (all from the ``algo`` config node, see ``conf/algo/kddrl.yaml``):
        priors, key_gaps: inputs of the shared embedding (both False: no embedding, plain D3QN+TD3 states).
        embed_dim, embed_hidden: size of s_e and width of the embedding MLPs.
        d3qn, td3: keyword arguments of :func:`~kddrl_trl.objectives.make_d3qn` /
            :func:`~kddrl_trl.objectives.make_td3` (``lr`` is taken out for the optimisers).
        cf_agent: ``"td3"`` (KDDRL) or ``"ddpg"`` (Peng et al., :func:`~kddrl_trl.objectives.make_ddpg` with the
            keyword arguments ``ddpg``).
        mobil_criteria: the lane-change state carries MOBIL's utilities and safety flags (Peng et al.;
            the env must carry :class:`~kddrl_trl.transforms.MOBILCriteria`).
        state_extras: features appended to both agents' states (``algo.state_extras``: ``thw``, ``ttc``;
            not in the paper; :func:`~kddrl_trl.modules.state.headway_features`).
        embed_lr: learning rate of the embedding's own optimiser.
        compile: ``torch.compile`` the losses (the learner's one compile site,
            :meth:`~kddrl_trl.training.learner.Learner._compile`): removes most of TensorDict's per-call overhead,
            after a one-off compile (a bool: a config's ``auto`` is resolved once, by ``make_job``). Measured gain: see
            ``benchmarks/results/update_speed.json`` (``python -m benchmarks.update_speed``).
        device: where the networks, the sampled batches and the updates live (None: the CPU).
        cudagraphs: wrap the update functions in ``CudaGraphModule`` (CUDA only; refused on the CPU).
        seeds: N independent learners stacked on a leading seed dimension (:mod:`kddrl_trl.modules.seed_batch`):
            every sample is ``[N, B]``, every loss ``[N]``; None: one learner.

    Updates (one call = one gradient step), three update functions (:meth:`update_functions`):

    - :meth:`update_cf`: TD3 critic (``value_loss``, trains the embedding too: ``"cf_value"``), and every
      ``policy_delay`` critic updates the same step followed by the actor (``actor_loss`` on detached s_e) and the
      soft target updates of the critics, the actor and the embedding (Eq. 9-10: ``"cf_full"``); DDPG: the same
      with one critic and ``policy_delay`` 1.
    - :meth:`update_lc`: D3QN double-DQN loss (Eq. 4, trains the embedding too), soft target updates of the
      Q network (Eq. 5) and the embedding (``"lc"``).
    """

    learns_from_decisions = True  # buffer H: the D3QN's macro-transitions
    frame_loss_name = "cf_loss"  # buffer L: TD3 (or Peng's DDPG)

    def __init__(
        self,
        *,
        priors: bool = True,
        key_gaps: bool = True,
        embed_dim: int = 16,
        embed_hidden: int = 64,
        d3qn: Mapping[str, Any] | None = None,
        td3: Mapping[str, Any] | None = None,
        embed_lr: float = 3e-4,
        tau: float | None = None,
        compile: bool = False,
        cf_agent: str = "td3",
        ddpg: Mapping[str, Any] | None = None,
        mobil_criteria: bool = False,
        device: torch.device | str | None = None,
        cudagraphs: bool = False,
        state_extras=(),
        seeds: int | None = None,
    ):
        super().__init__()
        if cf_agent not in CF_LOSSES:
            raise ValueError(f"cf_agent={cf_agent!r}: known car-following agents are {', '.join(CF_LOSSES)}")
        d3qn_kw, td3_kw = dict(d3qn or {}), dict((td3 if cf_agent == "td3" else ddpg) or {})
        self.lr_lc = float(d3qn_kw.pop("lr", 1e-4))
        self.lr_actor = float(td3_kw.pop("actor_lr", 3e-4))
        self.lr_critic = float(td3_kw.pop("critic_lr", 3e-4))
        self.embedding = make_shared_embedding(embed_dim, embed_hidden, priors=priors, key_gaps=key_gaps)
        self.target_embedding = make_target_embedding(self.embedding)
        self.embed_tau = float(tau if tau is not None else td3_kw.get("tau", 0.005))
        d = embed_dim if self.embedding is not None else 0
        self.mobil_criteria = bool(mobil_criteria)
        extras = tuple(state_extras)
        self.lc_state = lc_state(embed=self.embedding is not None, mobil=self.mobil_criteria, extras=extras)
        self.cf_state = cf_state(embed=self.embedding is not None, extras=extras)
        self.d3qn = make_d3qn(lc_obs_dim(d, mobil=self.mobil_criteria, extras=extras), **d3qn_kw)
        #: the car-following agent's parts (``TD3Parts`` or ``DDPGParts``; the attribute keeps its KDDRL name)
        self.td3 = CF_LOSSES[cf_agent](cf_obs_dim(d, extras=extras), **td3_kw)
        # registered so that state_dict() holds every network, target and exploration schedule
        self.lc_loss, self.cf_loss = self.d3qn.loss, self.td3.loss
        self.lc_explore, self.cf_explore = self.d3qn.explore, self.td3.explore
        self.lc_actor, self.cf_actor = self.d3qn.actor, self.td3.actor
        # the D3QN's greedy choice at a next state that is a decision frame (Eq. 30's a_D3QN^{t+1} in the TD3
        # target, modules/sharing.py::build_agent_states); kept out of the module tree (its parameters are the
        # lc actor's, already registered)
        self.__dict__["next_lc_policy"] = TensorDictSequential(self.lc_state, self.lc_actor)
        self.register_buffer("counters", torch.zeros(3, dtype=torch.long))  # lc updates, cf updates, actor updates
        if seeds is not None:  # N learners in one (modules/seed_batch.py): each loss reduced per seed by the base
            stack_seeds(self, seeds, scalars=["lc_explore.eps"])  # each seed's ε, annealed by its own decisions
            self.lc_loss.reduction = self.cf_loss.reduction = "none"
        dev = self._place(device)  # then the optimisers and target updates, on the moved tensors
        # a seed batch: the optimisers that a seed's decisions step (the D3QN's, the embedding's) keep a step count per
        # seed (SeedAdam); the TD3's step every seed that still trains at once, a seed that has ended never again, so
        # one count serves them and they keep the fused kernel
        per_seed = adam if seeds is None else (lambda params, lr, _dev: seed_adam(self, params, lr))
        self.opt_lc = per_seed(self.lc_loss.parameters(), self.lr_lc, dev)
        self.opt_critic = adam(self.td3.critic_params().flatten_keys().values(), self.lr_critic, dev)
        self.opt_actor = adam(self.cf_loss.actor_network_params.flatten_keys().values(), self.lr_actor, dev)
        emb = embedding_parameters(self.embedding)
        self.opt_embed = per_seed(emb, float(embed_lr), dev) if emb else None
        embed_targets = module_tensors(self.target_embedding, self.embedding, self.embed_tau)
        embed_buffers = (
            []
            if self.embedding is None
            else list(zip(self.target_embedding.buffers(), self.embedding.buffers(), strict=True))
        )
        # Eq. 9-10 (+ the target embedding) and Eq. 5 (+ the target embedding), as TorchRL's SoftUpdate computes them
        self._soft_cf = PolyakUpdate(soft_update_tensors(self.td3.target_updater), embed_targets, copies=embed_buffers)
        self._soft_lc = PolyakUpdate(soft_update_tensors(self.d3qn.target_updater), embed_targets, copies=embed_buffers)
        self._compile(compile, cudagraphs)  # the learner's one compile site

    # --------------------------------------------------------------------------------- acting
    def _policy(self, explore: bool = True) -> MultiRatePolicy:
        """The acting policy: D3QN on decision frames (held action otherwise), TD3 every frame.

        ``explore=True`` adds ε-greedy and Gaussian noise modules; they act only under TorchRL's
        ``ExplorationType.RANDOM`` (a collector's default), so the same policy is greedy inside
        ``set_exploration_type(ExplorationType.DETERMINISTIC)``."""
        lc = [self.lc_state, self.lc_actor] + ([self.lc_explore] if explore else [])
        cf = [self.cf_state, self.cf_actor] + ([self.cf_explore] if explore else [])
        policy = MultiRatePolicy(
            TensorDictSequential(*lc),
            TensorDictSequential(*cf),
            shared=self.embedding,
            every_row=self.seeds is not None,
        )
        return policy if self.seeds is None else SeedRows(policy, self.seeds)

    def buffer_keys(self) -> list:
        """Keys a replay-buffer entry must keep for the updates (root and under ``"next"``)."""
        emb = list(self.embedding.in_keys) if self.embedding is not None else []
        mobil = [K.MOBIL_INCENTIVE, K.MOBIL_SAFE] if self.mobil_criteria else []
        return transition_keys([*HIERARCHICAL_STATE_KEYS, *emb, *mobil], [K.LC_ACTION, K.CF_ACTION])

    def explore_step(self, decisions, frames: int) -> None:
        """Advances ε (per decision) and the Gaussian σ schedule (per frame). A batch of seeds: ``decisions`` per
        seed, each seed's ε stepped as TorchRL's ``EGreedyModule.step`` steps it, one decision at a time."""
        if self.seeds is not None:
            e = self.lc_explore
            delta = (e.eps_init - e.eps_end) / e.annealing_num_steps
            for i, n in enumerate(decisions):
                for _ in range(int(n)):
                    e.eps.data[i].copy_(torch.maximum(e.eps_end, e.eps[i] - delta))
        elif decisions:
            self.lc_explore.step(decisions)
        if frames:
            self.cf_explore.step(frames)

    def exploration(self) -> dict[str, float]:
        """ε (a batch of seeds: seed by seed, a list)."""
        eps = self.lc_explore.eps
        return {"epsilon": eps.reshape(-1).tolist() if self.seeds is not None else float(eps)}

    # ---------------------------------------------------------------------------------- updates
    def loss(self, name: str, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The loss ``name`` of a replay-buffer sample, on the agents' states (s_e of Eq. 23-24 inside), and for
        the value losses each transition's ``|δ|`` (prioritized replay, :mod:`~kddrl_trl.objectives.priority`):

        - ``"cf_value"``: TD3 twin-critic loss (Eq. 6-7); trains the embedding too (target s_e from the target
          embedding; the next state's lane-change action is the D3QN's greedy choice where the next frame is a
          decision frame, the held one elsewhere);
        - ``"cf_actor"``: TD3 actor loss (Eq. 8) on a detached s_e;
        - ``"lc"``: D3QN double-DQN loss (Eq. 4); trains the embedding too.

        Tensor maths only (no optimiser step): what ``compile`` hands to ``torch.compile``."""
        if name == "cf_value":
            states = build_agent_states(
                batch,
                self.embedding,
                self.cf_state,
                target_embedding=self.target_embedding,
                next_lc_policy=self.next_lc_policy,
            )
            return self.td3.value_loss(states)
        if name == "cf_actor":
            states = build_agent_states(batch.exclude("next"), self.embedding, self.cf_state)
            return self.td3.actor_loss(detach_embedding(states)), None
        if name == "lc":
            states = build_agent_states(batch, self.embedding, self.lc_state, target_embedding=self.target_embedding)
            loss = self.lc_loss(states)["loss"]  # DQNLoss writes the squared TD errors into ``states``
            return loss, td_priority(states.get(self.lc_loss.tensor_keys.priority), states.numel())
        raise ValueError(f"HierarchicalLearner.loss: unknown loss {name!r}; known: cf_value, cf_actor, lc")

    def update_functions(self) -> dict:
        """``"cf_value"``: the TD3 critic step; ``"cf_full"``: the critic step, then the actor step and the soft
        target updates (the step of every ``policy_delay``-th critic update); ``"lc"``: the D3QN step."""
        return {"cf_value": self._step_cf_value, "cf_full": self._step_cf_full, "lc": self._step_lc}

    def _step_cf_value(self, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """TD3 critic step (Eq. 6-7): the critics and the embedding (its own optimiser, ``modules/sharing.py``)."""
        value_loss, priority = self._descend("cf_value", batch, self.opt_critic, self.opt_embed)
        return value_loss.reshape(1, *value_loss.shape), priority

    def _step_cf_full(self, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """The critic step, then the delayed actor step (Eq. 8, on detached s_e, after the critic moved) and the
        soft target updates of the actor, the critics and the embedding (Eq. 9-10)."""
        value_loss, priority = self._step_cf_value(batch)
        actor_loss, _ = self._descend("cf_actor", batch, self.opt_actor)
        self._soft_cf()
        return torch.cat([value_loss, actor_loss.reshape(1, *actor_loss.shape)]), priority

    def _step_lc(self, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """D3QN step (Eq. 4, the embedding trained too), then the soft target updates (Eq. 5 and the embedding)."""
        loss, priority = self._descend("lc", batch, self.opt_lc, self.opt_embed)
        self._soft_lc()
        return loss.reshape(1, *loss.shape), priority

    def update_cf(self, batch: TensorDictBase, active: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """One TD3 step on a buffer-L sample (Algorithm 1 lines 38-43); ``active``: a seed batch's seeds that take it
        (:meth:`~kddrl_trl.training.learner.Learner._run`; they share the update counters, so a seed that sits a TD3
        step out takes no later one)."""
        self.counters[1] += 1
        if int(self.counters[1]) % self.td3.policy_delay == 0:
            value_loss, actor_loss = self._run("cf_full", batch, active).unbind()
            self.counters[2] += 1
            return {"loss_qvalue": value_loss, "loss_actor": actor_loss}
        return {"loss_qvalue": self._run("cf_value", batch, active)[0]}

    def update_frame(self, batch: TensorDictBase, active: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Buffer L: :meth:`update_cf` (called as a single learner's, ``update_cf(batch)``, where no seeds sit out)."""
        return self.update_cf(batch) if active is None else self.update_cf(batch, active)

    def update_decision(self, batch: TensorDictBase, active: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Buffer H: :meth:`update_lc` (called as a single learner's where no seeds sit out)."""
        return self.update_lc(batch) if active is None else self.update_lc(batch, active)

    def update_lc(self, batch: TensorDictBase, active: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """One D3QN step on a buffer-H sample of macro-transitions (Algorithm 1 lines 27-29); ``active``: a seed
        batch's seeds that take it (each seed learns once per decision of its own)."""
        loss = self._run("lc", batch, active)[0]
        self.counters[0] += 1
        return {"loss_lc": loss}

    # ------------------------------------------------------------------------------- checkpoints
    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        opts = {"lc": self.opt_lc, "critic": self.opt_critic, "actor": self.opt_actor}
        if self.opt_embed is not None:
            opts["embed"] = self.opt_embed
        return opts
