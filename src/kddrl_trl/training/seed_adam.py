"""``SeedAdam``: Adam over the seed-stacked parameters of N learners in one (:mod:`kddrl_trl.modules.seed_batch`),
each seed with its own step count.

Adam is elementwise but for its bias corrections, which read the number of steps taken. Seeds of a batch take
different numbers of steps (a seed's lane-change agent learns once per decision of its own, a seed that has
finished its episodes learns no more), so a single step count per tensor, as ``torch.optim.Adam`` keeps, would
bias-correct a seed with another's count. Here each parameter's ``state["step"]`` is ``[N]``, and the bias
corrections are ``[N]`` tensors broadcast along each stacked tensor's seed dimension, in one ``torch._foreach_*``
call per operation over all the parameters (stepping the N slices one by one would cost N times the calls). Which seeds step is the learner's business (:meth:`~kddrl_trl.training.learner.Learner._run`
restores the seeds that sat a step out).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

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
                "step": torch.zeros(self.seeds, device=p.device),
                "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format),
                "exp_avg_sq": torch.zeros_like(p, memory_format=torch.preserve_format),
            }
        self._views = self._seed_shaped()  # here, not in a step: a compiled step must not set attributes

    def _seed_shaped(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per parameter, views of two ``[N]`` tensors (the step size and the bias correction of the second moment,
        per seed) shaped to broadcast along its seed dimension; taken once, the ``[N]`` tensors written each step from
        the step counts (so a loaded state needs no new views)."""
        device = self.param_groups[0]["params"][0].device
        self._step_size, self._bc2_sqrt = torch.zeros(self.seeds, device=device), torch.ones(self.seeds, device=device)
        views = []
        for p, d in zip(self.param_groups[0]["params"], self.seed_dims):
            shape = [self.seeds if i == d else 1 for i in range(p.dim())]
            views.append((self._step_size.view(shape), self._bc2_sqrt.view(shape)))
        return views

    @torch.no_grad()
    def step(self, closure=None):
        """``torch.optim.Adam`` 's step (its single-tensor arithmetic, in the same order), the bias corrections
        per seed: ``m <- lerp(m, g, 1 - β1)``, ``v <- β2 v + (1 - β2) g²``, ``p <- p - lr / (1 - β1^t) ·
        m / (sqrt(v) / sqrt(1 - β2^t) + eps)`` with ``t`` the seed's own step count."""
        loss = closure() if closure is not None else None
        group = self.param_groups[0]
        beta1, beta2 = group["betas"]
        params, grads, m, v, sizes, bc2 = [], [], [], [], [], []
        for p, views in zip(group["params"], self._views):
            if p.grad is None:
                continue
            s = self.state[p]
            params.append(p)
            grads.append(p.grad)
            m.append(s["exp_avg"])
            v.append(s["exp_avg_sq"])
            sizes.append(views[0])
            bc2.append(views[1])
            s["step"].add_(1)
        if not params:
            return loss
        step = self.state[params[0]]["step"]  # the step counts of a step's parameters move together
        self._step_size.copy_(group["lr"] / (1 - beta1**step))
        self._bc2_sqrt.copy_((1 - beta2**step).sqrt())
        torch._foreach_lerp_(m, grads, 1 - beta1)
        torch._foreach_mul_(v, beta2)
        torch._foreach_addcmul_(v, grads, grads, value=1 - beta2)
        denom = torch._foreach_sqrt(v)
        torch._foreach_div_(denom, bc2)
        torch._foreach_add_(denom, group["eps"])
        update = torch._foreach_div(m, denom)
        torch._foreach_mul_(update, sizes)
        torch._foreach_sub_(params, update)
        return loss

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
