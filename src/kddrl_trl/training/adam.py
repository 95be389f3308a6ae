"""``FusedAdam``: ``torch.optim.Adam(fused=True)`` whose step, on the CPU, is the fused kernel and nothing more.

The learners step up to three optimisers per gradient step on minibatches of a hundred-odd rows, where
``Optimizer.step`` 's bookkeeping (the profiler hook, the step hooks, ``_init_group`` 's loop over the parameters,
grouping the tensors by device and dtype) costs about half as much again as the fused kernel it wraps. Once every
parameter has its state (after the first step), :meth:`FusedAdam.step` calls what ``torch.optim.adam._fused_adam``
calls for a single device and dtype, on the same tensors in the same order: ``torch._foreach_add_`` on the step
counters, then ``torch._fused_adam_``. The arithmetic, the state and ``state_dict()`` are ``torch.optim.Adam`` 's;
only the Python around them is gone. Anything outside that one case (a ``capturable`` group, as CUDA graphs need,
which :func:`~kddrl_trl.training.base.adam` leaves to ``torch.optim.Adam``; several parameter groups, devices or
dtypes; a parameter without a gradient; ``amsgrad``; a closure; a step traced by ``torch.compile``) takes
``torch.optim.Adam.step`` itself. Step hooks run once either way (``torch.optim`` wraps every optimiser class's
``step`` in the function that calls them).
"""

from __future__ import annotations

import torch


class FusedAdam(torch.optim.Adam):
    """``torch.optim.Adam(params, lr, fused=True)`` with a lean CPU step (module docstring)."""

    def __init__(self, params, lr: float):
        super().__init__(params, lr=lr, fused=True)
        self._tensors = None  # (params, exp_avgs, exp_avg_sqs, steps) once the lean step applies

    def _lean_tensors(self):
        """The single group's parameters and their state tensors, or None where the lean step does not apply."""
        if len(self.param_groups) != 1:
            return None
        group = self.param_groups[0]
        params = group["params"]
        if group["capturable"] or group["amsgrad"] or group["decoupled_weight_decay"] or not params:
            return None
        if len({(p.device, p.dtype) for p in params}) != 1 or params[0].device.type != "cpu":
            return None
        states = [self.state.get(p) for p in params]
        if any(not s for s in states):
            return None
        return params, [s["exp_avg"] for s in states], [s["exp_avg_sq"] for s in states], [s["step"] for s in states]

    def step(self, closure=None):
        if closure is not None or self._tensors is None or torch.compiler.is_compiling():
            loss = _adam_step(self, closure)
            self._tensors = self._lean_tensors()
            return loss
        params, exp_avgs, exp_avg_sqs, steps = self._tensors
        grads = [p.grad for p in params]
        if any(g is None for g in grads):
            return _adam_step(self)
        group = self.param_groups[0]
        beta1, beta2 = group["betas"]
        with torch.no_grad():
            torch._foreach_add_(steps, 1)
            torch._fused_adam_(
                params,
                grads,
                exp_avgs,
                exp_avg_sqs,
                [],
                steps,
                amsgrad=False,
                lr=group["lr"],
                beta1=beta1,
                beta2=beta2,
                weight_decay=group["weight_decay"],
                eps=group["eps"],
                maximize=group["maximize"],
                grad_scale=None,
                found_inf=None,
            )
        return None

    def load_state_dict(self, state_dict) -> None:
        super().load_state_dict(state_dict)
        self._tensors = None  # new state tensors: taken again after the next step

    def add_param_group(self, param_group) -> None:
        super().add_param_group(param_group)
        self._tensors = None


def _adam_step(opt: torch.optim.Adam, closure=None):
    """``torch.optim.Adam.step`` without the hook-calling wrapper ``torch.optim`` may have put around it (the
    wrapper around :meth:`FusedAdam.step` has called the hooks already)."""
    step = torch.optim.Adam.step
    return getattr(step, "__wrapped__", step)(opt, closure)
