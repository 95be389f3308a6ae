"""n-step returns for buffer L (option ``train.n_steps``; docs/usage.md, "Safety and learning-signal options"; not
in the paper).

The paper's TD3 target (Eq. 6) bootstraps after one 0.1 s frame. With ``n_steps = n`` each frame written to buffer L
carries instead the discounted sum of the next k rewards and the state k frames later,

    y_t = sum_{i<k} gamma^i r_{t+i} + gamma^k (1 - d_{t+k-1}) Q'(s_{t+k}, ...),   k = min(n, frames to the episode's
    end, frames to the end of the collector batch),

for every frame learner alike (TD3, DDPG, the unified D3QN, PASAC: TorchRL's TD(0) estimator of each loss reads
``keys.STEPS_TO_NEXT_OBS`` and discounts by ``gamma ** k``). Windows stop at the batch end instead of waiting for the
next batch: the last n - 1 frames of each row use a shorter (still exact) return, and nothing is carried between
batches, so checkpoints and resume are unchanged.

Why not TorchRL's ``MultiStepTransform``: in TorchRL 0.14.1 it keeps ``("next", "terminated")`` of frame t while it
moves the next observation to t + k - 1, so a window that reaches a collision bootstraps from the crash state
(checked by hand: the frame two steps before a terminal one gets ``terminated=False`` and the terminal state as
its next observation), and with two reward keys it renames both to the same ``original_reward``.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

from .. import keys as K


class NStepReturns:
    """Maps a collector batch ``[B, T]`` (time last, rows in a stable order) to the same frames with n-step
    returns: under ``"next"`` every entry is that of the window's last frame t + k - 1 (its done flags
    included, so a window that ends an episode does not bootstrap), the ``reward_keys`` are replaced by
    the discounted sums of the window (module docstring), and ``keys.STEPS_TO_NEXT_OBS`` holds k. The
    input is not modified. ``n_steps = 1`` returns the frames as they are."""

    def __init__(
        self,
        n_steps: int,
        gamma: float,
        reward_keys: Sequence[NestedKey] = (K.LC_REWARD, K.CF_REWARD),
        done_key: NestedKey = "done",
    ):
        if int(n_steps) < 1:
            raise ValueError(f"n_steps must be >= 1, got {n_steps!r}")
        if not 0.0 < float(gamma) <= 1.0:
            raise ValueError(f"gamma must be in (0, 1], got {gamma!r}")
        self.n_steps, self.gamma = int(n_steps), float(gamma)
        self.reward_keys, self.done_key = list(reward_keys), done_key

    def __call__(self, frames: TensorDictBase) -> TensorDictBase:
        if self.n_steps == 1:
            return frames
        if frames.batch_dims != 2:
            raise ValueError(f"NStepReturns needs frames [rows, time], got batch size {tuple(frames.batch_size)}")
        rows, steps = frames.batch_size
        nxt = frames.get("next")
        ended = nxt.get(self.done_key).reshape(rows, steps).bool()
        raw = {key: nxt.get(key) for key in self.reward_keys}
        summed = {key: r.clone() for key, r in raw.items()}
        k = torch.ones(rows, steps, dtype=torch.long, device=ended.device)
        reaches = ~ended  # the window of frame t goes on past its current last frame
        for i in range(1, min(self.n_steps, steps)):
            grows = torch.zeros_like(reaches)
            grows[:, : steps - i] = reaches[:, : steps - i]  # the window of t takes in frame t + i
            for key, r in raw.items():
                shape = (rows, steps - i) + (1,) * (r.dim() - 2)
                summed[key][:, : steps - i] += self.gamma**i * r[:, i:] * grows[:, : steps - i].reshape(shape)
            k += grows
            reaches = torch.zeros_like(reaches)
            reaches[:, : steps - i] = grows[:, : steps - i] & ~ended[:, i:]
        last = torch.arange(steps, device=k.device).expand(rows, steps) + k - 1
        moved = nxt.exclude(*self.reward_keys).gather(1, last)
        for key, value in summed.items():
            moved.set(key, value)
        out = frames.clone(False)
        out.set("next", moved)
        out.set(K.STEPS_TO_NEXT_OBS, k.unsqueeze(-1))
        return out
