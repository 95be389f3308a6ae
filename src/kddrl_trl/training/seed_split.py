"""A seed of a batch as a single learner's state, and back: what lets a batch of N seeds write, for each seed, the
checkpoint a run of its own writes (:meth:`~kddrl_trl.training.Learner.full_state_dict`: networks, targets,
exploration, counters, optimiser states), so that ``evaluate``, ``report``, a periodic validation and a resume read
a batched run's folders unchanged.

A seed's optimiser state is its slices of the batch's Adam moments and its own step count (a :class:`SeedAdam`'s
``[N]`` counts; the TD3's fused Adam, which every training seed steps at once, has one count), in
``torch.optim.Adam`` 's ``state_dict`` layout with the hyperparameters of the single learner's optimiser.
"""

from __future__ import annotations

import torch
from torch import nn

from ..modules.seed_batch import seed_dims_of, seed_slice, seed_value, stacked_names
from .seed_adam import SeedAdam


def _groups(opt: torch.optim.Optimizer) -> list[dict]:
    """``opt`` 's param groups in ``torch.optim.Adam`` 's ``state_dict`` layout (a :class:`SeedAdam` keeps fewer
    keys: the rest are Adam's defaults, which it uses)."""
    out = []
    for g in opt.state_dict()["param_groups"]:
        if isinstance(opt, SeedAdam):
            ref = torch.optim.Adam([torch.zeros(1)], lr=g["lr"], betas=g["betas"], eps=g["eps"], fused=True)
            g = {**ref.state_dict()["param_groups"][0], "params": g["params"]}
        out.append(g)
    return out


def seed_optimizer_state(batched: nn.Module, opt: torch.optim.Optimizer, i: int) -> dict:
    """Seed ``i`` 's state of one of the batch's optimisers, as the single learner's optimiser saves it."""
    params = [p for g in opt.param_groups for p in g["params"]]
    dims = seed_dims_of(batched, params)
    saved = opt.state_dict()
    state = {}
    for idx, (p, d) in enumerate(zip(params, dims)):
        s = saved["state"].get(idx)
        if s is None:
            continue
        step = s["step"]
        state[idx] = {
            "step": (step[i] if isinstance(opt, SeedAdam) else step).clone(),
            "exp_avg": s["exp_avg"].select(d, i).clone(),
            "exp_avg_sq": s["exp_avg_sq"].select(d, i).clone(),
        }
    return {"state": state, "param_groups": _groups(opt)}


def seed_full_state(batched: nn.Module, i: int, counters: torch.Tensor | None = None) -> dict:
    """Seed ``i`` of a batched learner as a single learner's :meth:`full_state_dict`; ``counters``: its own update
    counters (the batch's are shared: a trainer counts each seed's own)."""
    modules = seed_slice(batched, i)
    if counters is not None:
        modules["counters"] = counters.clone()
    return {
        "modules": modules,
        "optimizers": {name: seed_optimizer_state(batched, o, i) for name, o in batched.optimizers().items()},
    }


@torch.no_grad()
def load_seed_state(batched: nn.Module, i: int, state: dict) -> None:
    """Writes a single learner's :meth:`full_state_dict` (``state``) into seed ``i`` of a batched learner: its
    stacked tensors' slices, its optimisers' moments and (a :class:`SeedAdam`'s) step count; the shared tensors
    (scales, the TD3's step count, the counters) are taken as they are. A resumed batch loads each seed so."""
    own = batched.state_dict(keep_vars=True)
    stacked = set(stacked_names(batched))
    for name, value in state["modules"].items():
        target = own[name]
        if name in stacked:
            seed_value(name, target, i).copy_(value)
        else:
            target.copy_(value)
    for name, opt in batched.optimizers().items():
        saved = state["optimizers"][name]["state"]
        params = [p for g in opt.param_groups for p in g["params"]]
        for idx, (p, d) in enumerate(zip(params, seed_dims_of(batched, params))):
            if idx not in saved:
                continue
            if p not in opt.state or "exp_avg" not in opt.state[p]:  # a fused Adam that has not stepped yet
                opt.state[p] = {
                    "step": torch.zeros((), dtype=torch.float32, device=p.device),
                    "exp_avg": torch.zeros_like(p),
                    "exp_avg_sq": torch.zeros_like(p),
                }
            s = opt.state[p]
            s["exp_avg"].select(d, i).copy_(saved[idx]["exp_avg"])
            s["exp_avg_sq"].select(d, i).copy_(saved[idx]["exp_avg_sq"])
            if isinstance(opt, SeedAdam):
                s["step"][i].copy_(saved[idx]["step"])
            else:
                s["step"].copy_(saved[idx]["step"])
        if hasattr(opt, "_tensors"):
            opt._tensors = None  # a FusedAdam takes its lean tensors again


class SeedView:
    """Seed ``i`` of a batched learner seen as a learner of its own by a :class:`~kddrl_trl.training.Trainer`, which
    keeps that seed's run folder (episodes, logs, checkpoints, validations; :mod:`.seed_batch_trainer`): its
    :meth:`full_state_dict` is the seed's single-learner state (:func:`seed_full_state`, with the update counters the
    trainer counted for it), :meth:`load_full_state_dict` writes one back (:func:`load_seed_state`), and its
    :meth:`policy` is ``single`` (a learner of the same config, without seeds) given the seed's weights: the policy a
    validation or the final evaluation drives, as the run of its own would drive it.

    ``counts()`` returns the seed's (D3QN updates, TD3 updates): the learner's ``counters`` ``[lc, cf, actor]``
    are then those of a single learner that made them (one actor update every ``policy_delay`` TD3 updates)."""

    def __init__(self, batched: nn.Module, i: int, single: nn.Module, counts):
        self.batched, self.i, self.single, self.counts = batched, int(i), single, counts
        self.learns_from_decisions = batched.learns_from_decisions
        self.device = batched.device

    def counters(self) -> torch.Tensor:
        lc, cf = (int(c) for c in self.counts())
        return torch.tensor([lc, cf, cf // self.batched.td3.policy_delay], dtype=torch.long)

    def full_state_dict(self) -> dict:
        return seed_full_state(self.batched, self.i, self.counters())

    def load_full_state_dict(self, state: dict) -> None:
        load_seed_state(self.batched, self.i, state)

    def load_single(self) -> nn.Module:
        """``single`` with the seed's networks, targets, exploration and counters as they are now."""
        self.single.load_state_dict(seed_full_state(self.batched, self.i, self.counters())["modules"])
        return self.single

    def policy(self, explore: bool = True):
        return self.load_single().policy(explore)

    def exploration(self) -> dict[str, float]:
        """The seed's own ε."""
        return {"epsilon": float(self.batched.lc_explore.eps.reshape(-1)[self.i])}
