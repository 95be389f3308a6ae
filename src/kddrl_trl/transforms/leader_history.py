"""``LeaderHistory``: the rolling window of the leaders' positions and speeds, for envs that write only the
instantaneous raw keys (``keys.LEADERS_HISTORY`` is optional in the key contract, docs/design.md).

The window of each leader slot a, b, c is kept from ``("neighbors","kin")`` (its y and v) and
``("neighbors","mask")``, with no vehicle ids: the identity of the vehicle in a slot is judged by kinematics.

Decision (a slot's vehicle change, without ids)
    A slot keeps its vehicle from one frame to the next when the new (y, v) continues the previous one:
    ``|y - (y_prev + dt (v_prev + v) / 2)| <= jump_tolerance`` (1 m by default: the trapezoid rule is exact for
    a constant acceleration, and the nearest other vehicle in a lane is a car length away) and
    ``|v - v_prev| <= speed_tolerance`` (1 m/s in 0.1 s: 10 m/s², beyond any car's braking). All three slots of
    the previous frame are candidates (errors in units of the tolerances): when the *ego* changes lane its leaders
    move between slots (b becomes c, ...), and their windows move with them. A vehicle is in one slot only, so the
    pairing is one-to-one, the smallest errors first (:func:`one_to_one`): of two cars that both continue one
    previous leader (side by side in neighbouring lanes), the nearer in (y, v) takes its window. A vehicle that continues nothing starts a new window: its
    current (y, v) back-extrapolated at constant speed over the ``H`` frames (oldest first, last = now). An absent slot
    holds zeros.

What the SUMO env's own history does (:class:`kddrl_trl.envs.observe.Observer`), for comparison
    The env knows vehicle ids: it keeps each vehicle's samples since it was first seen as a leader of the road's
    ego and back-extrapolates at constant speed over the frames before that. Where a slot keeps its vehicle, and
    where a vehicle moves between slots, this transform gives the same window (tested on the SUMO env: equal where
    the vehicles stay). They differ only (a) for a vehicle seen as a leader earlier, then not, then again within
    ``H`` frames (the env has its real samples, this transform restarts), (b) right after a reset (the env may
    have seen the new ego's leaders as the previous ego's), and (c) where a car that continues a previous leader
    within 1 m and 1 m/s is taken for it while the real one has left the three slots (the env restarts it).

Per-row state lives in the tensordicts, as in TorchRL's ``RewardSum``: a step reads the previous window from
the root tensordict (the previous output, carried by ``step_mdp``) and writes the new one under ``"next"``; a
reset refills only the rows marked by ``"_reset"`` and keeps the others. Nothing is stored in the transform,
so it works on batched, serial and parallel envs, inside or outside the workers, and pickles as it is.

It is inert where the env writes the key itself: an output already holding ``("leaders","history")`` is left as
it is, and the spec is only extended when the parent's spec lacks the key. ``make_kddrl_transforms()`` therefore
always carries one in front of trajGAN (:attr:`PredictiveStack.history`): nothing to do on an env that keeps its
own history, the window built on one that does not.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.data import Composite
from torchrl.envs.transforms import Transform

from .. import keys as K
from ..highway_config import HighwayConfig
from .predictive import unbounded_spec

_DEFAULTS = HighwayConfig()


def restart_window(y: Tensor, v: Tensor, history_len: int, dt: float) -> Tensor:
    """``[*B, 3, H, 2]`` windows of vehicles first seen now at (y, v) ``[*B, 3]``: constant-speed
    back-extrapolation, oldest first, the last entry (y, v) itself."""
    back = torch.arange(history_len - 1, -1, -1, dtype=y.dtype, device=y.device) * dt  # H-1 ... 0 frames ago
    ys = y.unsqueeze(-1) - v.unsqueeze(-1) * back
    return torch.stack([ys, v.unsqueeze(-1).expand_as(ys)], -1)


def continuity_error(
    prev_y: Tensor, prev_v: Tensor, y: Tensor, v: Tensor, dt: float, jump_tolerance: float, speed_tolerance: float
) -> Tensor:
    """``[*B, 3 (now), 3 (before)]``: how far the vehicle now in slot i is from continuing the one in slot j a frame
    earlier, in tolerances: max(|y - (y_prev + dt (v_prev + v) / 2)| / jump_tolerance, |v - v_prev| /
    speed_tolerance). At most 1: it may be the same vehicle."""
    expected = prev_y.unsqueeze(-2) + dt * 0.5 * (prev_v.unsqueeze(-2) + v.unsqueeze(-1))
    return torch.maximum(
        (y.unsqueeze(-1) - expected).abs() / jump_tolerance,
        (v.unsqueeze(-1) - prev_v.unsqueeze(-2)).abs() / speed_tolerance,
    )


def one_to_one(error: Tensor) -> tuple[Tensor, Tensor]:
    """Which previous slot each slot now continues, from ``error`` ``[*B, 3 (now), 3 (before)]``
    (:func:`continuity_error`, inf where a slot is empty): ``(found [*B, 3], source [*B, 3])``. A vehicle is in
    one slot only, so the pairing is one-to-one, taken greedily by the smallest error first: of two vehicles that
    both continue one previous vehicle (side by side in neighbouring lanes, both within the tolerances), the one
    continuing it best keeps its window and the other restarts. ``source`` is the slot itself where not found."""
    error = error.clone()
    slots_now, slots_before = error.shape[-2], error.shape[-1]
    found = torch.zeros(error.shape[:-1], dtype=torch.bool, device=error.device)
    source = torch.arange(slots_now, device=error.device).expand(error.shape[:-1]).clone()
    for _ in range(min(slots_now, slots_before)):
        best, where = error.flatten(-2).min(-1)
        take = best <= 1.0
        now, before = where // slots_before, where % slots_before
        row = torch.nn.functional.one_hot(now, slots_now).bool() & take.unsqueeze(-1)  # [*B, now]
        col = torch.nn.functional.one_hot(before, slots_before).bool() & take.unsqueeze(-1)  # [*B, before]
        found = found | row
        source = torch.where(row, before.unsqueeze(-1), source)
        error = error.masked_fill(row.unsqueeze(-1) | col.unsqueeze(-2), float("inf"))
    return found, source


class LeaderHistory(Transform):
    """Writes ``keys.LEADERS_HISTORY`` ``[*B, 3, H, 2]`` (y in m, v in m/s of the leaders a, b, c over the last
    ``history_len`` frames, oldest first) from ``("neighbors","kin")`` and ``("neighbors","mask")``; see the
    module docstring for how a slot's vehicle change is detected and what restarts.

    Args:
        history_len: H, frames in the window (the trajGAN checkpoint's; 10 = 1 s at 0.1 s).
        dt: seconds per frame of the env.
        jump_tolerance: m; speed_tolerance: m/s (the continuity test).

    Examples:
        >>> from torchrl.envs import Compose, ExcludeTransform, TransformedEnv
        >>> from kddrl_trl import keys as K
        >>> from kddrl_trl.envs import FakeHighwayEnv
        >>> from kddrl_trl.transforms import LeaderHistory
        >>> env = TransformedEnv(FakeHighwayEnv(num_roads=2), Compose(ExcludeTransform(K.LEADERS_HISTORY),
        ...                                                          LeaderHistory()))  # an env without the key
        >>> env.rollout(3)["next", "leaders", "history"].shape
        torch.Size([2, 3, 3, 10, 2])
    """

    def __init__(
        self,
        history_len: int = _DEFAULTS.history_len,
        dt: float = _DEFAULTS.step_length,
        jump_tolerance: float = 1.0,
        speed_tolerance: float = 1.0,
    ):
        if int(history_len) < 1 or dt <= 0 or jump_tolerance <= 0 or speed_tolerance <= 0:
            raise ValueError(
                f"LeaderHistory: history_len >= 1 and positive dt / tolerances, got {history_len=}, "
                f"{dt=}, {jump_tolerance=}, {speed_tolerance=}"
            )
        super().__init__(in_keys=[K.NEIGHBORS_KIN, K.NEIGHBORS_MASK], out_keys=[K.LEADERS_HISTORY])
        self.history_len, self.dt = int(history_len), float(dt)
        self.jump_tolerance, self.speed_tolerance = float(jump_tolerance), float(speed_tolerance)

    # ------------------------------------------------------------------------------------------- maths
    def _leaders(self, td: TensorDictBase) -> tuple[Tensor, Tensor, Tensor]:
        kin, mask = td.get(K.NEIGHBORS_KIN), td.get(K.NEIGHBORS_MASK)
        return kin[..., :3, 0].float(), kin[..., :3, 1].float(), mask[..., :3].bool()

    def fresh(self, td: TensorDictBase) -> Tensor:
        """Windows of ``td``'s leaders as if each were seen for the first time (zeros for absent slots)."""
        y, v, present = self._leaders(td)
        return restart_window(y, v, self.history_len, self.dt) * present[..., None, None]

    def advance(self, previous: Tensor, prev_present: Tensor, td: TensorDictBase) -> Tensor:
        """The windows after one frame: each present slot continues the window of the previous slot whose vehicle
        it continues (itself first), or restarts; absent slots are zero."""
        y, v, present = self._leaders(td)
        prev_y, prev_v = previous[..., -1, 0], previous[..., -1, 1]
        error = continuity_error(prev_y, prev_v, y, v, self.dt, self.jump_tolerance, self.speed_tolerance)
        error = error.masked_fill(~(prev_present.unsqueeze(-2) & present.unsqueeze(-1)), float("inf"))
        found, source = one_to_one(error)
        moved = torch.gather(previous, -3, source[..., None, None].expand_as(previous))
        rolled = torch.cat([moved[..., 1:, :], torch.stack([y, v], -1).unsqueeze(-2)], -2)
        window = torch.where(found[..., None, None], rolled, restart_window(y, v, self.history_len, self.dt))
        return window * present[..., None, None]

    # ----------------------------------------------------------------------------------------- TorchRL
    def _previous(self, tensordict: TensorDictBase | None) -> tuple[Tensor, Tensor] | None:
        """(previous windows, which slots held a vehicle) from the root tensordict; presence is read from the
        window itself (absent slots are all zero), as a worker of a batched env only receives the state keys."""
        previous = None if tensordict is None else tensordict.get(K.LEADERS_HISTORY, None)
        if previous is None or previous.shape[-2] != self.history_len:
            return None
        return previous, (previous[..., -1, :] != 0).any(-1)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        if K.LEADERS_HISTORY in next_tensordict.keys(True, True):  # the env keeps its own history
            return next_tensordict
        prev = self._previous(tensordict)
        with torch.no_grad():
            window = self.fresh(next_tensordict) if prev is None else self.advance(*prev, next_tensordict)
        next_tensordict.set(K.LEADERS_HISTORY, window)
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        """Rows marked by ``"_reset"`` (all when there is none) start new windows; the others keep theirs."""
        if K.LEADERS_HISTORY in tensordict_reset.keys(True, True):
            return tensordict_reset
        with torch.no_grad():
            window = self.fresh(tensordict_reset)
            prev = self._previous(tensordict)
            reset = None if tensordict is None else tensordict.get("_reset", None)
            if prev is not None and reset is not None:
                rows = reset.reshape(*tensordict_reset.batch_size, -1).any(-1)
                window = torch.where(rows[..., None, None, None], window, prev[0].to(window.dtype))
        tensordict_reset.set(K.LEADERS_HISTORY, window)
        return tensordict_reset

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        """Without the previous frame, a window can only start: fresh windows where the key is missing."""
        if K.LEADERS_HISTORY not in next_tensordict.keys(True, True):
            with torch.no_grad():
                next_tensordict.set(K.LEADERS_HISTORY, self.fresh(next_tensordict))
        return next_tensordict

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Replay-buffer use: the windows were stored with the frames; nothing to recompute."""
        return tensordict

    def wanted(self, observation_spec: Composite | None) -> bool:
        """Whether an env of ``observation_spec`` needs the window built (None: unknown, assume so)."""
        return observation_spec is None or K.LEADERS_HISTORY not in observation_spec.keys(True, True)

    def declare_state(self, input_spec: Composite, env_observation_spec: Composite | None) -> Composite:
        """The window is per-row state carried from frame to frame (as ``RewardSum``'s episode reward): it is
        declared in the state spec, so that a partial reset and a batched env's workers receive the previous
        windows. Not where the env (``env_observation_spec``) writes the key itself."""
        if not self.wanted(env_observation_spec):
            return input_spec
        state = input_spec["full_state_spec"]
        if state is None:
            state = Composite(shape=input_spec.shape, device=input_spec.device)
        if K.LEADERS_HISTORY not in state.keys(True, True):
            state[K.LEADERS_HISTORY] = unbounded_spec(input_spec.shape, (3, self.history_len, 2), input_spec.device)
        input_spec["full_state_spec"] = state
        return input_spec

    def transform_input_spec(self, input_spec: Composite) -> Composite:
        parent = self.parent
        return self.declare_state(input_spec, None if parent is None else parent.full_observation_spec)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        if K.LEADERS_HISTORY not in observation_spec.keys(True, True):
            batch, device = observation_spec.shape, observation_spec.device
            observation_spec[K.LEADERS_HISTORY] = unbounded_spec(batch, (3, self.history_len, 2), device)
        return observation_spec

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(history_len={self.history_len}, dt={self.dt}, "
            f"jump_tolerance={self.jump_tolerance}, speed_tolerance={self.speed_tolerance})"
        )
