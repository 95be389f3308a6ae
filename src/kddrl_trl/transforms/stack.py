"""``PredictiveStack``: a chain of predictive-state transforms run as ONE function per frame (Algorithm 1
lines 15-20).

The KDDRL stack is four small transforms (IDM prior -> trajGAN -> MOBIL -> lcGAN). Called one after the other
through TorchRL, every frame pays four rounds of TensorDict reads and writes, four module calls and, when
compiled, four entries into compiled code (each with its guard checks) — on a CPU, beside SUMO, that per-call
overhead is most of the stack's cost. Every :class:`PredictiveTransform` keeps its maths in a pure
:meth:`~PredictiveTransform.frame` function, so this ``Compose`` reads the raw keys once, draws each member's
noise from that member's own generator (the same draws, in the same order, as the members called one by one),
runs all members' ``frame`` in one function and writes the outputs once. With ``compile``, that function
goes through ``torch.compile`` and — for the calls of an environment (step and reset: one fixed batch
shape) — through an AOTInductor package cached on disk (``aot.py``), which skips the per-call guards and
Python wrappers of ``torch.compile``. The results equal those of the members applied in sequence (tested:
exactly in eager mode, to float rounding when compiled).

It is still a ``Compose``: indexing, ``reseed`` of a member, the specs and ``TransformedEnv`` behave as for
the members chained; a stack holding any transform that is not a :class:`PredictiveTransform` (e.g. one
appended by a user) runs them one by one, as ``Compose`` does.
"""
from __future__ import annotations

import logging

import torch
from tensordict import TensorDictBase
from torchrl.envs.transforms import Compose, Transform

from ..compiling import maybe_compile, resolve_compile
from ._base import PredictiveTransform, call_on_root_and_next
from .aot import AOTFrames

log = logging.getLogger(__name__)


class PredictiveStack(Compose):
    """``Compose`` of :class:`PredictiveTransform` s evaluated as one fused function per frame.

    Args:
        *transforms: the members, in order (each may read what the earlier ones write).
        compile: ``torch.compile`` the fused function (``True`` / ``False`` / ``"auto"``); only when every
            member is ``pure`` (a member wrapping a user's TensorDict module is run eagerly).
        aot: run the environment's calls (``_step`` / ``_reset``) through an AOTInductor package of the fused
            function for their input signature, compiled once (~20-40 s) and cached under
            ``$KDDRL_TRL_CACHE/aot``; default: the same as ``compile``. Replay-buffer calls (``forward``), any
            device but the CPU and a failed AOT compilation (logged) use the ``compile`` path.

    Examples:
        >>> from torchrl.envs import TransformedEnv
        >>> from kddrl_trl.envs import FakeHighwayEnv
        >>> from kddrl_trl.transforms import IDMPrior, MOBILPrior
        >>> env = TransformedEnv(FakeHighwayEnv(num_roads=2), PredictiveStack(IDMPrior(), MOBILPrior()))
        >>> sorted(env.reset()["prior"].keys())
        ['p_mobil']
    """

    def __init__(self, *transforms: Transform, compile: bool | str = False, aot: bool | None = None):
        super().__init__(*transforms)
        self.compile = resolve_compile(compile)
        self._fused = maybe_compile(self._frames, self.compile and self._all_pure(transforms))
        #: env calls (step / reset) through an AOTInductor package for the env's batch shape (see ``aot.py``)
        self.aot = self.compile if aot is None else bool(aot)
        self._aot: dict = {}  # input signature -> AOTFrames (or None where AOT compilation failed)

    # ------------------------------------------------------------------------------------------ fusion
    def _members(self) -> list[PredictiveTransform] | None:
        """The members, when all of them can be fused (else None: run them one by one)."""
        members = list(self.transforms)
        return members if all(isinstance(t, PredictiveTransform) for t in members) else None

    @staticmethod
    def _all_pure(transforms) -> bool:
        return all(getattr(t, "pure", False) for t in transforms)

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

    def _run(self, next_tensordict: TensorDictBase, env_call: bool) -> TensorDictBase:
        members = self._members()
        if members is None:
            return super()._call(next_tensordict)
        values = {k: next_tensordict.get(k, None) for k in self._raw_keys(members)}
        if any(v is None for v in values.values()):  # let the members name what is missing (or tolerate it)
            return super()._call(next_tensordict)
        noises = [t.noise(next_tensordict.batch_size) for t in members]
        with torch.no_grad():
            run = self._aot_frames(members, values, noises) if env_call else None
            out = run(values, noises) if run is not None else self._fused(members, values, noises)
        for key, value in out.items():
            next_tensordict.set(key, value)
        return next_tensordict

    def _aot_frames(self, members, values, noises):
        """The AOT package for this input signature (compiled or loaded on first sight), or None (not asked
        for, a member that is not pure, not on the CPU, or its compilation failed: the other path runs)."""
        if not self.aot or not all(t.pure for t in members):
            return None
        sig = (tuple(id(t) for t in members),
               *((k, v.shape, v.dtype, v.device) for k, v in values.items()),
               *((None if z is None else (z.shape, z.dtype, z.device)) for z in noises))
        if sig not in self._aot:
            self._aot[sig] = None
            if all(t.device.type == "cpu" for t in (*values.values(), *(p for m in members for p in m.parameters()))):
                try:
                    self._aot[sig] = AOTFrames(self._frames, members, values, noises)
                except Exception as err:  # noqa: BLE001 - any export / compiler failure: keep the compiled path
                    log.warning("AOT compilation of the predictive-state stack failed (%s: %s); using "
                                "torch.compile for these inputs", type(err).__name__, err)
        return self._aot[sig]

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self._run(next_tensordict, env_call=False)

    # ------------------------------------------------------------------------------------ TorchRL hooks
    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self._run(next_tensordict, env_call=True)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._run(tensordict_reset, env_call=True)

    def __getstate__(self):  # compiled functions and loaded packages do not pickle: rebuilt / reloaded (cache)
        return {**{k: v for k, v in super().__getstate__().items() if k != "_fused"}, "_aot": {}}

    def __setstate__(self, state):
        super().__setstate__(state)
        self._fused = maybe_compile(self._frames, self.compile and self._all_pure(self.transforms))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Replay-buffer use, as :meth:`PredictiveTransform.forward`: the root and, when it holds the raw keys,
        ``"next"``."""
        members = self._members()
        if members is None:
            return super().forward(tensordict)
        return call_on_root_and_next(self._call, tensordict, self._raw_keys(members))
