"""``CapturedPolicy``: an acting policy run as the graph of torch calls it makes, without the TensorDict machinery.

On a CPU at a few env rows, an acting call is a handful of small matrix products wrapped in the per-call work of
TensorDict modules: reading and writing keys, sequencing modules, checking specs. TorchDynamo traces the call once
into a graph of the torch calls it makes; its ``eager`` backend runs that graph as it is, the same ops on the same
inputs in the same order, random draws included, so the actions are the module's own, bit for bit (tested), and the
collection's records do not change. The warm graph is then called directly
(:class:`~kddrl_trl.compiling.WarmCompiled`). ``benchmarks/train_throughput.py --acting-calls N`` measures the
acting call both ways (``acting``).
"""

from __future__ import annotations

import contextlib
import types

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs.utils import exploration_type

from ..compiling import WarmCompiled
from .policy import MultiRatePolicy


def _call(name, module: TensorDictModuleBase, tensordict: TensorDictBase) -> TensorDictBase:
    """``module(tensordict)``: what :class:`CapturedPolicy` traces (``name``: the exploration type it acts under)."""
    return module(tensordict)


class CapturedPolicy(TensorDictModuleBase):
    """``module`` (a TensorDict module acting on env TensorDicts: a policy or a part of one) called through
    TorchDynamo with the ``eager`` backend, its warm graphs called directly (module docstring).

    Calls are told apart by the exploration type (exploration modules act only under ``ExplorationType.RANDOM``)
    and the input's keys, shapes and dtypes; the row count is traced as a dynamic size (one graph for any count
    above one). The tensors the module reads (its parameters, ε, σ) are read at every call, so their in-place
    updates (the optimiser's, the exploration schedules', :meth:`~kddrl_trl.collectors.PolicySnapshot.sync`) act
    at once; what must not change between calls is the module's structure and its Python attributes. Each instance
    traces its own copy of the traced function, so that TorchDynamo keeps its graphs apart from other instances'
    (its recompile limit counts per function). Nothing compiled is pickled or copied: a copy traces again.

    The first ``eager_calls`` calls run ``module`` itself (the same actions): tracing costs more than it earns on a
    policy that acts only a few hundred times, as a validation's copy does, and is paid only by one that goes on
    acting, as a collector's does."""

    def __init__(self, module: TensorDictModuleBase, eager_calls: int = 2000):
        super().__init__()
        self.module = module
        self.in_keys, self.out_keys = list(module.in_keys), list(module.out_keys)
        self.eager_calls = int(eager_calls)
        self.__dict__["_warm"], self.__dict__["_calls"] = None, 0

    def _caller(self) -> WarmCompiled:
        fn = types.FunctionType(_call.__code__.replace(), _call.__globals__, _call.__name__)  # a code of its own
        compiled = torch.compile(fn, backend="eager", dynamic=True)
        self.__dict__["_warm"] = WarmCompiled(compiled, context=contextlib.nullcontext)
        return self._warm

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self._warm is None:
            if self._calls < self.eager_calls:
                self.__dict__["_calls"] += 1
                return self.module(tensordict)
            self._caller()
        return self._warm(exploration_type(), self.module, tensordict)

    def __getstate__(self) -> dict:
        return {**super().__getstate__(), "_warm": None, "_calls": 0}


def capture(policy: TensorDictModuleBase, eager_calls: int = 2000) -> TensorDictModuleBase:
    """``policy`` acting through :class:`CapturedPolicy` (after ``eager_calls`` calls of its own): a
    :class:`MultiRatePolicy` 's parts each (its choice of the deciding rows stays in Python), any other policy
    whole."""
    if isinstance(policy, MultiRatePolicy):
        return policy.with_parts(lambda part: CapturedPolicy(part, eager_calls))
    return CapturedPolicy(policy, eager_calls)
