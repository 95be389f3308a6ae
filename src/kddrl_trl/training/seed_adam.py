"""``SeedAdam``: Adam over the seed-stacked parameters of N learners in one (:mod:`kddrl_trl.modules.seed_batch`),
each seed with its own step count.

Adam is elementwise but for its bias corrections, which read the number of steps taken. Seeds of a batch take
different numbers of steps (a seed's lane-change agent learns once per decision of its own, a seed that has
finished its episodes learns no more), so a single step count per tensor, as ``torch.optim.Adam`` keeps, would
bias-correct a seed with another's count. Here each stacked tensor is stepped as its N per-seed slices, each
slice with its own step count (``state["step"]`` is ``[N]``), by ``torch.optim.adam.adam`` (the foreach
implementation: the slices of a twin critic's ``[2, N, out, in]`` are not contiguous, which the fused CPU kernel
does not handle). Which seeds step is the learner's business (:meth:`~kddrl_trl.training.learner.Learner._run`
restores the seeds that sat a step out).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn
from torch.optim.adam import adam

from ..modules.seed_batch import seed_dims_of


class SeedAdam(torch.optim.Optimizer):
    """Adam (``lr``, default betas and eps) over ``params``, each stacked on a seed dimension at ``seed_dims``."""

    def __init__(self, params, seed_dims: Sequence[int], lr: float, betas=(0.9, 0.999), eps: float = 1e-8):
        params = [p for p in params]
        if len(params) != len(seed_dims) or not params:
            raise ValueError(f"SeedAdam: {len(params)} parameters for {len(seed_dims)} seed dimensions")
        super().__init__(params, {"lr": float(lr), "betas": tuple(betas), "eps": float(eps)})
        self.seed_dims = [int(d) for d in seed_dims]
        self.seeds = params[0].shape[self.seed_dims[0]]
        for p, d in zip(params, self.seed_dims):
            if p.shape[d] != self.seeds:
                raise ValueError(f"SeedAdam: a parameter of shape {tuple(p.shape)} has no seed dimension {d}")
            self.state[p] = {
                "step": torch.zeros(self.seeds),
                "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format),
                "exp_avg_sq": torch.zeros_like(p, memory_format=torch.preserve_format),
            }
        self._views = None

    def _slices(self) -> list:
        """Per parameter: its per-seed slices of the parameter, both moments and the step count (views, taken once:
        the tensors are updated in place)."""
        if self._views is None:
            self._views = []
            for p, d in zip(self.param_groups[0]["params"], self.seed_dims):
                s = self.state[p]
                self._views.append(
                    (p.unbind(d), s["exp_avg"].unbind(d), s["exp_avg_sq"].unbind(d), s["step"].unbind(0))
                )
        return self._views

    @torch.no_grad()
    def step(self, closure=None):
        loss = closure() if closure is not None else None
        group = self.param_groups[0]
        params, grads, m, v, steps = [], [], [], [], []
        for p, d, (ps, ms, vs, ss) in zip(group["params"], self.seed_dims, self._slices()):
            if p.grad is None:
                continue
            params += ps
            grads += p.grad.unbind(d)
            m += ms
            v += vs
            steps += ss
        beta1, beta2 = group["betas"]
        adam(params, grads, m, v, [], steps, foreach=True, amsgrad=False, beta1=beta1, beta2=beta2,
             lr=group["lr"], weight_decay=0.0, eps=group["eps"], maximize=False)  # fmt: skip
        return loss

    def load_state_dict(self, state_dict) -> None:
        super().load_state_dict(state_dict)
        self._views = None  # new state tensors

    def seed_tensors(self) -> list[tuple[torch.Tensor, int]]:
        """Every tensor whose slices are a seed's own (the parameters, both moments, the step counts), each with its
        seed dimension: what a step's restore of the seeds that sat it out reads."""
        out = []
        for p, d in zip(self.param_groups[0]["params"], self.seed_dims):
            s = self.state[p]
            out += [(p, d), (s["exp_avg"], d), (s["exp_avg_sq"], d), (s["step"], 0)]
        return out


def seed_adam(module: nn.Module, params, lr: float) -> SeedAdam:
    """A :class:`SeedAdam` over ``params``, stacked tensors of the seed-batched ``module`` (their seed dimensions
    read from it)."""
    params = [p for p in params if p.requires_grad]
    return SeedAdam(params, seed_dims_of(module, params), lr)
