"""A frozen generative predictor (a TensorDict module) inside a transform, without gradients: the one setup of
:class:`~kddrl_trl.transforms.TrajGANPrediction` and :class:`~kddrl_trl.transforms.LCGANPrior`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import Tensor

from .. import keys as K
from .predictive import PredictiveTransform


def freeze(module: TensorDictModuleBase) -> TensorDictModuleBase:
    """Put ``module`` in eval mode with every parameter ``requires_grad=False`` (frozen during RL)."""
    module.eval()
    for p in module.parameters():
        p.requires_grad_(False)
    return module


def module_device(module: torch.nn.Module) -> torch.device | None:
    """Device of the module's first parameter / buffer (None for a module without any); looked up once and
    remembered (frozen modules do not move), since walking the module tree costs more than a small GAN call."""
    cached = getattr(module, "_kddrl_device", False)
    if cached is not False:
        return cached
    dev = next((t.device for t in (*module.parameters(), *module.buffers())), None)
    module._kddrl_device = dev
    return dev


def run_frozen(module: TensorDictModuleBase, tensordict: TensorDictBase, out_key: NestedKey) -> Tensor:
    """``module(td.select(*module.in_keys))[out_key]`` under ``no_grad``, moved to and from the module device.

    One call for the whole batch (any batch shape). The caller's tensordict is not modified."""
    src_device = tensordict.get(module.in_keys[0]).device if module.in_keys else None
    sub = tensordict.select(*module.in_keys)
    dev = module_device(module)
    moved = dev is not None and src_device is not None and dev != src_device
    if moved:
        sub = sub.to(dev)
    with torch.no_grad():
        out = module(sub).get(out_key)
    return out.to(src_device) if moved else out


def as_tensordict(values, batch_size) -> TensorDictBase:
    """A TensorDict of ``batch_size`` holding ``values`` (``{nested key: tensor}``), for a user's module."""
    td = TensorDict(batch_size=batch_size)
    for key, value in values.items():
        td.set(key, value)
    return td


class FrozenPredictorTransform(PredictiveTransform):
    """Base of the transforms around a frozen generative predictor (trajGAN Eq. 13, lcGAN Eq. 16).

    * The predictor: a user's TensorDict module writing :attr:`out_key` (``predictor``), or the shipped
      predictor of :attr:`kind` loaded from ``checkpoint`` (default: the weights shipped with the package) with
      ``seed`` and ``options``, on ``device``; exclusive. Frozen (eval mode, ``requires_grad=False``).
    * ``pure`` when it is the shipped predictor class: its ``predict(*inputs, z)`` is plain tensor maths that the
      fused stack compiles; a user's module is run as a TensorDict module (:func:`run_frozen`).
    * Noise: :attr:`rows_per_env` rows per environment and call from the predictor's own ``torch.Generator``
      (``predictor.generator``), drawn outside :meth:`frame` (a user's module draws its own). A stream over
      calls, untouched by resets; :meth:`reseed` restarts it.

    Subclasses set :attr:`kind`, :attr:`out_key`, :attr:`rows_per_env` and implement :meth:`predict_inputs`
    and :meth:`frame` (around :meth:`prediction`). Keys read: the predictor's in-keys, ``EGO_STATE`` (the batch
    shape of a user's module call) and the subclass's ``in_keys``.
    """

    #: the shipped predictor's name in :data:`kddrl_trl.generative.PREDICTORS`
    kind: str
    #: the key the predictor writes
    out_key: NestedKey
    #: noise rows per environment of one call
    rows_per_env: int = 1

    def __init__(
        self,
        predictor: TensorDictModuleBase | None,
        *,
        checkpoint: str | Path | None,
        seed: int,
        device: str | torch.device,
        options: Mapping[str, Any],
        in_keys: Sequence[NestedKey],
        out_keys: Sequence[NestedKey],
    ):
        if predictor is not None and checkpoint is not None:
            raise ValueError(f"{type(self).__name__}: give either a predictor module or a checkpoint path, not both")
        from ..generative import PREDICTORS, load_predictor

        if predictor is None:
            predictor = load_predictor(self.kind, checkpoint, seed=int(seed), device=device, **options)
        if self.out_key not in [tuple(k) if isinstance(k, (tuple, list)) else k for k in predictor.out_keys]:
            raise ValueError(f"the {self.kind} predictor must write {self.out_key}, it writes {predictor.out_keys}")
        self.seed = int(getattr(predictor, "seed", seed))
        super().__init__(
            in_keys=list(dict.fromkeys([*predictor.in_keys, K.EGO_STATE, *in_keys])),
            out_keys=out_keys,
            pure=isinstance(predictor, PREDICTORS[self.kind]),
        )
        self.predictor = freeze(predictor)

    def reseed(self, seed: int | None = None) -> None:
        """Restart the predictor's noise stream (with ``seed``, or the constructor's)."""
        seed = self.seed if seed is None else int(seed)
        if hasattr(self.predictor, "reset"):
            self.predictor.reset(seed)
        elif isinstance(getattr(self.predictor, "generator", None), torch.Generator):
            self.predictor.generator.manual_seed(seed)

    def noise(self, batch: torch.Size) -> Tensor | None:
        """The shipped predictor's noise for ``batch`` x :attr:`rows_per_env` rows (a user's module draws its own)."""
        return self.predictor.noise(batch.numel() * self.rows_per_env) if self.pure else None

    def predict_inputs(self, values: Mapping[NestedKey, Tensor]) -> tuple[Tensor, ...]:  # pragma: no cover
        """The arguments of the shipped predictor's ``predict`` before the noise, from ``values``."""
        raise NotImplementedError

    def prediction(self, values: Mapping[NestedKey, Tensor], noise: Tensor | None) -> Tensor:
        """:attr:`out_key` of one frame: the shipped predictor's pure ``predict``, or a user's module on ``values``."""
        if self.pure:
            return self.predictor.predict(*self.predict_inputs(values), noise)
        return run_frozen(self.predictor, as_tensordict(values, values[K.EGO_STATE].shape[:-1]), self.out_key)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(predictor={type(self.predictor).__name__})"
