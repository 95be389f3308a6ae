"""``FusedAdam``: ``torch.optim.Adam(fused=True)`` whose step, on the CPU, is the fused kernel and nothing more.

The learners step up to three optimisers per gradient step on minibatches of a hundred-odd rows, where
``Optimizer.step`` 's bookkeeping (the profiler hook, the step hooks, ``_init_group`` 's loop over the parameters,
grouping the tensors by device and dtype, one step-counter increment per parameter) costs about as much as the
fused kernel it wraps. Once every parameter has its state (after the first step), the lean step does what
``torch.optim.adam._fused_adam`` does for a single device and dtype, on the same tensors in the same order: it
adds one to the step counters, then calls ``torch._fused_adam_``. The counters are views of one tensor of the
optimiser's own (:meth:`FusedAdam._lean_tensors`), so one ``add_`` counts them all; each is still its parameter's
``state["step"]``, saved and loaded as ``torch.optim.Adam`` 's. The arithmetic, the state and ``state_dict()`` are
``torch.optim.Adam`` 's; only the Python around them is gone.

:func:`step_all` steps a gradient step's optimisers together: where each can take the lean step and nothing
watches its steps (no step hooks of its own or global ones, no ``step`` patched on the instance, as an LR
scheduler patches it), the optimisers sharing their hyperparameters share one ``torch._fused_adam_`` call. The
kernel steps each tensor on its own (its own step counter, its own chunks), so one call over two optimisers'
tensors gives the bits of two calls. Anything outside the lean case (a ``capturable`` group, as CUDA graphs need,
which :func:`~kddrl_trl.training.learner.adam` leaves to ``torch.optim.Adam``; several parameter groups, devices or
dtypes; a parameter without a gradient; ``amsgrad``; a closure; a step traced by ``torch.compile``) takes
``torch.optim.Adam.step`` itself. Step hooks run once either way (``torch.optim`` wraps every optimiser class's
``step`` in the function that calls them).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch.optim import optimizer as _optim


class FusedAdam(torch.optim.Adam):
    """``torch.optim.Adam(params, lr, fused=True)`` with a lean CPU step (module docstring)."""

    def __init__(self, params, lr: float):
        super().__init__(params, lr=lr, fused=True)
        self._tensors = None  # (params, exp_avgs, exp_avg_sqs, steps, the steps' own tensor) once the lean step applies

    def _lean_tensors(self):
        """The single group's parameters and their state tensors, or None where the lean step does not apply. The
        step counters become views of one new tensor holding their values (the same values, dtype and device)."""
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
        counters = [s["step"] for s in states]
        if any(c.dim() != 0 or c.dtype != counters[0].dtype or c.device != counters[0].device for c in counters):
            return None
        flat = torch.stack(counters)
        for i, s in enumerate(states):
            s["step"] = flat[i]
        steps = [s["step"] for s in states]
        return params, [s["exp_avg"] for s in states], [s["exp_avg_sq"] for s in states], steps, flat

    def _hyperparameters(self) -> tuple:
        """What ``torch._fused_adam_`` takes besides the tensors: optimisers with equal ones may share a call."""
        group = self.param_groups[0]
        beta1, beta2 = group["betas"]
        return group["lr"], beta1, beta2, group["weight_decay"], group["eps"], group["maximize"]

    def _lean_grads(self) -> list | None:
        """The gradients of the lean step, or None where the lean step does not apply now."""
        if self._tensors is None or torch.compiler.is_compiling():
            return None
        grads = [p.grad for p in self._tensors[0]]
        return None if any(g is None for g in grads) else grads

    def _unwatched(self) -> bool:
        """No step hooks (its own or global) and no ``step`` patched on the instance: nothing :func:`step_all`
        would skip by not calling ``step``."""
        return not (
            self._optimizer_step_pre_hooks
            or self._optimizer_step_post_hooks
            or _optim._global_optimizer_pre_hooks
            or _optim._global_optimizer_post_hooks
            or "step" in self.__dict__
        )

    def step(self, closure=None):
        grads = None if closure is not None else self._lean_grads()
        if grads is None:
            loss = _adam_step(self, closure)
            if self._tensors is None and not torch.compiler.is_compiling():  # taken once, outside a traced step
                self._tensors = self._lean_tensors()
            return loss
        _fused_steps([(self, grads)])
        return None

    def load_state_dict(self, state_dict) -> None:
        super().load_state_dict(state_dict)
        self._tensors = None  # new state tensors: taken again after the next step

    def add_param_group(self, param_group) -> None:
        super().add_param_group(param_group)
        self._tensors = None


def step_all(optimizers: Sequence[torch.optim.Optimizer]) -> None:
    """``o.step()`` for each optimiser (disjoint parameters, so the order does not matter). The :class:`FusedAdam`
    ones that can take the lean step now and whose steps nothing watches take it together (module docstring); the
    others step on their own."""
    lean = []
    for o in optimizers:
        grads = o._lean_grads() if isinstance(o, FusedAdam) and o._unwatched() else None
        if grads is None:
            o.step()  # its own step (another kind of optimiser, or one that cannot take the lean step now)
        else:
            lean.append((o, grads))
    if lean:
        _fused_steps(lean)


def _fused_steps(lean: list) -> None:
    """The lean step of each ``(FusedAdam, its gradients)``: every optimiser's counters plus one, then one
    ``torch._fused_adam_`` call per set of hyperparameters, over the tensors of the optimisers that share it.
    Traced by TorchDynamo (a frame of a compiled update function's eager remainder after a graph break), each takes
    ``torch.optim.Adam``'s step instead, as :meth:`FusedAdam.step` does."""
    if torch.compiler.is_compiling():
        for opt, _ in lean:
            _adam_step(opt)
        return
    calls: dict[tuple, list] = {}
    with torch.no_grad():
        for opt, grads in lean:
            params, exp_avgs, exp_avg_sqs, steps, flat = opt._tensors
            flat.add_(1)
            lists = calls.setdefault(opt._hyperparameters(), [[], [], [], [], []])  # params, grads, m, v, steps
            for into, tensors in zip(lists, (params, grads, exp_avgs, exp_avg_sqs, steps)):
                into += tensors
        for (lr, beta1, beta2, weight_decay, eps, maximize), tensors in calls.items():
            torch._fused_adam_(
                *tensors[:4],
                [],
                tensors[4],
                amsgrad=False,
                lr=lr,
                beta1=beta1,
                beta2=beta2,
                weight_decay=weight_decay,
                eps=eps,
                maximize=maximize,
                grad_scale=None,
                found_inf=None,
            )


def _adam_step(opt: torch.optim.Adam, closure=None):
    """``torch.optim.Adam.step`` without the hook-calling wrapper ``torch.optim`` may have put around it (the
    wrapper around :meth:`FusedAdam.step` has called the hooks already)."""
    step = torch.optim.Adam.step
    return getattr(step, "__wrapped__", step)(opt, closure)
