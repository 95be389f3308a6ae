"""N independent learners as one: every weight of every network gets a leading seed dimension, every linear layer
becomes a batched matrix product over it, and a batch of data carries the seed as its first dimension.

A learner built with ``seeds=N`` (:class:`~kddrl_trl.training.HierarchicalLearner`) is built as one learner, then
:func:`stack_seeds` turns it into N: each ``nn.Linear`` of its module tree becomes a :class:`SeedLinear`, and every
weight and bias the learner holds (networks, TorchRL's stacked twin critics, target copies) is reshaped in place to
carry the seed dimension just before the layer's own dimensions (a twin-critic weight ``[2, out, in]`` becomes
``[2, N, out, in]``, so that ``TD3Loss`` still vmaps its critics over the first). The tensors keep their identity,
so TorchRL's losses (which hold them in ``TensorDictParams``), the optimisers and the soft target updates built on
them work unchanged. :func:`load_seeds` then gives seed ``i`` the state of the ``i``-th of N single learners.

Why this is N independent learners, exactly:

- a :class:`SeedLinear` computes ``y[n] = x[n] W[n]^T + b[n]``: seed ``n`` 's outputs read only seed ``n`` 's inputs
  and weights;
- each loss is reduced per seed (:func:`seed_means`, the mean over that seed's minibatch, weighted as TorchRL
  weights it) and the step descends their sum, whose gradient with respect to seed ``n`` 's weights is the gradient
  of seed ``n`` 's own loss;
- Adam and the Polyak updates are elementwise, so one step over the stacked tensors is N steps.

The batched arithmetic (``baddbmm``) rounds differently from a single layer's ``addmm``, so seed ``n`` of a batch
matches the single learner to float tolerance, not bit for bit (``tests/training/test_seed_batch.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn

from .. import keys as K


class SeedLinear(nn.Linear):
    """``nn.Linear`` with a leading seed dimension: ``weight [N, out, in]``, ``bias [N, out]``; an input
    ``[N, ..., in]`` gives ``[N, ..., out]``, seed ``n`` 's rows through seed ``n`` 's weights only."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n = self.weight.shape[0]
        if x.shape[0] != n:
            raise ValueError(
                f"SeedLinear: the input's first dimension ({x.shape[0]}, of {tuple(x.shape)}) must be the seed "
                f"dimension of the weights ({n})"
            )
        flat = x.reshape(n, -1, x.shape[-1])
        w = self.weight.transpose(-1, -2)
        y = torch.bmm(flat, w) if self.bias is None else torch.baddbmm(self.bias.unsqueeze(-2), flat, w)
        return y.reshape(*x.shape[:-1], y.shape[-1])


def stacked_names(module: nn.Module) -> list[str]:
    """The ``state_dict`` entries that :func:`stack_seeds` gives a seed dimension: every tensor ending in
    ``weight`` or ``bias`` of a learner's networks, wherever TorchRL keeps it (its losses' parameter copies and
    target copies are named after the network's layers, not the layers' own attributes), and the per-seed scalars
    it was given (``seed_scalars``)."""
    scalars = set(getattr(module, "seed_scalars", ()))
    return [
        k for k, v in module.state_dict().items() if k in scalars or (v.is_floating_point() and _is_layer_tensor(k))
    ]


def _is_layer_tensor(name: str) -> bool:
    return name.rsplit(".", 1)[-1] in ("weight", "bias")


def _unstacked_seed_dim(name: str, single: torch.Tensor) -> int:
    return single.dim() - (2 if name.endswith("weight") else 1)


def seed_dim(name: str, stacked: torch.Tensor) -> int:
    """Where a stacked tensor's seed dimension is: just before a weight's ``[out, in]`` or a bias's ``[out]``; a
    per-seed scalar is ``[N, 1]`` (it broadcasts over a seed's rows ``[N, K]``), its seed dimension the first."""
    if not _is_layer_tensor(name):
        return 0
    return stacked.dim() - (3 if name.endswith("weight") else 2)


def _stacked_value(name: str, values: list[torch.Tensor], stacked: torch.Tensor) -> torch.Tensor:
    """The single learners' ``values`` of ``name`` stacked as ``stacked`` holds them."""
    return torch.stack(values, seed_dim(name, stacked)).reshape(stacked.shape)


def seed_value(name: str, stacked: torch.Tensor, i: int) -> torch.Tensor:
    """Seed ``i`` 's value of a stacked tensor, shaped as a single learner's."""
    if not _is_layer_tensor(name):
        return stacked[i, 0]
    return stacked.select(seed_dim(name, stacked), i)


def _tensors_by_name(module: nn.Module) -> dict[str, torch.Tensor]:
    """``state_dict`` names -> the module's own tensors (not detached copies), parameters and buffers."""
    own = dict(module.named_parameters(remove_duplicate=False))
    own.update(dict(module.named_buffers(remove_duplicate=False)))
    return own


def _all_modules(module: nn.Module) -> list[nn.Module]:
    """Every module reachable from ``module``: its submodules and the networks a TorchRL loss keeps outside the
    module tree (``TD3Loss`` calls a critic held as a plain attribute, with its parameters swapped in)."""
    seen, out, todo = set(), [], [module]
    while todo:
        m = todo.pop()
        if id(m) in seen:
            continue
        seen.add(id(m))
        out.append(m)
        todo.extend(m.children())
        todo.extend(v for v in vars(m).values() if isinstance(v, nn.Module))
    return out


