"""``PredictiveStack``: a chain of predictive-state transforms run as ONE function per frame (Algorithm 1
lines 15-20).

The KDDRL stack is four small transforms (IDM prior -> trajGAN -> MOBIL -> lcGAN). Called one after the other
through TorchRL, every frame pays four rounds of TensorDict reads and writes and four module calls; on a CPU,
beside SUMO, that per-call overhead is a large part of the stack's cost. Every :class:`PredictiveTransform`
keeps its maths in a pure :meth:`~PredictiveTransform.frame` function, so this ``Compose`` reads the raw keys
once, draws each member's noise from that member's own generator (the same draws, in the same order, as the
members called one by one), runs all members' ``frame`` in one function (:func:`run_frames`) and writes the
outputs once. With ``compile``, that function goes through ``torch.compile`` (:func:`compiled_frames`, the
transforms' only compile site), its warm graphs called directly (:func:`warm_frames`). The results equal those of
the members applied in sequence (tested: exactly in eager mode, to float rounding when compiled).

It is still a ``Compose``: indexing, ``reseed`` of a member, the specs and ``TransformedEnv`` behave as for
the members chained; a stack holding any transform that is not a :class:`PredictiveTransform` (e.g. one
appended by a user) runs them one by one, as ``Compose`` does.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from functools import lru_cache

import torch
from tensordict import TensorDictBase
from torchrl.envs.transforms import Compose, Transform

from ..compiling import WarmCompiled, resolved, specializing_floats
from .leader_history import LeaderHistory
from .predictive import PredictiveTransform, call_on_root_and_next


def run_frames(members: Sequence[PredictiveTransform], values: dict, noises: list) -> dict:
    """Every member's ``frame`` in order on one dict of tensors (each sees what the earlier ones wrote);
    returns what they write."""
    values, out = dict(values), {}
    for t, z in zip(members, noises):
        new = t.frame(values, z)
        values.update(new)
        out.update(new)
    return out


@lru_cache(maxsize=1)
def compiled_frames():
    """:func:`run_frames` through ``torch.compile`` (dynamic shapes: any batch shape without recompiling):
    the one compile site of the transforms, built once per process on first use (nothing compiled is stored
    on a stack, so stacks pickle as they are). Stacks call it through :func:`warm_frames`.

    Its gain (collection ego-frames/s with the full KDDRL stack, compiled vs eager) is measured by
    ``python -m benchmarks.transform_overhead`` (``benchmarks/results/transform_overhead.json``)."""
    return torch.compile(run_frames, dynamic=True)


#: each stack's :func:`warm_frames`, dropped with the stack
_WARM: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def warm_frames(stack: Compose) -> WarmCompiled:
    """``stack`` 's caller of :func:`compiled_frames`, ``(tuple(members), values, noises) -> dict``: a
    :class:`~kddrl_trl.compiling.WarmCompiled`, so that once a call signature is warm its graph runs without
    TorchDynamo's guard evaluation, bit for bit the graph TorchDynamo would run. The members are part of the
    signature (by identity, and kept alive by it): the graph holds their float constants, traced as constants under
    :func:`~kddrl_trl.compiling.specializing_floats` (one trace, not two), which its compiling calls enter. One per
    stack, so that what it keeps goes with the stack."""
    warm = _WARM.get(stack)
    if warm is None:
        warm = _WARM[stack] = WarmCompiled(compiled_frames(), context=specializing_floats)
    return warm


class PredictiveStack(Compose):
    """``Compose`` of :class:`PredictiveTransform` s evaluated as one fused function per frame.

    Args:
        *transforms: the members, in order (each may read what the earlier ones write).
        history: a :class:`LeaderHistory` run before the members (``make_kddrl_transforms`` adds one in front of
            trajGAN): it builds ``("leaders","history")`` where the env does not write it, and is inert where it does.
        compile: ``torch.compile`` the fused function (a bool: a config's ``auto`` is resolved by
            :func:`kddrl_trl.compiling.resolve_compile`; gain measured in :func:`compiled_frames`); only when
            every member is ``pure`` (a member wrapping a user's TensorDict module is run eagerly).

    Examples:
        >>> from torchrl.envs import TransformedEnv
        >>> from kddrl_trl.envs import FakeHighwayEnv
        >>> from kddrl_trl.transforms import IDMPrior, MOBILPrior
        >>> env = TransformedEnv(FakeHighwayEnv(num_roads=2), PredictiveStack(IDMPrior(), MOBILPrior()))
        >>> sorted(env.reset()["prior"].keys())
        ['p_mobil']
    """

    def __init__(self, *transforms: Transform, history: LeaderHistory | None = None, compile: bool = False):
        super().__init__(*transforms)
        self.compiled = resolved("compile", compile)  # not `.compile`: that hides nn.Module.compile
        #: builds ``("leaders","history")`` before the members where the env does not write it (not a member:
        #: indexing and the fused members are as without it; inert on an env keeping its own history)
        self.history = history

    def _env_observation_spec(self):
        parent = self.parent
        return None if parent is None else parent.full_observation_spec

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

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        if self.history is not None:  # a lone frame without the key: windows can only start (no-op if present)
            next_tensordict = self.history._call(next_tensordict)
        members = self._members()
        if members is None:
            return super()._call(next_tensordict)
        values = {k: next_tensordict.get(k, None) for k in self._raw_keys(members)}
        if any(v is None for v in values.values()):  # let the members name what is missing (or tolerate it)
            return super()._call(next_tensordict)
        noises = [t.noise(next_tensordict.batch_size) for t in members]
        with torch.no_grad():
            if self.compiled and all(t.pure for t in members):
                out = warm_frames(self)(tuple(members), values, noises)
            else:
                out = run_frames(members, values, noises)
        for key, value in out.items():
            next_tensordict.set(key, value)
        return next_tensordict

    # ------------------------------------------------------------------------------------ TorchRL hooks
    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        if self.history is not None:
            next_tensordict = self.history._step(tensordict, next_tensordict)
        return self._call(next_tensordict)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        if self.history is not None:
            tensordict_reset = self.history._reset(tensordict, tensordict_reset)
        return self._call(tensordict_reset)

    def transform_output_spec(self, output_spec):
        if self.history is not None:
            output_spec["full_observation_spec"] = self.history.transform_observation_spec(
                output_spec["full_observation_spec"]
            )
        return super().transform_output_spec(output_spec)

    def transform_input_spec(self, input_spec):
        if self.history is not None:
            self._check_frame_time()
            input_spec = self.history.declare_state(input_spec, self._env_observation_spec())
        return super().transform_input_spec(input_spec)

    def _check_frame_time(self) -> None:
        """Refuses an env whose frames last another time than the leaders' history assumes (``LeaderHistory.dt``;
        trajGAN's key steps, 10 and 20 frames = 1 and 2 s, Eq. 24, were learned at that rate). The env's frame
        time is read from its ``config.step_length`` (kddrl_trl's envs); an env without one is taken on trust."""
        from torchrl.envs import TransformedEnv

        env = self.parent
        while isinstance(env, TransformedEnv):
            env = env.base_env
        # the instance's own attributes only: a batched env forwards unknown names to workers that may not run yet
        step = getattr(vars(env).get("config") if env is not None else None, "step_length", None)
        if step is not None and abs(float(step) - self.history.dt) > 1e-9:
            raise ValueError(
                f"PredictiveStack: the env's frames last {float(step)} s (config.step_length), but the leaders' "
                f"history and trajGAN's key steps assume {self.history.dt} s frames: step the env at "
                f"{self.history.dt} s, or build the stack for your rate (a LeaderHistory(dt=...) and a trajGAN "
                "trained on recordings at that rate)"
            )

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Replay-buffer use, as :meth:`PredictiveTransform.forward`: the root and, when it holds the raw keys,
        ``"next"``."""
        members = self._members()
        if members is None:
            return super().forward(tensordict)
        return call_on_root_and_next(self._call, tensordict, self._raw_keys(members))
