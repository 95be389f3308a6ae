"""``MultiRatePolicy``: two policies on two clocks as one TorchRL policy (paper Algorithm 1 lines 22-33)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey

from .. import keys as K


def _keys(module) -> list:
    return list(dict.fromkeys(tuple(k) if isinstance(k, list) else k for k in module.in_keys))


class MultiRatePolicy(TensorDictModuleBase):
    """Lane-change policy on decision frames, its held action elsewhere, car-following policy every frame.

    On every frame:

    1. ``shared`` (optional, e.g. the shared embedding of Eq. 23-24) runs once on a shallow copy;
    2. rows with ``decide_key`` True get the lane-change policy's action (Algorithm 1 lines 23-24) — the
       lane-change policy runs **only on those rows** (on a sub-batch of its own in-keys); the other rows keep
       ``held_key`` (the action in force, written by :class:`~kddrl_trl.transforms.DecisionClock`). Running it on
       all rows and keeping the decision rows would draw the ε-greedy coin for every row, so the random stream,
       and with it every later exploring action, would differ (and it is hardly faster);
    3. the car-following policy runs on all rows, reading the lane-change action just set (Eq. 30: the held
       a_D3QN is part of s_TD3; lines 31-32).

    Only the two action keys (and the car-following policy's other ``out_keys``, if asked) are written back to
    the input: intermediate keys (``s_e``, agent states, Q values) are not, so they never reach a replay buffer.
    No environment-specific code: any pair of TensorDict policies and any batch shape. Acting only: runs
    under ``torch.no_grad()`` (the learners recompute what they need from replay-buffer samples).

    Args:
        lc_policy: writes ``lc_action_key`` (e.g. D3QN's Q-value actor + ε-greedy).
        cf_policy: reads ``lc_action_key``, writes ``cf_action_key`` (e.g. TD3's actor + Gaussian noise).
        shared: module run once before both (its outputs are visible to both policies only).
        extra_out_keys: further keys of the policies to write back (e.g. Q values for logging).
        every_row: the lane-change policy runs on every row and its action is kept on the decision rows (for
            policies whose batch dimensions carry structure that a sub-batch of rows would break: N seeds' networks,
            :mod:`kddrl_trl.modules.seed_batch`).
    """

    def __init__(
        self,
        lc_policy: TensorDictModuleBase,
        cf_policy: TensorDictModuleBase,
        shared: TensorDictModuleBase | None = None,
        *,
        decide_key: NestedKey = K.LC_DECIDE,
        held_key: NestedKey = K.LC_HELD,
        lc_action_key: NestedKey = K.LC_ACTION,
        cf_action_key: NestedKey = K.CF_ACTION,
        extra_out_keys: tuple = (),
        every_row: bool = False,
    ):
        super().__init__()
        self.every_row = bool(every_row)
        self.lc_policy, self.cf_policy, self.shared = lc_policy, cf_policy, shared
        self.decide_key, self.held_key = decide_key, held_key
        self.lc_action_key, self.cf_action_key = lc_action_key, cf_action_key
        produced = set(shared.out_keys) if shared is not None else set()
        produced |= {lc_action_key}
        needed = _keys(lc_policy) + _keys(cf_policy) + (_keys(shared) if shared is not None else [])
        self.in_keys = list(dict.fromkeys([decide_key, held_key] + [k for k in needed if k not in produced]))
        self.out_keys = [lc_action_key, cf_action_key, *extra_out_keys]
        self.extra_out_keys = tuple(extra_out_keys)
        self.lc_in_keys = _keys(lc_policy)

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        work = tensordict.select(*self.in_keys, strict=False)
        if self.shared is not None:
            self.shared(work)
        batch = work.batch_size
        decide = work.get(self.decide_key).reshape(*batch, -1).any(-1)
        held = work.get(self.held_key)
        if bool(decide.all()):
            action = self.lc_policy(work.clone(False)).get(self.lc_action_key).to(held.dtype)
        elif self.every_row and bool(decide.any()):
            action = self.lc_policy(work.clone(False)).get(self.lc_action_key).to(held.dtype)
            action = torch.where(decide.reshape(*batch, *([1] * (held.dim() - len(batch)))), action, held)
        elif bool(decide.any()):  # only the lane-change policy's inputs, by integer index: less to index and copy
            rows = decide.nonzero(as_tuple=True)
            sub = self.lc_policy(work.select(*self.lc_in_keys, strict=False)[rows])
            action = held.clone()
            action[rows] = sub.get(self.lc_action_key).to(held.dtype)
        else:
            action = held
        work.set(self.lc_action_key, action)
        self.cf_policy(work)
        tensordict.set(self.lc_action_key, action)
        tensordict.set(self.cf_action_key, work.get(self.cf_action_key))
        for key in self.extra_out_keys:
            value = work.get(key, None)
            if value is not None:
                tensordict.set(key, value)
        return tensordict
