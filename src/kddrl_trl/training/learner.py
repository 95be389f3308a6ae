"""``Learner``: what :class:`~kddrl_trl.training.Trainer`, the collector factory and the evaluation need from a
learning algo, whatever its agents. Three learners implement it:

=============================================  ======================================  ===========================
learner                                        algos                                   buffers it learns from
=============================================  ======================================  ===========================
:class:`~.hierarchical.HierarchicalLearner`    kddrl, ablations, ni, peng              L (frames) and H (decisions)
:class:`~.joint_d3qn.JointD3QNLearner`         d3qn_unified                            L (frames)
:class:`~.pasac.PASACLearner`                  pasac_unified                           L (frames)
=============================================  ======================================  ===========================

A learner acts through :meth:`Learner.policy` (a TensorDict module writing ``keys.LC_ACTION`` and
``keys.CF_ACTION``, the env's action keys), names the keys its updates read (:meth:`Learner.buffer_keys`), makes
one gradient step per call of :meth:`Learner.update_frame` (a buffer-L sample, once per collected frame) and,
when :attr:`Learner.learns_from_decisions`, of :meth:`Learner.update_decision` (a buffer-H sample of
macro-transitions, once per lane-change decision), and saves everything in one dict
(:meth:`Learner.full_state_dict`).

Device and update functions
--------------------------------------
A learner lives on one ``device`` (``device=auto|cpu|cuda``, :func:`kddrl_trl.factories.make_device`): its
networks, targets, optimiser states, its replay buffers (:func:`~kddrl_trl.training.make_buffer`: sampled there;
:meth:`Learner._run` moves a batch from elsewhere) and its updates. The env, SUMO and the transforms stay on the
CPU, and so does the acting policy: a non-CPU learner acts through a CPU copy of its policy
(:class:`~kddrl_trl.collectors.PolicySnapshot`, refreshed after every batch of updates), faster than the GPU with the
transfers there and back (measured).

Each learner names its gradient steps as update functions (:meth:`Learner.update_functions`), as TorchRL's
``sota-implementations`` (td3, dqn) write ``update(batch)``: loss, gradients, optimiser steps and soft target
updates (:class:`~kddrl_trl.objectives.PolyakUpdate`, one ``torch._foreach_lerp_`` per group of targets) in one
function of a sampled batch that returns its detached losses. :meth:`Learner._compile` is the learner's one compile
site: with ``compile``, a step's loss and its gradients (:meth:`Learner._gradients`) are ``torch.compile`` d as one
graph and, once warm, called without TorchDynamo's frame evaluation (the CPU); on CUDA with ``cudagraphs``, each
update function is ``torch.compile`` d whole and wrapped in ``tensordict.nn.CudaGraphModule``
(:class:`~kddrl_trl.compiling.GraphedUpdate`: a batch's leaves copied in by one ``_foreach_copy_`` per dtype;
optimisers: ``Adam(capturable=True)``; the minibatch shapes are fixed). Nothing on the update path waits for the GPU:
the losses come back as device tensors, read once per collection batch by the trainer, and the update counters (the
TD3 policy delay reads one every update) stay on the CPU.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import nn

from .. import keys as K
from ..collectors import PolicySnapshot
from ..compiling import GraphedUpdate, WarmCompiled, inductor_options, resolve_cudagraphs, resolved
from ..modules.seed_batch import seed_means, stacked_tensors
from .adam import FusedAdam, step_all

#: keys a learner reads from a replay-buffer sample besides those of its own state (root and "next")
STATE_KEYS = (K.EGO_STATE, K.NEIGHBORS_REL, K.NEIGHBORS_MASK, K.EGO_ACCEL, K.LC_ACTION_MASK)
DONE_KEYS = ("done", "terminated", "truncated")


def adam(params, lr: float, device: torch.device | str | None = None, lean: bool = True) -> torch.optim.Adam:
    """Adam with the fused kernel (one call per step for all tensors; on a CPU PyTorch's default is a
    per-tensor loop). On CUDA it is ``torch.optim.Adam(capturable=True)`` (its step counters stay on the GPU, so
    that a CUDA graph can capture the step, which ``torch.compile`` traces); elsewhere, with ``lean``, a
    :class:`~.adam.FusedAdam` (the same arithmetic without ``Optimizer.step`` 's bookkeeping), without it
    ``torch.optim.Adam`` itself."""
    params = [p for p in params if p.requires_grad]
    capturable = device is not None and torch.device(device).type == "cuda"
    if lean and not capturable:
        return FusedAdam(params, lr=lr)
    return torch.optim.Adam(params, lr=lr, fused=True, capturable=capturable)


def _param_layout(grad: torch.Tensor | None, param: torch.Tensor) -> torch.Tensor | None:
    """``grad`` with ``param`` 's strides, as ``backward`` stores a ``.grad`` (``AccumulateGrad`` 's layout
    contract). ``torch.autograd.grad`` returns what the backward ops made (a weight's gradient from ``mm``
    transposed), and torch's fused CPU Adam kernel (2.13) reads a gradient in its parameter's layout without
    checking its strides: given a transposed one, it steps each weight with another weight's gradient, silently."""
    if grad is None or grad.stride() == param.stride():
        return grad
    return grad.new_empty_strided(param.size(), param.stride()).copy_(grad)


