"""Ahead-of-time compiled frame functions of a :class:`~kddrl_trl.transforms.PredictiveStack`, cached on disk.

Inside an environment the stack is called with one fixed batch shape (K roads), once or twice per frame, next
to SUMO. ``torch.compile`` fuses its maths into a few kernels, but every call still runs through TorchDynamo's
guard checks and several Python wrapper layers, which on a CPU cost more than the kernels themselves. An
AOTInductor package (``torch.export`` + ``torch._inductor.aoti_compile_and_package``) is the same Inductor
code behind a C++ entry point: no guards, no Python wrappers. It is compiled for one input signature (keys,
shapes, dtypes) and stored under ``$KDDRL_TRL_CACHE/aot/`` (default ``~/.cache/kddrl_trl/aot/``), named by a
hash of everything it bakes in — the members' settings and weights, the input signature, the source of this
package, the torch version and thread count — so a later process (a sweep's next run, a test) loads it in
well under a second instead of compiling again. Packages are written atomically: parallel workers may race
to write the same one safely.

The noise of the generative members is drawn outside, from their own generators, exactly as in the other
paths, so all three paths (eager, ``torch.compile``, AOT) see the same random inputs.
"""
from __future__ import annotations

import dataclasses
import hashlib
import logging
import warnings
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path

import torch
from tensordict.utils import NestedKey
from torch import Tensor

from ..io import cache_dir, write_atomic

log = logging.getLogger(__name__)


@lru_cache(maxsize=1)
def _source_digest() -> str:
    """Hash of the package's Python source (the maths an AOT package bakes in lives there)."""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parents[1]
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


#: settings that do not shape the compiled function (noise is drawn outside it; compile flags choose paths)
_NOT_BAKED_IN = frozenset({"seed", "compile", "aot"})


def _plain(value) -> bool:
    return value is None or isinstance(value, (bool, int, float, str, tuple, list, dict)) or \
        (dataclasses.is_dataclass(value) and not isinstance(value, type))


def module_fingerprint(module: torch.nn.Module) -> str:
    """Every plain setting (numbers, strings, dataclasses such as ``IDMParams``...) and every tensor of the
    state dict of ``module`` and its submodules, hashed: what a compiled copy of it depends on."""
    h = hashlib.sha256()
    for name, sub in module.named_modules():
        items = sorted((k, repr(v)) for k, v in vars(sub).items()
                       if not k.startswith("_") and k not in _NOT_BAKED_IN and _plain(v))
        h.update(f"{name}|{type(sub).__module__}.{type(sub).__qualname__}|{items}".encode())
    for name, tensor in module.state_dict().items():
        t = tensor.detach().cpu().contiguous()
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return h.hexdigest()


@contextmanager
def _quiet():
    """Silence torch's own deprecation chatter from inside export / packaging (nothing a user can act on)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=FutureWarning)
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        yield


class _FlatFrames(torch.nn.Module):
    """The fused frame function with a flat tensor signature (what ``torch.export`` takes)."""

    def __init__(self, frames: Callable, members: Sequence[torch.nn.Module], keys: Sequence[NestedKey],
                 noise_slots: Sequence[int], out_keys: Sequence[NestedKey]):
        super().__init__()
        self.members = torch.nn.ModuleList(members)
        self._frames, self._keys, self._slots, self._out = frames, list(keys), list(noise_slots), list(out_keys)

    def forward(self, *tensors: Tensor) -> tuple[Tensor, ...]:
        n = len(self._keys)
        noises: list[Tensor | None] = [None] * len(self.members)
        for j, slot in enumerate(self._slots):
            noises[slot] = tensors[n + j]
        out = self._frames(list(self.members), dict(zip(self._keys, tensors[:n])), noises)
        return tuple(out[k] for k in self._out)


class AOTFrames:
    """A loaded AOTInductor package of a stack's fused frame function for ONE input signature.

    Call it like the fused function: ``(values, noises) -> {out_key: tensor}``. ``source`` says whether it
    was ``"compiled"`` in this process or loaded from the ``"cache"``; ``path`` is the package file.
    """

    def __init__(self, frames: Callable, members: Sequence[torch.nn.Module], values: dict[NestedKey, Tensor],
                 noises: Sequence[Tensor | None]):
        self.keys = list(values)
        self.noise_slots = [i for i, z in enumerate(noises) if z is not None]
        self.out_keys = list(dict.fromkeys(k for t in members for k in t.out_keys))  # order of the outputs
        examples = [*values.values(), *(noises[i] for i in self.noise_slots)]
        self.path = self._path(members, examples)
        if self.path.exists():
            self.source = "cache"
        else:
            self.source = "compiled"
            self._compile(_FlatFrames(frames, members, self.keys, self.noise_slots, self.out_keys), examples)
        with _quiet():
            self._runner = torch._inductor.aoti_load_package(str(self.path))

    def _path(self, members, examples) -> Path:
        h = hashlib.sha256()
        for part in (torch.__version__, str(torch.get_num_threads()), _source_digest(),
                     *(module_fingerprint(m) for m in members), repr(self.keys), repr(self.noise_slots),
                     *(f"{tuple(t.shape)}|{t.dtype}|{t.device}" for t in examples)):
            h.update(part.encode())
            h.update(b"\0")
        return cache_dir() / "aot" / f"predictive-stack-{h.hexdigest()[:24]}.pt2"

    def _compile(self, module: torch.nn.Module, examples: list[Tensor]) -> None:
        log.info("AOT-compiling the predictive-state stack for inputs %s (one-off, cached as %s)",
                 [tuple(t.shape) for t in examples], self.path)
        with torch.no_grad(), _quiet():
            program = torch.export.export(module, tuple(examples), strict=False)
        with _quiet():
            write_atomic(self.path, lambda fh: torch._inductor.aoti_compile_and_package(program, package_path=fh),
                         binary=True)

    def __call__(self, values: dict[NestedKey, Tensor], noises: Sequence[Tensor | None]) -> dict[NestedKey, Tensor]:
        outs = self._runner(*(values[k] for k in self.keys), *(noises[i] for i in self.noise_slots))
        return dict(zip(self.out_keys, outs))
