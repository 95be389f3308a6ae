"""``MacroTransitionWriter``: frame trajectories -> macro-transitions of buffer H (docs/design.md, "Clocks";
paper Algorithm 1 lines 25-26, 35)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

from .. import keys as K

#: keys never copied into a macro-transition (per-frame bookkeeping of collectors and envs)
DROP_KEYS: tuple[NestedKey, ...] = ("collector",)


class MacroTransitionWriter:
    """Turns batches of frames ``[B, T]`` (B environments, T consecutive frames each, as TorchRL collectors
    return them) into the lane-change agent's macro-transitions, carrying unfinished ones across batches.

    A macro-transition starts on a frame with ``decide_key`` True and holds

    - the root of that frame (state s^t at the decision and the action taken, ``keys.LC_ACTION``),
    - ``("next", reward_key)``: the **undiscounted sum** of the per-frame lane-change rewards from the decision
      frame to the last frame of the interval (Algorithm 1 line 35, "cumulative r_D3QN"); or, with
      ``efficiency_key`` given (``algo.lc_reward=decision``), §III.G's reading, the reward "calculated at each
      2-second decision step": the efficiency term counted once (its mean over the interval's frames) plus the
      event terms in full (r_lc of Eq. 28, r_collision of Eq. 29), i.e. ``sum(r - e) + mean(e)``,
    - ``"next"``: the observation after that last frame — the state at the next decision, or the terminal /
      truncated frame (an episode that ends mid-interval closes the macro-step), with its done flags,
    - ``("next", frames_key)``: the number of frames it spans.

    The interval of a decision ends on the frame whose ``("next", decide_key)`` is True (the next frame is a
    decision frame) or whose ``("next", done_key)`` is True. Both are written by
    :class:`~kddrl_trl.transforms.DecisionClock` and the env, so nothing here is specific to an environment
    or to ``lc_period``. Frames before the first decision of a row (a collection that starts mid-interval)
    cannot form a transition and are counted in :attr:`dropped_frames`.

    The row order of successive batches must be the same (true for ``Collector`` and ``MultiSyncCollector``).
    :meth:`reset` drops the unfinished transitions (e.g. when the environments restart).

    Why the reading matters: with the sum, the efficiency term (up to 1 per frame, Eq. 27) counts ~20 times per
    decision against the -1 lane-change penalty (Eq. 28) counted once; with ``decision`` they weigh 1 : 1.

    Args:
        efficiency_key: the key under ``"next"`` of the per-frame efficiency term e that the env writes beside the
            reward (``keys.EFFICIENCY_TERM``, :func:`kddrl_trl.envs.rewards.reward_terms`); None: the sum.
    """

    def __init__(
        self,
        *,
        decide_key: NestedKey = K.LC_DECIDE,
        reward_key: NestedKey = K.LC_REWARD,
        done_key: NestedKey = "done",
        frames_key: NestedKey = K.LC_MACRO_FRAMES,
        exclude: tuple[NestedKey, ...] = DROP_KEYS,
        efficiency_key: NestedKey | None = None,
    ):
        self.decide_key, self.reward_key, self.done_key, self.frames_key = decide_key, reward_key, done_key, frames_key
        self.exclude = tuple(exclude)
        self.efficiency_key = efficiency_key
        self.reset()

    def reset(self) -> None:
        self._start: TensorDictBase | None = None  # [B] root of each row's open decision frame
        self._reward: torch.Tensor | None = None  # [B, C] reward (C = 1; 2 with efficiency: r - e, e) so far
        self._frames: torch.Tensor | None = None  # [B] frames so far in the open interval
        self._open: torch.Tensor | None = None  # [B] bool, an interval is open
        self.dropped_frames = 0

    def _flag(self, td: TensorDictBase, key, name: str) -> torch.Tensor:
        value = td.get(key, None)
        if value is None:
            raise KeyError(
                f"MacroTransitionWriter: the batch has no {name} key {key!r} (is the DecisionClock "
                "transform on the env?)"
            )
        return value.reshape(*td.batch_size, -1).any(-1)

    def __call__(self, frames: TensorDictBase) -> TensorDictBase | None:
        """Macro-transitions closed in ``frames`` ``[B, T]`` (a TensorDict ``[N]``), or None if none closed."""
        if frames.batch_dims != 2:
            raise ValueError(f"expected frames of batch shape [B, T], got {tuple(frames.batch_size)}")
        frames = frames.exclude(*self.exclude)
        b, t = frames.batch_size
        decide = self._flag(frames, self.decide_key, "decision")
        end = self._flag(frames, ("next", self.decide_key), "next-decision") | self._flag(
            frames, ("next", self.done_key), "done"
        )
        reward = frames.get(("next", self.reward_key)).reshape(b, t, -1).sum(-1).to(torch.float32)
        if self.efficiency_key is None:
            reward = reward.unsqueeze(-1)  # [B, T, 1]
        else:
            key = ("next", self.efficiency_key)
            eff = frames.get(key, None)
            if eff is None:
                raise KeyError(
                    f"MacroTransitionWriter: lc_reward=decision reads the efficiency term {key!r}, which the env "
                    "did not write (kddrl_trl.envs.rewards.reward_terms)"
                )
            eff = eff.reshape(b, t).to(torch.float32)
            reward = torch.stack([reward - eff, eff], -1)  # [B, T, 2]
        if self._open is None or self._open.shape[0] != b:
            if self._open is not None:
                raise ValueError(f"the batch has {b} rows, earlier batches had {self._open.shape[0]}")
            self._open = torch.zeros(b, dtype=torch.bool)
            self._reward = torch.zeros(b, reward.shape[-1])
            self._frames = torch.zeros(b, dtype=torch.long)

        time = torch.arange(t).expand(b, t)
        last_decision = torch.where(decide, time, torch.full_like(time, -1)).cummax(dim=1).values  # [B, T]
        csum = reward.cumsum(1)  # reward of frames 0..t of the batch
        index = (last_decision - 1).clamp(min=0).unsqueeze(-1).expand_as(csum)
        before = torch.where(
            (last_decision > 0).unsqueeze(-1), csum.gather(1, index), torch.zeros_like(csum)
        )  # reward of the frames before the interval's decision
        in_batch = last_decision >= 0
        carried = ~in_batch & self._open.unsqueeze(1)
        seg_reward = torch.where(in_batch.unsqueeze(-1), csum - before, self._reward.unsqueeze(1) + csum)
        seg_frames = torch.where(in_batch, time - last_decision, self._frames.unsqueeze(1) + time) + 1
        valid = in_batch | carried
        self.dropped_frames += int((~valid).sum())

        closes = end & valid  # [B, T]
        out = None
        rows, cols = closes.nonzero(as_tuple=True)
        if rows.numel():
            nxt = frames["next"][rows, cols]
            root = frames[rows, last_decision[rows, cols].clamp(min=0)].exclude("next")
            from_earlier = ~in_batch[rows, cols]  # decided in an earlier batch: the carried start state
            if bool(from_earlier.any()):
                root[from_earlier] = self._start[rows[from_earlier]]
            total = seg_reward[rows, cols]
            n = seg_frames[rows, cols].to(total.dtype)
            total = total[:, 0] if self.efficiency_key is None else total[:, 0] + total[:, 1] / n
            nxt.set(self.reward_key, total.unsqueeze(-1).to(nxt.get(self.reward_key).dtype))
            nxt.set(self.frames_key, seg_frames[rows, cols].unsqueeze(-1))
            root.set("next", nxt)
            out = root

        # carry the interval open at the end of the batch (if any) to the next batch
        last = t - 1
        open_now = valid[:, last] & ~end[:, last]
        new_start = open_now & in_batch[:, last]
        if bool(new_start.any()):
            r = new_start.nonzero().squeeze(-1)
            src = frames[r, last_decision[r, last]].exclude("next")
            if self._start is None:
                self._start = src[:1].expand(b).clone().zero_()
            self._start[r] = src
        self._reward = torch.where(open_now.unsqueeze(-1), seg_reward[:, last], torch.zeros_like(self._reward))
        self._frames = torch.where(open_now, seg_frames[:, last], torch.zeros_like(self._frames))
        self._open = open_now
        return out