def stack_seeds(module: nn.Module, seeds: int, scalars: Sequence[str] = ()) -> nn.Module:
    """Turns ``module`` (a learner, before its optimisers and target updates are built or after: the tensors keep
    their identity) into ``seeds`` learners (module docstring); returns it. Each seed starts with the weights
    ``module`` had (:func:`load_seeds` gives each its own). ``scalars``: ``state_dict`` names of 0-d buffers that
    are each seed's own (an exploration schedule's ε), made ``[N, 1]``."""
    if seeds < 1:
        raise ValueError(f"seeds must be >= 1, got {seeds}")
    own = _tensors_by_name(module)
    for name in scalars:
        t = own.get(name)
        if t is None or t.dim() != 0:
            raise ValueError(f"stack_seeds: {name!r} is not a 0-d tensor of the module")
        t.data = t.data.expand(seeds, 1).clone()
    module.seed_scalars = tuple(scalars)
    for name, t in _unique_stacked(module):
        if name in module.seed_scalars:
            continue
        d = _unstacked_seed_dim(name, t)
        with torch.no_grad():
            t.data = t.data.unsqueeze(d).expand(*t.shape[:d], seeds, *t.shape[d:]).clone()
    for m in _all_modules(module):
        if type(m) is nn.Linear:
            m.__class__ = SeedLinear
    module.seeds = int(seeds)
    return module


@torch.no_grad()
def load_seeds(batched: nn.Module, singles: Sequence[nn.Module]) -> None:
    """Gives seed ``i`` of ``batched`` (:func:`stack_seeds`) the state of ``singles[i]``: its stacked tensors take
    slice ``i`` of each single learner's, the other tensors must be equal in all of them (refused otherwise,
    naming the entry)."""
    if len(singles) != batched.seeds:
        raise ValueError(f"load_seeds: {len(singles)} learners for a batch of {batched.seeds} seeds")
    own, stacked = _tensors_by_name(batched), set(stacked_names(batched))
    states = [s.state_dict() for s in singles]
    for name, t in batched.state_dict().items():
        values = [s[name] for s in states]
        if name in stacked:
            own[name].copy_(_stacked_value(name, values, t))
        elif any(not torch.equal(values[0], v) for v in values[1:]):
            raise ValueError(f"load_seeds: {name!r} differs between the learners and is not stacked per seed")
        else:
            own[name].copy_(values[0])


def seed_dims_of(module: nn.Module, tensors) -> list[int]:
    """The seed dimension of each of ``tensors``, stacked tensors of ``module`` (refused otherwise)."""
    dims = {id(t): d for t, d in stacked_tensors(module)}
    out = []
    for t in tensors:
        if id(t) not in dims:
            raise ValueError(
                f"seed_dims_of: a tensor of shape {tuple(t.shape)} is not one of the module's stacked ones"
            )
        out.append(dims[id(t)])
    return out


def _unique_stacked(module: nn.Module):
    """``(name, tensor)`` of each of :func:`stacked_names` ' tensors once: one tensor under two names (a network and
    its loss's copy of it) under the first."""
    own, seen = _tensors_by_name(module), set()
    for name in stacked_names(module):
        t = own[name]
        if id(t) not in seen:
            seen.add(id(t))
            yield name, t


def stacked_tensors(module: nn.Module) -> list[tuple[torch.Tensor, int]]:
    """Every stacked tensor of ``module`` once (a tensor under two names counted once), with its seed dimension."""
    return [(t, seed_dim(name, t)) for name, t in _unique_stacked(module)]


def seed_slice(batched: nn.Module, i: int) -> dict[str, torch.Tensor]:
    """Seed ``i`` 's state of a batched learner as a single learner's ``state_dict`` (the other entries as they
    are): what a seed's own checkpoint holds."""
    stacked = set(stacked_names(batched))
    return {k: (seed_value(k, v, i) if k in stacked else v).clone() for k, v in batched.state_dict().items()}


class SeedRows(TensorDictModuleBase):
    """A seed-batched policy on an env batch of ``N * K`` rows, seed-major (rows ``i K`` to ``(i + 1) K - 1`` are
    seed ``i`` 's roads): the rows are seen as ``[N, K]`` by ``policy`` and its ``out_keys`` written back as rows."""

    def __init__(self, policy: TensorDictModuleBase, seeds: int):
        super().__init__()
        self.policy, self.seeds = policy, int(seeds)
        self.in_keys, self.out_keys = list(policy.in_keys), list(policy.out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        rows = tensordict.shape[0] if tensordict.batch_dims else 0
        if tensordict.batch_dims != 1 or rows % self.seeds:
            raise ValueError(
                f"SeedRows: a batch of {self.seeds} seeds acts on one dimension of N x K rows, got batch "
                f"{tuple(tensordict.shape)}"
            )
        out = self.policy(tensordict.select(*self.in_keys, strict=False).reshape(self.seeds, rows // self.seeds))
        for key in self.out_keys:
            value = out.get(key, None)
            if value is not None:
                tensordict.set(key, value.reshape(rows, *value.shape[2:]))
        return tensordict


def seed_means(loss: torch.Tensor, batch: TensorDictBase) -> torch.Tensor:
    """A loss computed without reduction on a seed-batched minibatch (``[N, B]``, or ``[N, B, 1]``; with importance
    weights ``keys.PRIORITY_WEIGHT`` already applied, as TorchRL's ``reduction="none"`` applies them) reduced per
    seed as TorchRL's ``reduction="mean"`` reduces one minibatch: ``[N]``."""
    n = batch.shape[0]
    per_row = loss.reshape(n, -1)
    if K.PRIORITY_WEIGHT in batch.keys():
        return per_row.sum(-1) / batch.get(K.PRIORITY_WEIGHT).reshape(n, -1).sum(-1)
    return per_row.mean(-1)
