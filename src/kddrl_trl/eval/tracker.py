"""``EpisodeTracker``: per-episode driving metrics from collected frames, for any env writing the raw keys."""
from __future__ import annotations

import torch
from tensordict import TensorDictBase

from .. import keys as K
from ..envs.sim import EpisodeStats


class EpisodeTracker:
    """Accumulates, per environment of a batch, the metrics :func:`~kddrl_trl.eval.metrics.summarize` reads
    (the same fields as ``SumoHighwayEnv.episodes``, through the same :class:`EpisodeStats`) from frame batches
    ``[B, T]`` of a collector, and returns the episodes that finished in each batch, in the order they finished.

    Read under ``"next"`` of each frame: ``EGO_STATE`` speed, ``EGO_ACCEL``, ``LC_STARTED`` (lane changes),
    ``COLLISION``, the two rewards and the done flags. Only needs the raw keys, not SUMO.
    """

    #: running sums per road, named as the fields of :class:`~kddrl_trl.envs.sim.EpisodeStats`
    FIELDS = ("frames", "speed_sum", "speed_sq_sum", "accel_sum", "accel_sq_sum", "abs_accel_sum", "lane_changes",
              "return_lc", "return_cf")

    def __init__(self):
        self.sums: dict[str, torch.Tensor] | None = None
        self.collided: torch.Tensor | None = None
        self.finished = 0

    def _get(self, frames: TensorDictBase, key, default=0.0) -> torch.Tensor:
        value = frames.get(("next", *(key if isinstance(key, tuple) else (key,))), None)
        if value is None:
            return torch.full(frames.batch_size, float(default))
        return value.reshape(*frames.batch_size, -1)[..., 0].to(torch.float32)

    def __call__(self, frames: TensorDictBase) -> list[dict]:
        if frames.batch_dims != 2:
            raise ValueError(f"expected frames of batch shape [B, T], got {tuple(frames.batch_size)}")
        b, t = frames.batch_size
        if self.sums is None:
            self.sums = {f: torch.zeros(b, dtype=torch.float64) for f in self.FIELDS}
            self.collided = torch.zeros(b, dtype=torch.bool)
        speed = frames.get(("next", *K.EGO_STATE))[..., 1].to(torch.float32)
        accel = self._get(frames, K.EGO_ACCEL)
        per_frame = {"frames": torch.ones(b, t), "speed_sum": speed, "speed_sq_sum": speed * speed,
                     "accel_sum": accel, "accel_sq_sum": accel * accel, "abs_accel_sum": accel.abs(),
                     "lane_changes": self._get(frames, K.LC_STARTED), "return_lc": self._get(frames, K.LC_REWARD),
                     "return_cf": self._get(frames, K.CF_REWARD)}
        collision = self._get(frames, K.COLLISION) > 0
        done = self._get(frames, "done") > 0
        terminated = self._get(frames, "terminated") > 0
        out = []
        for j in range(t):
            for f, v in per_frame.items():
                self.sums[f] += v[:, j].double()
            self.collided |= collision[:, j]
            for r in done[:, j].nonzero().squeeze(-1).tolist():
                out.append(self._episode(r, bool(terminated[r, j])))
        return out

    def _episode(self, r: int, terminated: bool) -> dict:
        sums = {f: float(v[r]) for f, v in self.sums.items()}
        sums["frames"], sums["lane_changes"] = int(sums["frames"]), int(sums["lane_changes"])
        stats = EpisodeStats(road=r, ego="", driver="", index=self.finished, **sums)  # ego / driver: unknown here
        collision = bool(self.collided[r])
        ep = stats.finish("collision" if collision else ("terminated" if terminated else "truncated"))
        for v in self.sums.values():
            v[r] = 0.0
        self.collided[r] = False
        self.finished += 1
        return ep
