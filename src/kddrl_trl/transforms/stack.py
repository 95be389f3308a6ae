"""``PredictiveStack``: a chain of predictive-state transforms run as ONE function per frame (Algorithm 1
lines 15-20).

The KDDRL stack is four small transforms (IDM prior -> trajGAN -> MOBIL -> lcGAN). Called one after the other
through TorchRL, every frame pays four rounds of TensorDict reads and writes, four module calls and, when
compiled, four entries into compiled code (each with its guard checks) — on a CPU, beside SUMO, that per-call
overhead is most of the stack's cost. Every :class:`PredictiveTransform` keeps its maths in a pure
:meth:`~PredictiveTransform.frame` function, so this ``Compose`` reads the raw keys once, draws each member's
noise from that member's own generator (the same draws, in the same order, as the members called one by one),
runs all members' ``frame`` in one function (``torch.compile``-d as a whole when asked) and writes the
outputs once. The results equal those of the members applied in sequence (tested, eager and compiled).

It is still a ``Compose``: indexing, ``reseed`` of a member, the specs and ``TransformedEnv`` behave as for
the members chained; a stack holding any transform that is not a :class:`PredictiveTransform` (e.g. one
appended by a user) runs them one by one, as ``Compose`` does.
"""
from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.envs.transforms import Compose, Transform

from ..compiling import maybe_compile, resolve_compile
from ._base import PredictiveTransform


class PredictiveStack(Compose):
    """``Compose`` of :class:`PredictiveTransform` s evaluated as one fused function per frame.

    Args:
        *transforms: the members, in order (each may read what the earlier ones write).
        compile: ``torch.compile`` the fused function (``True`` / ``False`` / ``"auto"``); only when every
            member is ``pure`` (a member wrapping a user's TensorDict module is run eagerly).

    Examples:
        >>> from torchrl.envs import TransformedEnv
        >>> from kddrl_trl.envs import FakeHighwayEnv
        >>> from kddrl_trl.transforms import IDMPrior, MOBILPrior
        >>> env = TransformedEnv(FakeHighwayEnv(num_roads=2), PredictiveStack(IDMPrior(), MOBILPrior()))
        >>> sorted(env.reset()["prior"].keys())
        ['p_mobil']
    """

    def __init__(self, *transforms: Transform, compile: bool | str = False):
        super().__init__(*transforms)
        self.compile = resolve_compile(compile)
        self._fused = maybe_compile(self._frames, self.compile and all(getattr(t, "pure", False) for t in transforms))

    # ------------------------------------------------------------------------------------------ fusion
    def _members(self) -> list[PredictiveTransform] | None:
        """The members, when all of them can be fused (else None: run them one by one)."""
        members = list(self.transforms)
        return members if all(isinstance(t, PredictiveTransform) for t in members) else None

    @staticmethod
    def _raw_keys(members) -> list:
        """The keys the stack reads: the members' in-keys that no earlier member writes."""
        written, reads = set(), []
        for t in members:
            reads += [k for k in t.in_keys if k not in written and k not in reads]
            written.update(t.out_keys)
        return reads

    def _frames(self, members, values: dict, noises: list) -> dict:
        """Every member's ``frame`` in order on one dict of tensors; returns what they write."""
        values, out = dict(values), {}
        for t, z in zip(members, noises):
            new = t.frame(values, z)
            values.update(new)
            out.update(new)
        return out

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        members = self._members()
        if members is None:
            return super()._call(next_tensordict)
        values = {k: next_tensordict.get(k, None) for k in self._raw_keys(members)}
        if any(v is None for v in values.values()):  # let the members name what is missing (or tolerate it)
            return super()._call(next_tensordict)
        noises = [t.noise(next_tensordict.batch_size) for t in members]
        with torch.no_grad():
            out = self._fused(members, values, noises)
        for key, value in out.items():
            next_tensordict.set(key, value)
        return next_tensordict

    # ------------------------------------------------------------------------------------ TorchRL hooks
    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self._call(next_tensordict)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict_reset)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Replay-buffer use, as :meth:`PredictiveTransform.forward`: the root and, when it holds the raw keys,
        ``"next"``."""
        if self._members() is None:
            return super().forward(tensordict)
        self._call(tensordict)
        nxt = tensordict.get("next", None)
        if isinstance(nxt, TensorDictBase):
            keys = nxt.keys(include_nested=True)
            if all(k in keys for k in self._raw_keys(self._members())):
                self._call(nxt)
        return tensordict
