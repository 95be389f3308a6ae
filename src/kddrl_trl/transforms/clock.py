"""``DecisionClock``: the lane-change agent's clock (docs/design.md, "Clocks"; paper Algorithm 1 line 22).

A TorchRL transform, so that any collector (``Collector``, ``MultiSyncCollector`` workers, a plain
``env.rollout``) sees the clock in the observation and no learning code has to count frames.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import Categorical, Composite, OneHot
from torchrl.envs.transforms import Transform

from .. import keys as K


class DecisionClock(Transform):
    """Writes ``keys.LC_DECIDE`` (``t mod lc_period == 0``, t = frames since the episode started) and
    ``keys.LC_HELD`` (the lane-change action executed in the previous frame; ``default`` at reset).

    Algorithm 1 line 22: the lane-change agent decides when ``t mod interval == 0`` (interval = 20 frames
    = 2 s for KDDRL, 10 for Ni et al., 1 for same-clock systems) and its action is held in between (§III.G.2).
    The clock is per environment of the batch: a partial reset (``"_reset"``) restarts only the reset rows, so
    every episode's first frame is a decision frame. The held action is read from the step's input
    (``action_key``), i.e. what was really sent to the env, whatever policy produced it.

    Args:
        lc_period (int): frames between two decisions (>= 1).
        action_key, decide_key, held_key: keys (defaults: ``keys.LC_ACTION``, ``LC_DECIDE``, ``LC_HELD``).
        num_actions (int): size of the one-hot action. Defaults to 3 (left, keep, right).
        default (int): action held before the first decision. Defaults to ``keys.KEEP``.
    """

    def __init__(
        self,
        lc_period: int,
        *,
        action_key: NestedKey = K.LC_ACTION,
        decide_key: NestedKey = K.LC_DECIDE,
        held_key: NestedKey = K.LC_HELD,
        num_actions: int = 3,
        default: int = K.KEEP,
    ):
        if isinstance(lc_period, bool) or int(lc_period) != lc_period or int(lc_period) < 1:
            raise ValueError(
                f"lc_period must be an integer >= 1 (frames between lane-change decisions), got {lc_period!r}"
            )
        if not 0 <= int(default) < int(num_actions):
            raise ValueError(f"default action {default!r} is not in [0, {num_actions})")
        super().__init__(in_keys=[], out_keys=[decide_key, held_key])
        self.lc_period, self.num_actions, self.default = int(lc_period), int(num_actions), int(default)
        self.action_key, self.decide_key, self.held_key = action_key, decide_key, held_key
        self._count: torch.Tensor | None = None  # [*B] frames since each episode started
        self._held: torch.Tensor | None = None  # [*B, num_actions]

    # ------------------------------------------------------------------------------------ state
    def _ensure(self, batch: torch.Size, device) -> None:
        if self._count is None or self._count.shape != batch:
            self._count = torch.zeros(batch, dtype=torch.long, device=device)
            self._held = self._default_action(batch, device)

    def _default_action(self, batch: torch.Size, device) -> torch.Tensor:
        out = torch.zeros((*batch, self.num_actions), dtype=torch.float32, device=device)
        out[..., self.default] = 1.0
        return out

    def _write(self, td: TensorDictBase) -> TensorDictBase:
        td.set(self.decide_key, (self._count % self.lc_period == 0).unsqueeze(-1))
        td.set(self.held_key, self._held.clone())
        return td

    # ---------------------------------------------------------------------------------- TorchRL
    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        batch = tensordict_reset.batch_size
        self._ensure(batch, tensordict_reset.device)
        reset = None if tensordict is None else tensordict.get("_reset", None)
        if reset is None or self._count.numel() == 0:
            rows = torch.ones(batch, dtype=torch.bool, device=self._count.device)
        else:
            rows = reset.reshape(*batch, -1).any(-1).to(self._count.device)
        self._count = torch.where(rows, torch.zeros_like(self._count), self._count)
        self._held = torch.where(rows.unsqueeze(-1), self._default_action(batch, self._held.device), self._held)
        return self._write(tensordict_reset)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        self._ensure(next_tensordict.batch_size, next_tensordict.device)
        action = tensordict.get(self.action_key, None)
        if action is None:
            raise KeyError(f"DecisionClock: the step's input has no {self.action_key!r} (the held lane-change action)")
        self._held = action.detach().to(torch.float32).reshape(self._held.shape).clone()
        self._count = self._count + 1
        return self._write(next_tensordict)

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:  # used by forward() only
        return next_tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        b, dev = observation_spec.shape, observation_spec.device
        observation_spec[self.decide_key] = Categorical(2, shape=(*b, 1), dtype=torch.bool, device=dev)
        observation_spec[self.held_key] = OneHot(
            self.num_actions, shape=(*b, self.num_actions), dtype=torch.float32, device=dev
        )
        return observation_spec

    def __repr__(self) -> str:
        return f"{type(self).__name__}(lc_period={self.lc_period})"
