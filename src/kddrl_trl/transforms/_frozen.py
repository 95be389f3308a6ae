"""Running a frozen generative predictor (a TensorDict module) inside a transform, without gradients."""
from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import Tensor


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
