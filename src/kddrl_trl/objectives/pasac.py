"""PASAC, parameterised-action soft actor-critic (``algo=pasac_unified``; the paper's "PASAC (Unit)", Table I,
§II.B): one agent choosing a discrete lane command and a continuous acceleration every 0.1 s. TorchRL has no loss
for it: :class:`PASACLoss` is one, written the way ``torchrl/objectives/sac.py`` (``SACLoss``, ``DiscreteSACLoss``)
is. :func:`make_pasac` wires it to the keys of :mod:`kddrl_trl.keys`.

The policy factorises, ``π(k, x | s) = π_d(k | s) π_c(x | s, k)``: a categorical over the lane commands k (left,
keep, right; invalid commands have probability 0) and, for each command, a tanh-Gaussian over its acceleration x_k,
scaled to [low, high] (Eq. 31). The acceleration is conditioned on the command, as in parameterised-action SAC
(Delalleau et al. 2019) and P-DQN (Xiong et al. 2018): the acceleration that suits a lane change (closing on a gap
in the target lane) differs from the one that suits keeping the lane, and one acceleration shared by all commands
would have to average them. Each part has its own temperature (α_d, α_c), auto-tuned towards its own target entropy
(Haarnoja et al. 2018 for the continuous part, Christodoulou 2019 for the discrete one) and kept inside
[``alpha_min``, ``alpha_max``] (TorchRL's ``SACLoss`` bounds its temperature the same way). With twin soft critics
``Q_i(s, k, x)`` and target copies ``Q'_i``:

- soft value of a next state, exact over k and one sample x'_k ~ π_c(·|s', k) per command:
  ``V(s') = Σ_k π_d(k|s') [min_i Q'_i(s', k, x'_k) - α_d log π_d(k|s') - α_c log π_c(x'_k|s', k)]``;
- critic loss: ``Σ_i E[(Q_i(s, k, x) - r - γ (1 - terminated) V(s'))²]`` (the target through the TorchRL value
  estimator made by :meth:`~PASACLoss.make_value_estimator`, TD(0) by default);
- actor loss, x_k reparameterised, critics detached:
  ``E_s[Σ_k π_d(k|s) (α_d log π_d(k|s) + α_c log π_c(x_k|s, k) - min_i Q_i(s, k, x_k))]``;
- temperatures: ``-log α_c (Σ_k π_d(k|s) log π_c(x_k|s, k) + H̄_c)`` (π_d detached) and ``log α_d (H_d - H̄_d)``,
  so each α falls while its part's entropy is above its target H̄ and rises below it; ``H_d`` is averaged over the
  states where the mask leaves more than one lane command (elsewhere the lane choice has entropy 0, below any
  target, whatever α_d).

``log π_c`` is the density of the tanh-squashed action in [-1, 1] (before the affine scaling to [low, high]), SAC's
usual convention, so ``target_entropy_param = -1`` (-dim) is the usual target.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.nn import TensorDictModule, TensorDictModuleBase
from tensordict.utils import NestedKey, unravel_key
from torch import Tensor
from torchrl.envs.utils import ExplorationType, exploration_type
from torchrl.objectives import LossModule, SoftUpdate
from torchrl.objectives.utils import ValueEstimators, _vmap_func, default_value_kwargs, distance_loss
from torchrl.objectives.value import TD0Estimator, TD1Estimator, TDLambdaEstimator

from .. import keys as K
from ..modules.heads import HybridActor, HybridCritic


def tanh_gaussian(loc: Tensor, scale: Tensor, noise: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """A reparameterised sample ``u = tanh(loc + scale ε)`` in [-1, 1] (``noise`` = ε, drawn when None) and its
    log-density, summed over the last dimension (change of variables of the tanh)."""
    eps = torch.randn_like(loc) if noise is None else noise
    pre = loc + scale * eps
    u = torch.tanh(pre)
    log_prob = torch.distributions.Normal(loc, scale).log_prob(pre) - torch.log1p(-u.pow(2) + 1e-6)
    return u, log_prob.sum(-1, keepdim=True)


class PASACLoss(LossModule):
    """Loss of a parameterised-action SAC agent (module docstring for the equations).

    Args:
        actor_network (TensorDictModule): reads the state (and the valid-command mask), writes the ``logits``, ``loc``
            and ``scale`` keys (:class:`~kddrl_trl.modules.heads.HybridActor`).
        qvalue_network (TensorDictModule): reads the state, the one-hot ``action`` and the continuous ``param``,
            writes ``state_action_value`` (:class:`~kddrl_trl.modules.heads.HybridCritic`). Its last two ``in_keys``
            must be the ``action`` and ``param`` keys.

    Keyword Args:
        num_choices (int): discrete choices (3 lane commands).
        num_qvalue_nets (int): twin critics by default.
        low, high (float): bounds of the continuous parameter (the tanh sample is scaled to them).
        alpha_init (float): initial value of both temperatures.
        alpha_min, alpha_max (float): bounds of both temperatures (TorchRL ``SACLoss``'s ``min_alpha``,
            ``max_alpha``): an entropy target the policy cannot reach (a critic that ranks commands far apart) then
            leaves α at ``alpha_max`` instead of letting it grow until the entropy bonus outweighs the rewards.
        target_entropy_lane (float): target entropy H̄_d of the lane choice, in nats (≤ log of the number of commands).
        target_entropy_param (float): target entropy H̄_c of the tanh-squashed parameter (SAC: ``-dim``).
        loss_function (str): critic distance, ``"l2"`` (default) or ``"smooth_l1"``.

    Returns (``forward``): a TensorDict with ``loss_qvalue``, ``loss_actor``, ``loss_alpha_lane``,
    ``loss_alpha_param`` (each trains disjoint parameters: summing them and stepping one optimiser per part is
    the SAC update) and the detached diagnostics ``alpha_lane``, ``alpha_param``, ``entropy_lane``,
    ``log_prob_param``, ``state_action_value``, ``target_value``, and ``td_error`` (TorchRL's priority key): the
    squared TD errors ``[critics, B]`` (prioritized replay's priorities, :mod:`.priority`). A sample with
    ``keys.PRIORITY_WEIGHT`` weights the critic and policy means by them (TorchRL's reduction); the temperature
    losses stay unweighted.
    """

    @dataclass
    class _AcceptedKeys:
        """Keys a :class:`PASACLoss` reads and writes; change them with ``set_keys``.

        Attributes:
            action: one-hot discrete choice (the lane command). Defaults to ``keys.LC_ACTION``.
            param: continuous parameter (the acceleration). Defaults to ``keys.CF_ACTION``.
            action_mask: valid discrete choices. Defaults to ``keys.LC_ACTION_MASK``.
            logits, loc, scale: outputs of the actor network. Default to ``keys.PASAC_*``.
            state_action_value: output of the critic. Defaults to ``keys.PASAC_STATE_ACTION_VALUE``.
            value: the soft value of the next state, written under ``"next"`` for the value estimator.
                Defaults to ``"state_value"``.
            reward, done, terminated: read under ``"next"``. Default to ``keys.JOINT_REWARD``, ``"done"``,
                ``"terminated"``.
            priority: the squared TD errors in ``forward`` 's output. Defaults to ``"td_error"``.
            priority_weight: a prioritized sample's importance weights. Defaults to ``keys.PRIORITY_WEIGHT``.
        """

        action: NestedKey = K.LC_ACTION
        param: NestedKey = K.CF_ACTION
        action_mask: NestedKey = K.LC_ACTION_MASK
        logits: NestedKey = K.PASAC_LOGITS
        loc: NestedKey = K.PASAC_LOC
        scale: NestedKey = K.PASAC_SCALE
        state_action_value: NestedKey = K.PASAC_STATE_ACTION_VALUE
        value: NestedKey = "state_value"
        reward: NestedKey = K.JOINT_REWARD
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"
        priority: NestedKey = "td_error"
        priority_weight: NestedKey = K.PRIORITY_WEIGHT

    tensor_keys: _AcceptedKeys
    actor_network: TensorDictModule
    qvalue_network: TensorDictModule
    actor_network_params: TensorDictParams
    qvalue_network_params: TensorDictParams
    target_actor_network_params: TensorDictParams
    target_qvalue_network_params: TensorDictParams
    default_keys = _AcceptedKeys
    use_prioritized_weights = "auto"  # a sample's priority_weight (prioritized replay) weights the means, as TorchRL's
    default_value_estimator = ValueEstimators.TD0
    out_keys = [
        "loss_qvalue",
        "loss_actor",
        "loss_alpha_lane",
        "loss_alpha_param",
        "alpha_lane",
        "alpha_param",
        "entropy_lane",
        "log_prob_param",
        "state_action_value",
        "target_value",
        "td_error",
    ]

    def __init__(
        self,
        actor_network: TensorDictModule,
        qvalue_network: TensorDictModule,
        *,
        num_choices: int = 3,
        num_qvalue_nets: int = 2,
        low: float = -5.0,
        high: float = 5.0,
        alpha_init: float = 1.0,
        alpha_min: float = 1e-4,
        alpha_max: float = 1.0,
        target_entropy_lane: float = 0.33,
        target_entropy_param: float = -1.0,
        loss_function: str = "l2",
    ):
        super().__init__()
        self._in_keys = None
        self.num_choices, self.num_qvalue_nets = int(num_choices), int(num_qvalue_nets)
        self.loss_function = loss_function
        self.convert_to_functional(actor_network, "actor_network", create_target_params=False)
        self.convert_to_functional(
            qvalue_network,
            "qvalue_network",
            expand_dim=self.num_qvalue_nets,
            create_target_params=True,
            compare_against=list(actor_network.parameters()),
        )
        # every critic on one batch in one call (the critics' parameters stacked along dim 0), as SACLoss does
        self._vmap_q = _vmap_func(self.qvalue_network, (None, 0), randomness="error")
        self.register_buffer("param_loc", torch.tensor((high + low) / 2.0))
        self.register_buffer("param_half", torch.tensor((high - low) / 2.0))
        if not 0.0 < alpha_min <= alpha_init <= alpha_max:
            raise ValueError(
                f"PASACLoss: need 0 < alpha_min <= alpha_init <= alpha_max, got alpha_min={alpha_min}, "
                f"alpha_init={alpha_init}, alpha_max={alpha_max}"
            )
        self.log_alpha_min, self.log_alpha_max = math.log(alpha_min), math.log(alpha_max)
        self.log_alpha_lane = torch.nn.Parameter(torch.tensor(math.log(alpha_init)))
        self.log_alpha_param = torch.nn.Parameter(torch.tensor(math.log(alpha_init)))
        self.register_buffer("target_entropy_lane", torch.tensor(float(target_entropy_lane)))
        self.register_buffer("target_entropy_param", torch.tensor(float(target_entropy_param)))

    # ---------------------------------------------------------------------------------- TorchRL API
    def _forward_value_estimator_keys(self, **kwargs) -> None:
        if self._value_estimator is not None:
            self._value_estimator.set_keys(
                value=self.tensor_keys.value,
                reward=self.tensor_keys.reward,
                done=self.tensor_keys.done,
                terminated=self.tensor_keys.terminated,
            )
        self._set_in_keys()

    def _set_in_keys(self) -> None:
        keys = list(dict.fromkeys([*self.actor_network.in_keys, *self.qvalue_network.in_keys]))
        t = self.tensor_keys
        nxt = [unravel_key(("next", k)) for k in [*self.actor_network.in_keys, t.reward, t.done, t.terminated]]
        self._in_keys = list(dict.fromkeys([*keys, *nxt]))

    @property
    def in_keys(self):
        if self._in_keys is None:
            self._set_in_keys()
        return self._in_keys

    def make_value_estimator(self, value_type: ValueEstimators | None = None, **hyperparams):
        """The estimator of the critic target (TD(0) by default; ``gamma`` among ``hyperparams``)."""
        if value_type is None:
            value_type = self.default_value_estimator
        self.value_type = value_type
        hp = dict(default_value_kwargs(value_type))
        hp.update(hyperparams)
        estimators = {
            ValueEstimators.TD0: TD0Estimator,
            ValueEstimators.TD1: TD1Estimator,
            ValueEstimators.TDLambda: TDLambdaEstimator,
        }
        if value_type not in estimators:
            raise NotImplementedError(f"PASACLoss: value estimator {value_type} is not supported")
        self._value_estimator = estimators[value_type](value_network=None, **hp)
        self._value_estimator.set_keys(
            value=self.tensor_keys.value,
            reward=self.tensor_keys.reward,
            done=self.tensor_keys.done,
            terminated=self.tensor_keys.terminated,
        )
        return self

    # -------------------------------------------------------------------------------------- pieces
    @property
    def alpha_lane(self) -> Tensor:
        return self.log_alpha_lane.detach().exp()

    @property
    def alpha_param(self) -> Tensor:
        return self.log_alpha_param.detach().exp()

    def clamp_temperatures(self) -> None:
        """Bring both log-temperatures back into [log alpha_min, log alpha_max] (in place, outside autograd)."""
        with torch.no_grad():
            self.log_alpha_lane.clamp_(self.log_alpha_min, self.log_alpha_max)
            self.log_alpha_param.clamp_(self.log_alpha_min, self.log_alpha_max)

    def _policy(self, td: TensorDictBase) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """(π_d [*, K], log π_d [*, K], one reparameterised parameter x_k in [low, high] per command [*, K, P], and
        log π_c(x_k | s, k) [*, K])."""
        td = td.select(*self.actor_network.in_keys, strict=False).clone(False)
        with self.actor_network_params.to_module(self.actor_network):
            self.actor_network(td)
        log_p = torch.log_softmax(td.get(self.tensor_keys.logits), dim=-1)
        u, log_prob = tanh_gaussian(td.get(self.tensor_keys.loc), td.get(self.tensor_keys.scale))
        return log_p.exp(), log_p, self.param_loc + self.param_half * u, log_prob.squeeze(-1)

    def _q(self, td: TensorDictBase, choice: Tensor, param: Tensor, params: TensorDictBase) -> Tensor:
        """``Q_i(s, choice, param)`` of every critic i: ``[num_qvalue_nets, *batch]``."""
        obs_keys = self.qvalue_network.in_keys[:-2]
        x = td.select(*obs_keys).clone(False)
        x.set(self.tensor_keys.action, choice)
        x.set(self.tensor_keys.param, param)
        return self._vmap_q(x, params).get(self.tensor_keys.state_action_value).squeeze(-1)

    def _q_every_choice(self, td: TensorDictBase, param: Tensor, params: TensorDictBase) -> Tensor:
        """``min_i Q_i(s, k, x_k)`` for every choice k, ``param`` holding x_k ``[*batch, K, P]``: ``[*batch, K]``."""
        n, batch = self.num_choices, td.batch_size
        expanded = td.select(*self.qvalue_network.in_keys[:-2]).unsqueeze(-1).expand(*batch, n)
        choice = torch.eye(n, dtype=param.dtype, device=param.device).expand(*batch, n, n)
        return self._q(expanded, choice, param, params).min(0).values

    # ---------------------------------------------------------------------------------------- losses
    def qvalue_loss(self, tensordict: TensorDictBase) -> tuple[Tensor, dict[str, Tensor]]:
        """Twin soft-critic loss and the detached target (module docstring)."""
        with torch.no_grad():
            nxt = tensordict.get("next")
            p, log_p, param, log_prob = self._policy(nxt)
            q_next = self._q_every_choice(nxt, param, self.target_qvalue_network_params)
            value = (p * (q_next - self.alpha_lane * log_p - self.alpha_param * log_prob)).sum(-1, keepdim=True)
            td = tensordict.clone(False)
            td.set(("next", self.tensor_keys.value), value)
            target = self.value_estimator.value_estimate(td).squeeze(-1)
        pred = self._q(
            tensordict,
            tensordict.get(self.tensor_keys.action),
            tensordict.get(self.tensor_keys.param),
            self.qvalue_network_params,
        )
        loss = distance_loss(pred, target.expand_as(pred), loss_function=self.loss_function).sum(0)
        return self._weighted_mean(loss, tensordict), {
            "state_action_value": pred.detach().mean(),
            "target_value": target.detach().mean(),
            self.tensor_keys.priority: (pred - target).detach().pow(2),
        }

    def actor_loss(self, tensordict: TensorDictBase) -> tuple[Tensor, dict[str, Tensor]]:
        """Policy loss of both heads (critics detached) and the entropies the temperatures are tuned on."""
        p, log_p, param, log_prob = self._policy(tensordict)
        q = self._q_every_choice(tensordict, param, self.qvalue_network_params.detach())
        loss = self._weighted_mean(
            (p * (self.alpha_lane * log_p + self.alpha_param * log_prob - q)).sum(-1), tensordict
        )
        entropy = -(p * log_p).sum(-1)
        return loss, {
            "entropy_lane": entropy.detach(),
            "log_prob_param": (p * log_prob).sum(-1).detach(),
            "choosable": self.choosable(tensordict),
        }

    def choosable(self, tensordict: TensorDictBase) -> Tensor:
        """``[B]`` float, 1 where the state offers more than one valid lane command (its lane entropy can reach any
        target up to log(valid commands)), 0 where the mask leaves one (during a manoeuvre: entropy 0 whatever the
        policy). All ones for a sample without a mask."""
        mask = tensordict.get(self.tensor_keys.action_mask, None)
        if mask is None:
            return torch.ones(tensordict.batch_size, device=tensordict.device)
        return (mask.sum(-1) > 1).to(torch.get_default_dtype())

    def _weighted_mean(self, loss: Tensor, tensordict: TensorDictBase) -> Tensor:
        """Mean of a per-transition ``loss`` ``[B]``, weighted by the sample's ``priority_weight`` when it has them
        (``sum(w l) / sum(w)``, TorchRL's reduction)."""
        weights = self._maybe_get_priority_weight(tensordict)
        if weights is None:
            return loss.mean()
        weights = weights.reshape(loss.shape)
        return (loss * weights).sum() / weights.sum()

    def alpha_loss(
        self, entropy_lane: Tensor, log_prob_param: Tensor, choosable: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """Temperature losses of the lane choice and the parameter (module docstring). The lane temperature is
        tuned on the ``choosable`` states only (:meth:`choosable`): a state with one valid command has entropy 0
        below any target, and counting it drove α_d up without bound (measured 0.2 to 3e14 over a 1000-episode
        baseline run, the soft targets and the critic loss with it)."""
        gap = entropy_lane - self.target_entropy_lane
        if choosable is None:
            choosable = torch.ones_like(gap)
        lane = self.log_alpha_lane * (gap * choosable).sum() / choosable.sum().clamp(min=1.0)
        param = -(self.log_alpha_param * (log_prob_param + self.target_entropy_param)).mean()
        return lane, param

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        self.clamp_temperatures()
        loss_q, meta_q = self.qvalue_loss(tensordict)
        loss_actor, meta_a = self.actor_loss(tensordict)
        choosable = meta_a["choosable"]
        loss_lane, loss_param = self.alpha_loss(meta_a["entropy_lane"], meta_a["log_prob_param"], choosable)
        entropy_lane = (meta_a["entropy_lane"] * choosable).sum() / choosable.sum().clamp(min=1.0)
        return TensorDict(
            {
                "loss_qvalue": loss_q,
                "loss_actor": loss_actor,
                "loss_alpha_lane": loss_lane,
                "loss_alpha_param": loss_param,
                "alpha_lane": self.alpha_lane,
                "alpha_param": self.alpha_param,
                "entropy_lane": entropy_lane,
                "log_prob_param": meta_a["log_prob_param"].mean(),
                **meta_q,
            },
            batch_size=[],
        )


class HybridActionSampler(TensorDictModuleBase):
    """Acting with a PASAC policy: reads the actor's ``logits``, ``loc``, ``scale`` and writes the one-hot lane
    command (``keys.LC_ACTION``) and the acceleration (``keys.CF_ACTION``, in [low, high]). With ``explore`` and under
    TorchRL's ``ExplorationType.RANDOM`` (a collector's default) it samples both; otherwise it takes the modes
    (most probable valid command, ``tanh(loc_k)`` of that command k, scaled)."""

    def __init__(self, low: float = -5.0, high: float = 5.0, explore: bool = True):
        super().__init__()
        self.in_keys = [K.PASAC_LOGITS, K.PASAC_LOC, K.PASAC_SCALE]
        self.out_keys = [K.LC_ACTION, K.CF_ACTION]
        self.loc, self.half, self.explore = (high + low) / 2.0, (high - low) / 2.0, bool(explore)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        logits, loc, scale = (tensordict.get(k) for k in self.in_keys)
        sample = self.explore and exploration_type() in (ExplorationType.RANDOM, None)
        choice = torch.distributions.Categorical(logits=logits).sample() if sample else logits.argmax(-1)
        index = choice.reshape(*choice.shape, 1, 1).expand(*loc.shape[:-2], 1, loc.shape[-1])
        loc, scale = loc.gather(-2, index).squeeze(-2), scale.gather(-2, index).squeeze(-2)
        u = tanh_gaussian(loc, scale)[0] if sample else torch.tanh(loc)
        tensordict.set(K.LC_ACTION, torch.nn.functional.one_hot(choice, logits.shape[-1]).to(loc.dtype))
        tensordict.set(K.CF_ACTION, self.loc + self.half * u)
        return tensordict


@dataclass
class PASACParts:
    actor: TensorDictModule  # state -> logits, loc, scale
    critic: TensorDictModule  # Q(s, k, x) (PASACLoss makes the twin copies and targets)
    loss: PASACLoss
    target_updater: SoftUpdate

    def sampler(self, explore: bool) -> HybridActionSampler:
        return HybridActionSampler(
            float(self.loss.param_loc - self.loss.param_half),
            float(self.loss.param_loc + self.loss.param_half),
            explore,
        )


def make_pasac(
    obs_dim: int,
    *,
    num_choices: int = 3,
    low: float = -5.0,
    high: float = 5.0,
    hidden: Sequence[int] = (256, 256),
    gamma: float = 0.99,
    tau: float = 0.005,
    alpha_init: float = 1.0,
    alpha_min: float = 1e-4,
    alpha_max: float = 1.0,
    target_entropy_lane: float = 0.33,
    target_entropy_param: float = -1.0,
    loss_function: str = "l2",
    obs_key=K.JOINT_OBS,
) -> PASACParts:
    """The PASAC agent on ``obs_key``: lane command (``keys.LC_ACTION``, masked by ``keys.LC_ACTION_MASK``) and
    acceleration (``keys.CF_ACTION`` in [low, high] m/s², Eq. 31), rewarded with ``keys.JOINT_REWARD``."""
    actor = TensorDictModule(
        HybridActor(obs_dim, num_choices, 1, hidden),
        in_keys=[obs_key, K.LC_ACTION_MASK],
        out_keys=[K.PASAC_LOGITS, K.PASAC_LOC, K.PASAC_SCALE],
    )
    critic = TensorDictModule(
        HybridCritic(obs_dim, num_choices, 1, hidden, param_scale=max(abs(low), abs(high))),
        in_keys=[obs_key, K.LC_ACTION, K.CF_ACTION],
        out_keys=[K.PASAC_STATE_ACTION_VALUE],
    )
    loss = PASACLoss(
        actor,
        critic,
        num_choices=num_choices,
        low=low,
        high=high,
        alpha_init=alpha_init,
        alpha_min=alpha_min,
        alpha_max=alpha_max,
        target_entropy_lane=target_entropy_lane,
        target_entropy_param=target_entropy_param,
        loss_function=loss_function,
    )
    loss.make_value_estimator(gamma=gamma)
    return PASACParts(actor, critic, loss, SoftUpdate(loss, tau=tau))
