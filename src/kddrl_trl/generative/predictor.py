"""What the RL-time predictors of trajGAN (Eq. 13) and lcGAN (Eq. 16) share: a frozen generator, its noise
stream and how it is rebuilt from a training task or a checkpoint.

The transforms (:class:`~kddrl_trl.transforms.TrajGANPrediction`, :class:`~kddrl_trl.transforms.LCGANPrior`)
code against this interface:

* ``generator``: the CPU ``torch.Generator`` of the noise, seeded with ``seed``; a stream over calls, not
  per-environment state;
* ``reset(seed=None)``: re-seed it (with ``seed``, or the constructor's);
* ``noise(rows)``: the noise of one call on ``rows`` rows, ``[draws, rows, noise_dim]`` on the net's device;
* ``predict(..., z)``: the model as a pure tensor function of its inputs and that noise (no data-dependent
  shapes, so the fused transform stack can compile it);
* ``forward(tensordict)``: ``predict`` on the in-keys with fresh noise, written to the out-key.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from tensordict.nn import TensorDictModuleBase
from torch import Tensor, nn

from .checkpoint import CheckpointError, load_checkpoint, read_checkpoint


class GANPredictor(TensorDictModuleBase):
    """A frozen generator as a batched, gradient-free TensorDict module (see the module docstring).

    Subclasses set ``kind`` and implement :meth:`predict`, ``forward``, :meth:`build_net` (the generator of a
    checkpoint's architecture) and :meth:`check_architecture` (refuse a foreign condition layout).

    Args:
        net: the trained generator (its normalisation statistics are buffers); frozen here (eval mode,
            ``requires_grad=False``). It must have ``noise_dim`` and its first ``Linear`` at ``net.net[0]``.
        seed: seed of :attr:`generator`.
        draws: noise draws per row and call (:meth:`noise`).
    """

    kind: str

    def __init__(self, net: nn.Module, seed: int = 0, draws: int = 1):
        super().__init__()
        if int(draws) < 1:
            raise ValueError(f"{type(self).__name__}: the number of noise draws must be >= 1, got {draws!r}")
        self.net = net.eval().requires_grad_(False)
        self.seed, self.draws = int(seed), int(draws)
        self.generator = torch.Generator().manual_seed(self.seed)

    def device(self) -> torch.device:
        """Device of the generator (its first layer: cheaper than walking the module tree on every call)."""
        return self.net.net[0].weight.device

    def reset(self, seed: int | None = None) -> None:
        """Re-seed the noise generator (with ``seed``, or the constructor's)."""
        self.seed = self.seed if seed is None else int(seed)
        self.generator.manual_seed(self.seed)

    def noise(self, rows: int) -> Tensor:
        """The noise ``Z`` of one call on ``rows`` rows: ``[draws, rows, noise_dim]``, drawn from
        :attr:`generator` on the CPU (the same stream on every device) and moved to the net's device."""
        return torch.randn(self.draws, int(rows), self.net.noise_dim, generator=self.generator).to(self.device())

    # ---------------------------------------------------------------------------------------- building
    @classmethod
    def build_net(cls, architecture: Mapping[str, Any]) -> nn.Module:
        raise NotImplementedError

    @classmethod
    def check_architecture(cls, path: str | Path, architecture: Mapping[str, Any]) -> None:
        raise NotImplementedError

    @classmethod
    def from_net(cls, net: nn.Module, architecture: Mapping[str, Any], **kwargs) -> GANPredictor:
        """The predictor of ``net`` trained with ``architecture`` (override where the predictor needs it)."""
        return cls(net, **kwargs)

    @classmethod
    def from_task(cls, task, **kwargs) -> GANPredictor:
        """A predictor of a frozen COPY of ``task``'s generator (later training does not leak in; the task's
        own generator stays trainable). ``seed`` defaults to the task's."""
        kwargs.setdefault("seed", task.cfg.seed)
        return cls.from_net(copy.deepcopy(task.generator), task.architecture(), **kwargs)

    @classmethod
    def from_checkpoint(
        cls,
        path: str | Path,
        dataset_hash: str | None = None,
        architecture: Mapping[str, Any] | None = None,
        device: str | torch.device = "cpu",
        **kwargs,
    ) -> GANPredictor:
        """Rebuild the generator from a ``best.pt`` / ``last.pt`` of
        :func:`~kddrl_trl.generative.pretraining.run_pretraining` (or the shipped weights) on ``device``.
        ``architecture`` / ``dataset_hash``, if given, must match the checkpoint (:class:`CheckpointError`
        otherwise)."""
        payload = read_checkpoint(path)
        if payload["kind"] != cls.kind:
            raise CheckpointError(f"{path} holds a {payload['kind']!r} model, not {cls.kind!r}")
        arch = dict(payload["architecture"] if architecture is None else architecture)
        cls.check_architecture(path, arch)
        net = cls.build_net(arch)
        load_checkpoint(path, kind=cls.kind, architecture=arch, modules={"generator": net}, dataset_hash=dataset_hash)
        return cls.from_net(net.to(device), arch, **kwargs)
