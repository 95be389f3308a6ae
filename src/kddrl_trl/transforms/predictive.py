"""Shared machinery of the predictive-state transforms (paper §III.B-C, Algorithm 1 lines 15-20).

Every transform of this package is *stateless per frame*: its output at a frame depends only on the raw
observation of that frame (plus the keys written by the transforms before it in the stack, and, for the
generative ones, the state of their noise generator). There is no per-environment memory, so a partial
reset of a batched environment needs no bookkeeping: the reset rows are simply recomputed from their new
observation. The same ``_call`` serves

* ``env.reset()`` (``_reset`` calls ``_call`` on the reset tensordict, so the keys exist from frame 0),
* ``env.step()`` (the default ``Transform._step`` calls ``_call`` on ``"next"``),
* a replay-buffer sample (``forward``): any batch shape (``[N]``, ``[N, T]``, ...); the root is transformed
  and, when present and carrying the raw keys, the ``"next"`` sub-tensordict too.

All maths runs under ``torch.no_grad()`` (nothing here is trained by the RL losses).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torch import Tensor
from torchrl.data import Bounded, Composite, TensorSpec, Unbounded
from torchrl.envs.transforms import Transform


def unbounded_spec(batch: torch.Size, shape: Sequence[int], device) -> TensorSpec:
    """float32 spec of positions / gaps (m): ``[*batch, *shape]``."""
    return Unbounded(shape=(*batch, *shape), dtype=torch.float32, device=device)


def probability_spec(batch: torch.Size, shape: Sequence[int], device) -> TensorSpec:
    """float32 spec of probabilities in [0, 1]: ``[*batch, *shape]``."""
    return Bounded(0.0, 1.0, shape=(*batch, *shape), dtype=torch.float32, device=device)


def finite_or_zero(x: Tensor) -> Tensor:
    """``x`` with NaN / ±inf replaced by 0 (the outputs of this package are never NaN)."""
    return torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0)


def as_params(cls, value):
    """An instance of the parameter dataclass ``cls`` from an instance, a mapping of its fields (a Hydra
    config) or None (its defaults: Table A.1)."""
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    return cls(**{str(k): v for k, v in dict(value).items()})


def call_on_root_and_next(call, tensordict: TensorDictBase, in_keys: Sequence[NestedKey]) -> TensorDictBase:
    """``call`` on ``tensordict`` and, when it has a ``"next"`` holding every key of ``in_keys``, on ``"next"``
    too (a replay-buffer sample of transitions, any batch shape)."""
    call(tensordict)
    nxt = tensordict.get("next", None)
    if isinstance(nxt, TensorDictBase):
        keys = nxt.keys(include_nested=True)
        if all(k in keys for k in in_keys):
            call(nxt)
    return tensordict


class PredictiveTransform(Transform):
    """Base of the KDDRL observation transforms: reads ``in_keys``, writes ``out_keys`` of one frame.

    A plain TorchRL transform. Subclasses implement :meth:`frame` (a *pure tensor function*:
    ``{in_key: tensor [*B, ...]}`` and the call's noise -> ``{out_key: tensor [*B, ...]}``, batched over any
    leading batch shape), optionally :meth:`noise` (drawn from the transform's own generator, outside
    ``frame``), and :meth:`out_specs` (``{out_key: spec}`` for a given batch shape / device). Keeping the maths
    pure is what lets :class:`~kddrl_trl.transforms.PredictiveStack` run a whole stack as ONE function per frame
    (the one place where it is compiled). This class wires them into TorchRL: ``_call`` (step), ``_reset``
    (reset), ``forward`` (replay buffer) and ``transform_observation_spec`` (every added key declared with shape
    and dtype).

    Args:
        in_keys, out_keys: the keys read / written.
        pure: see the attribute.
    """

    def __init__(self, in_keys: Sequence[NestedKey], out_keys: Sequence[NestedKey], pure: bool = True):
        super().__init__(in_keys=list(in_keys), out_keys=list(out_keys))
        #: whether :meth:`frame` is plain tensor maths that ``torch.compile`` can fuse with its neighbours (False
        #: for a transform wrapping a user's TensorDict module: never compiled)
        self.pure = bool(pure)

    # ----------------------------------------------------------------------------- to implement
    def frame(
        self, values: Mapping[NestedKey, Tensor], noise: Tensor | None
    ) -> dict[NestedKey, Tensor]:  # pragma: no cover
        """The outputs of one frame from ``values`` (holding at least ``in_keys``); no side effects."""
        raise NotImplementedError

    def noise(self, batch: torch.Size) -> Tensor | None:
        """The random input of one call on ``batch`` (None: deterministic transform)."""
        return None

    def out_specs(self, batch: torch.Size, device) -> dict[NestedKey, TensorSpec]:  # pragma: no cover
        raise NotImplementedError

    def compute(self, tensordict: TensorDictBase) -> dict[NestedKey, Tensor]:
        """:meth:`frame` on the ``in_keys`` of ``tensordict``."""
        values = {key: tensordict.get(key) for key in self.in_keys}
        return self.frame(values, self.noise(tensordict.batch_size))

    # --------------------------------------------------------------------------------- TorchRL
    def _has_inputs(self, tensordict: TensorDictBase) -> bool:
        keys = tensordict.keys(include_nested=True)
        missing = [k for k in self.in_keys if k not in keys]
        if missing and not self.missing_tolerance:
            raise KeyError(
                f"{type(self).__name__}: keys {missing} not found in the tensordict; they are raw "
                "keys of the environment (kddrl_trl.keys) or written by an earlier transform of the "
                "stack (see make_kddrl_transforms for the order)"
            )
        return not missing

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        if not self._has_inputs(next_tensordict):
            return next_tensordict
        with torch.no_grad():
            out = self.compute(next_tensordict)
        for key, value in out.items():
            next_tensordict.set(key, value)
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        # stateless per frame: a (partial) reset only needs the keys computed on the new observation
        return self._call(tensordict_reset)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Replay-buffer use: transform the root and, if it holds the raw keys, ``"next"`` (any batch shape)."""
        return call_on_root_and_next(self._call, tensordict, self.in_keys)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        batch, device = observation_spec.shape, observation_spec.device
        for key, spec in self.out_specs(batch, device).items():
            observation_spec[key] = spec  # Composite creates the missing parent ("pred", "prior")
        return observation_spec