def transition_keys(obs: Sequence[NestedKey], actions: Sequence[NestedKey]) -> list:
    """Keys of a stored transition: ``obs`` and ``actions`` at the root, ``obs``, both agents' rewards and the
    done flags under ``"next"``."""
    obs = list(dict.fromkeys(obs))
    rewards = [("next", K.LC_REWARD), ("next", K.CF_REWARD)] + [("next", k) for k in DONE_KEYS]
    return [*obs, *actions, *[("next", *(k if isinstance(k, tuple) else (k,))) for k in obs], *rewards]


class Learner(nn.Module):
    """Base of the learners (module docstring). Subclasses register their networks, losses and exploration
    modules as submodules (so that ``state_dict()`` holds them) and implement the methods that raise here."""

    #: whether :meth:`update_decision` learns from buffer H (the lane-change agent's macro-transitions)
    learns_from_decisions: bool = False
    #: the attribute holding the TorchRL loss that learns from buffer L (frames)
    frame_loss_name: str = ""
    #: None: one learner; N: N independent learners stacked on a leading seed dimension
    #: (:mod:`kddrl_trl.modules.seed_batch`), each loss reduced per seed and its step descending their sum
    seeds: int | None = None

    @property
    def frame_gamma(self) -> float:
        """The per-frame discount of the buffer-L loss (its TD(0) estimator's ``gamma``): what n-step returns
        (``train.n_steps``, :class:`~kddrl_trl.collectors.nstep.NStepReturns`) discount the window's rewards by."""
        return float(getattr(self, self.frame_loss_name).value_estimator.gamma)

    def _place(self, device: torch.device | str | None) -> torch.device:
        """Moves the learner (networks, targets, exploration schedules, counters) to ``device`` (None: the CPU)
        and returns it. Call it before building optimisers and target updates (they hold the moved tensors)."""
        self.device = torch.device(device if device is not None else "cpu")
        self.to(self.device)
        if "counters" in self._buffers:  # read on every update (the policy delay): a GPU read would wait for the GPU
            self._buffers["counters"] = self.counters.cpu()
        return self.device

    def _compile(self, compile: bool, cudagraphs: bool = False) -> None:
        """The learner's one compile site (module docstring), when ``compile`` (resolved by
        :func:`kddrl_trl.factories.make_job`), with fixed minibatch shapes (``dynamic=False``):

        - without CUDA graphs (the CPU): the learner's :meth:`_gradients` (a step's loss and ``torch.autograd.grad``
          of it, forward and backward in one graph: :func:`~kddrl_trl.compiling.tracing_gradients`) is
          ``torch.compile`` d (on the CPU with TorchInductor's C++ wrapper,
          :func:`~kddrl_trl.compiling.inductor_options`) and, once warm, its graph is called directly, without
          TorchDynamo's frame evaluation (:class:`~kddrl_trl.compiling.WarmCompiled`); the rest of the update
          functions stays eager:
          the fused Adam steps and ``_foreach_lerp_`` are one call each already, and each of them would be a graph
          break (with its guarded resume frames) inside a compiled update function, whose TorchDynamo cache lookups
          would then cost more than they save (``benchmarks/update_speed.py`` measures both);
        - with ``cudagraphs`` (CUDA learners only): each of :meth:`update_functions` is ``torch.compile`` d whole and
          wrapped in ``CudaGraphModule``, whose replays skip Python, guards included."""
        self._trained = {}  # loss name -> the parameters its step trains (:meth:`_descend`)
        self.compiled = resolved("compile", compile)
        self.cudagraphs = resolve_cudagraphs(resolved("cudagraphs", cudagraphs), self.device)  # refused off CUDA
        if self.compiled and not self.cudagraphs:
            options = inductor_options(self.device)
            self.__dict__["_gradients"] = WarmCompiled(torch.compile(self._gradients, dynamic=False, options=options))
        fns = {}
        for name, fn in self.update_functions().items():
            if self.compiled and self.cudagraphs:
                fn = torch.compile(fn, dynamic=False)
            if self.cudagraphs:
                fn = GraphedUpdate(fn, self.device, written=(K.PRIORITY,))
            fns[name] = fn
        self.__dict__["_update_fns"] = fns  # not submodules (compiled wrappers hold the learner's own modules)

    def _seed_tensors(self) -> list[tuple[torch.Tensor, int]]:
        """Every tensor of a seed batch whose slices are a seed's own, with its seed dimension: the stacked networks
        and targets (found once: they keep their identity), and the optimisers' moments and step counts (read each
        time: a fused Adam makes its moments at its first step)."""
        if "_stacked" not in self.__dict__:
            self.__dict__["_stacked"] = stacked_tensors(self)
        out = list(self._stacked)
        dims = dict((id(t), d) for t, d in out)
        for opt in self.optimizers().values():
            if hasattr(opt, "seed_tensors"):
                out += opt.seed_tensors()
            else:  # one step count for all seeds (module docstring of seed_adam): the moments are per seed
                for p in (p for g in opt.param_groups for p in g["params"]):
                    state = opt.state.get(p, {})
                    out += [(state[k], dims[id(p)]) for k in ("exp_avg", "exp_avg_sq") if k in state]
        return out

    def _run(self, name: str, batch: TensorDictBase, active: torch.Tensor | None = None) -> torch.Tensor:
        """Runs the update function ``name`` on a sampled ``batch`` (moved to the learner's device); returns its
        detached losses (a 1-d tensor on the learner's device, not read here: on a GPU reading it would wait for
        the update, :meth:`~kddrl_trl.training.Trainer._update` reads a whole batch of updates' losses at once)
        and writes each transition's ``|δ|`` into ``batch`` (``keys.PRIORITY``: what a prioritized buffer's
        ``update_tensordict_priority`` reads; a graph's outputs come back cloned). ``active`` (a seed batch, ``[N]``
        bool): the seeds that take this step; the others' networks, targets and optimiser states are as before it."""
        on_device = batch if batch.device == self.device else batch.to(self.device, non_blocking=True)
        if active is not None and not bool(active.all()):  # a seed batch's step that some seeds sit out
            idle = (~active).nonzero().flatten()
            kept = [(t, d, t.index_select(d, idle)) for t, d in self._seed_tensors()]
            losses, priority = self._update_fns[name](on_device)
            with torch.no_grad():
                for t, d, before in kept:
                    t.index_copy_(d, idle, before)
        else:
            losses, priority = self._update_fns[name](on_device)
        batch.set(K.PRIORITY, priority.reshape(batch.shape))
        return losses

    def policy(self, explore: bool = True) -> TensorDictModuleBase:
        """The acting policy (exploration modules act only under ``ExplorationType.RANDOM``) for env TensorDicts
        on the CPU: :meth:`_policy`; a non-CPU learner's is a CPU copy,
        :class:`~kddrl_trl.collectors.PolicySnapshot` (acting is faster on the CPU, measured)."""
        policy = self._policy(explore)
        return policy if self.device.type == "cpu" else PolicySnapshot(policy)

    # ------------------------------------------------------------------------------- to implement
    def _policy(self, explore: bool = True) -> TensorDictModuleBase:
        """The acting policy on the learner's device."""
        raise NotImplementedError

    def update_functions(self) -> dict:
        """Name -> ``update(batch) -> (detached losses (1-d tensor), |δ| per transition)``: one gradient step (loss,
        backward, optimiser steps, soft target updates), what :meth:`_compile` compiles and graphs."""
        raise NotImplementedError

    def buffer_keys(self) -> list:
        """Keys a replay-buffer entry must keep for the updates (root and under ``"next"``)."""
        raise NotImplementedError

    def loss(self, name: str, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(the loss ``name`` of a replay-buffer sample, its transitions' ``|δ|`` for a value loss, else None):
        tensor maths only, what ``compile`` compiles. A sample with ``keys.PRIORITY_WEIGHT`` (prioritized replay)
        weights the loss's mean by them."""
        raise NotImplementedError

    def update_frame(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One gradient step on a buffer-L sample (frames); returns the losses as 0-d tensors on the learner's
        device (unread: reading one on a GPU waits for the update; the trainer reads a batch of them at once)."""
        raise NotImplementedError

    def update_decision(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One gradient step on a buffer-H sample (macro-transitions); returns the losses as :meth:`update_frame`."""
        raise NotImplementedError(f"{type(self).__name__} learns from buffer L only")

    def explore_step(self, decisions: int, frames: int) -> None:
        """Advances the exploration schedules by the decisions and frames just collected."""

    def exploration(self) -> dict[str, float]:
        """Exploration scalars logged under ``train/`` per training episode (ε, temperatures, ...)."""
        return {}

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        raise NotImplementedError

    # -------------------------------------------------------------------------------- shared parts
    def _objective(self, name: str, losses: torch.Tensor) -> torch.Tensor:
        """The scalar that the step of the loss ``name`` descends, from what :meth:`loss` returned: the loss itself
        (a learner whose loss returns several entries, some of them diagnostics, says which to sum)."""
        return losses

    def _gradients(self, name: str, batch: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor | None, tuple]:
        """(the detached loss ``name`` of ``batch``, its transitions' ``|δ|`` or None, the gradients of its
        :meth:`_objective` with respect to the parameters its step trains, in :meth:`_descend` 's order; None for a
        parameter it does not reach). ``torch.autograd.grad`` computes the same gradients as ``backward``; what
        ``compile`` compiles, forward and backward in one graph (:meth:`_compile`)."""
        losses, priority = self.loss(name, batch)
        objective = self._objective(name, losses)
        if self.seeds is not None:  # each seed's own mean; the sum's gradient for seed n is seed n's loss's
            losses = seed_means(losses, batch)
            objective = seed_means(objective, batch).sum()
        params = self._trained[name]
        grads = torch.autograd.grad(objective, params, allow_unused=True)
        return losses.detach(), priority, tuple(map(_param_layout, grads, params))

    def _descend(self, name: str, batch: TensorDictBase, *optimizers: torch.optim.Optimizer | None):
        """One gradient step on the loss ``name`` of ``batch``: the gradients of :meth:`_gradients` become the
        parameters' ``grad`` (what ``zero_grad`` then ``backward`` would leave), then each optimiser steps (None
        entries skipped; :func:`~.adam.step_all`: lean ones share their fused kernel call). The parameters a step
        trains are its optimisers' own, in their order. Returns the detached loss and the ``|δ|`` (or None)."""
        opts = [o for o in optimizers if o is not None]
        if name not in self._trained:
            self._trained[name] = tuple(p for o in opts for g in o.param_groups for p in g["params"])
        losses, priority, grads = self._gradients(name, batch)
        for p, g in zip(self._trained[name], grads, strict=True):
            p.grad = g
        step_all(opts)
        return losses, priority

    def full_state_dict(self) -> dict:
        """Networks, targets, exploration schedules, counters and optimiser states."""
        return {"modules": self.state_dict(), "optimizers": {k: o.state_dict() for k, o in self.optimizers().items()}}

    def load_full_state_dict(self, state: Mapping) -> None:
        """Loads :meth:`full_state_dict`, also one saved on another device: each optimiser keeps its own
        ``capturable`` and ``fused`` (a CPU checkpoint's ``capturable=False`` would stop a CUDA graph's capture)."""
        self.load_state_dict(state["modules"])
        for name, opt in self.optimizers().items():
            saved = state["optimizers"][name]
            groups = [
                {**g, "capturable": own["capturable"], "fused": own["fused"]}
                for g, own in zip(saved["param_groups"], opt.param_groups)
            ]
            opt.load_state_dict({**saved, "param_groups": groups})
