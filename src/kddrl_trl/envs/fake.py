"""``FakeHighwayEnv``: the specs and reward functions of ``SumoHighwayEnv`` without SUMO.

Deterministic and cheap, for fast unit tests of transforms, collectors and losses. Background vehicles
drive at constant speed in their lane (spacing set by the configured flow), so every raw key has a
simple, checkable value; the ego follows the same command semantics as the SUMO env (v' = max(v + a dt, 0),
a lane change lasts ``lc_duration`` and switches lane half way, commands outside ``action_mask`` keep
the lane). It writes the same episode events (``keys.OUTCOME``, ``COLLISION_KIND``, ``COLLISION_SLOT``; the
braking phase stays ``none``), so evaluation and the episode metrics run on it unchanged. It is *not* a
traffic simulator: use it for plumbing, never for results.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase

from .. import keys as K
from .rewards import reward_terms
from .specs import HighwayEnvBase, lc_command, write_rewards

_PER_LANE = 4  # background vehicles per lane


class FakeHighwayEnv(HighwayEnvBase):
    """Same constructor, specs and keys as :class:`~kddrl_trl.envs.SumoHighwayEnv`; no SUMO."""

    def __init__(
        self, scenario: str = "baseline", num_roads: int = 1, seed: int = 0, device=None, road_seeds=None, **overrides
    ):
        """``road_seeds`` as :class:`~kddrl_trl.envs.SumoHighwayEnv` 's: road ``r`` places its episodes as road ``j``
        of an env of seed ``road_seeds[r]`` would, ``j`` the number of earlier roads with that seed."""
        if road_seeds is not None and len(road_seeds) != num_roads:
            raise ValueError(f"road_seeds holds {len(road_seeds)} seeds for num_roads={num_roads}: one per road")
        #: per road: (its seed's offset from the env's seed, its place among the roads of that seed); a reseed keeps
        #: the offsets
        self._roads = None
        if road_seeds is not None:
            own = [int(s) for s in road_seeds]
            self._roads = [(s - int(seed or 0), own[:r].count(s)) for r, s in enumerate(own)]
        super().__init__(scenario, num_roads, seed, device, **overrides)
        cfg, b, n = self.config, num_roads, self.config.num_lanes * _PER_LANE
        self.lc_frames = int(round(cfg.lc_duration / cfg.step_length))
        self.ego_y, self.ego_v = torch.zeros(b), torch.zeros(b)
        self.ego_lane, self.lc_left, self.lc_dir = (torch.zeros(b, dtype=torch.long) for _ in range(3))
        self.frame = torch.zeros(b, dtype=torch.long)
        self.accel = torch.zeros(b)
        self.o_y, self.o_v = torch.zeros(b, n), torch.zeros(b, n)
        self.o_lane = torch.arange(cfg.num_lanes).repeat_interleave(_PER_LANE).expand(b, n).clone()
        self.episode_count = torch.zeros(b, dtype=torch.long)
        self._started = torch.zeros(b, dtype=torch.bool)
        self._set_seed(seed)

    # ----------------------------------------------------------------------------------- dynamics
    def _place(self, rows: torch.Tensor) -> None:
        """Deterministic placement of road ``rows`` from (seed, road, episode number)."""
        cfg = self.config
        spacing = 3600.0 * 36.0 / max(cfg.flow / cfg.num_lanes, 1.0)  # m between vehicles of one lane
        for r in rows.tolist():
            offset, j = (0, r) if self._roads is None else self._roads[r]
            g = torch.Generator().manual_seed((self._seed + offset) * 100_003 + j * 1_009 + int(self.episode_count[r]))
            self.ego_lane[r] = (
                cfg.ego_lane if cfg.ego_lane is not None else int(torch.randint(cfg.num_lanes, (1,), generator=g))
            )
            start = float(torch.rand(1, generator=g))  # drawn in both modes: the other draws stay the same
            self.ego_y[r] = 0.0 if cfg.ego_start == "entry" else -cfg.pick_window * start
            self.ego_v[r] = 25.0 + 10.0 * float(torch.rand(1, generator=g))
            k = torch.arange(_PER_LANE).repeat(cfg.num_lanes).float()
            offset = spacing * (k - 1.0) + spacing * torch.rand(k.shape, generator=g) * 0.5 + 20.0
            self.o_y[r] = self.ego_y[r] + offset
            self.o_v[r] = 22.0 + 14.0 * torch.rand(k.shape, generator=g)
            self.episode_count[r] += 1
        self.lc_left[rows] = 0
        self.frame[rows] = 0
        self.accel[rows] = 0.0

    def _slots(self):
        """Nearest leader / follower per (left, current, right) lane: indices [B,6] and presence [B,6]."""
        dy = self.o_y - self.ego_y[:, None]
        idx, present = [], []
        for ahead in (True, False):
            for off in (1, 0, -1):
                in_lane = self.o_lane == (self.ego_lane + off)[:, None]
                ok = in_lane & ((dy > 0) if ahead else (dy <= 0)) & (dy.abs() <= self.config.sensing_range)
                score = torch.where(ok, dy.abs(), torch.full_like(dy, float("inf")))
                best = score.argmin(-1)
                idx.append(best)
                present.append(ok.gather(-1, best[:, None]).squeeze(-1))
        return torch.stack(idx, -1), torch.stack(present, -1)

    def _action_mask(self, active: torch.Tensor) -> torch.Tensor:
        mask = torch.ones(self.num_roads, 3, dtype=torch.bool)
        mask[:, K.LEFT] = ~active & (self.ego_lane < self.config.num_lanes - 1)
        mask[:, K.RIGHT] = ~active & (self.ego_lane > 0)
        return mask

    def _observe(self) -> dict:
        """The raw observation keys (``keys.py``) of the current state."""
        cfg, b = self.config, self.num_roads
        h = cfg.history_len
        idx, present = self._slots()
        ny, nv = self.o_y.gather(-1, idx), self.o_v.gather(-1, idx)
        lanes = self.o_lane.gather(-1, idx)
        active = self.lc_left > 0
        vx = torch.where(active, self.lc_dir.float() * cfg.lane_width / cfg.lc_duration, torch.zeros(b))
        dx = (lanes - self.ego_lane[:, None]).float() * cfg.lane_width
        zeros = torch.zeros(b, 6)
        rel = torch.stack([dx, ny - self.ego_y[:, None], zeros - vx[:, None], nv - self.ego_v[:, None]], -1)
        kin = torch.stack([ny, nv, zeros], -1)
        pm = present[..., None].float()
        # vehicle ahead of each leader: nearest in the leader's lane in front of it
        ly, llane = ny[:, :3], lanes[:, :3]
        gap = self.o_y[:, None, :] - ly[..., None]
        ok = (self.o_lane[:, None, :] == llane[..., None]) & (gap > 0) & present[:, :3, None]
        best = torch.where(ok, gap, torch.full_like(gap, float("inf"))).argmin(-1)
        has = ok.gather(-1, best[..., None]).squeeze(-1)
        ahead = torch.stack([self.o_y.gather(-1, best), self.o_v.gather(-1, best), has.float()], -1) * has[..., None]
        back = torch.arange(h - 1, -1, -1, dtype=torch.float32) * cfg.step_length
        hist_y = ly[..., None] - nv[:, :3, None] * back
        history = torch.stack([hist_y, nv[:, :3, None].expand(b, 3, h)], -1) * pm[:, :3, None]
        done = 1.0 - self.lc_left.float() / self.lc_frames  # share of the manoeuvre done; lane switched at 0.5
        offset = torch.where(
            active, self.lc_dir.float() * cfg.lane_width * (done - (done >= 0.5).float()), torch.zeros(b)
        )
        return {
            K.EGO_STATE: torch.stack([self.ego_y, self.ego_v, vx], -1),
            K.EGO_LANE: self.ego_lane[:, None].clone(),
            K.EGO_LANE_OFFSET: offset[:, None],
            K.NEIGHBORS_LANE_OFFSET: zeros.clone(),  # background: centred
            K.EGO_ACCEL: self.accel[:, None].clone(),
            K.NEIGHBORS_REL: rel * pm,
            K.NEIGHBORS_MASK: present,
            K.NEIGHBORS_KIN: kin * pm,
            K.LEADERS_AHEAD: ahead,
            K.LEADERS_HISTORY: history,
            K.LC_ACTION_MASK: self._action_mask(active),
            K.LC_ACTIVE: active[:, None],
            K.LC_STARTED: self._started[:, None].clone(),
        }

    def _output(
        self, obs: dict, collision: torch.Tensor, outcome: torch.Tensor, kind: torch.Tensor, slot: torch.Tensor
    ) -> TensorDictBase:
        """Observation, episode events ([B] each; no braking event in the fake) and done flags as a TensorDict."""
        col = lambda x: x[:, None]  # noqa: E731
        terminated = (outcome == K.COLLIDED) | (outcome == K.LEFT_SECTION)
        truncated = outcome == K.MAX_STEPS
        zero = torch.zeros(self.num_roads, 1)
        events = {
            K.COLLISION: col(collision),
            K.OUTCOME: col(outcome),
            K.COLLISION_KIND: col(kind),
            K.COLLISION_SLOT: col(slot),
            K.BRAKING_PHASE: zero.long(),
            K.BRAKING_DISTANCE: zero,
            K.BRAKING_GAP: zero,
            K.BRAKING_SPEED: zero,
            K.BRAKING_LANE_CHANGES: zero.long(),
            K.BRAKING_CONTACT: zero.bool(),
            K.BRAKING_SLOT: zero.long() - 1,
            K.BRAKING_FUTURE: torch.zeros(self.num_roads, 2),
            K.BRAKING_FUTURE_KNOWN: torch.zeros(self.num_roads, 2, dtype=torch.bool),
            "terminated": col(terminated),
            "truncated": col(truncated),
            "done": col(terminated | truncated),
        }
        return TensorDict({**obs, **events}, batch_size=self.batch_size, device=self.device)

    # ------------------------------------------------------------------------------------ TorchRL
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        if tensordict is not None and "_reset" in tensordict.keys():
            rows = tensordict.get("_reset").reshape(-1).nonzero().flatten()
        else:
            rows = torch.arange(self.num_roads)
        self._place(rows)
        self._started[rows] = False
        none = torch.zeros(self.num_roads, dtype=torch.long)
        return self._output(self._observe(), none.bool(), none, none, none - 1)

    def _contact(self, changing: torch.Tensor, seen) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(collision, kind, slot) [B] of the ego overlapping a vehicle of its lane; ``changing``: a manoeuvre is
        in progress; ``seen``: :meth:`_slots` of the last observation, where the slot is looked up (-1 if the
        vehicle was not a neighbour)."""
        same = self.o_lane == self.ego_lane[:, None]
        dy = self.o_y - self.ego_y[:, None]
        gap = torch.where(same, dy.abs(), torch.full_like(dy, float("inf")))
        other = gap.argmin(-1)
        collision = gap.gather(-1, other[:, None]).squeeze(-1) < self.config.vehicle_length
        ahead = dy.gather(-1, other[:, None]).squeeze(-1) > 0
        kind = torch.where(changing, K.SIDE_CONTACT, torch.where(ahead, K.REAR_END, K.HIT_FROM_BEHIND))
        idx, present = seen
        match = present & (idx == other[:, None])
        slot = torch.where(match.any(-1), match.long().argmax(-1), -1)
        return collision, torch.where(collision, kind, K.NO_CONTACT), torch.where(collision, slot, -1)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        cfg = self.config
        cmd = lc_command(tensordict.get(K.LC_ACTION)).reshape(-1).cpu()
        a = tensordict.get(K.CF_ACTION).reshape(-1).detach().cpu().clamp(cfg.accel_low, cfg.accel_high)
        a = torch.nan_to_num(a)
        seen = self._slots()  # the neighbours of the last observation
        mask = self._action_mask(self.lc_left > 0)
        want = (cmd != K.KEEP) & mask.gather(-1, cmd[:, None]).squeeze(-1)
        self._started = want
        self.lc_dir = torch.where(want, torch.where(cmd == K.LEFT, 1, -1), self.lc_dir)
        self.lc_left = torch.where(want, torch.full_like(self.lc_left, self.lc_frames), self.lc_left)
        v_new = (self.ego_v + a * cfg.step_length).clamp_min(0.0)
        self.accel = (v_new - self.ego_v) / cfg.step_length
        self.ego_v = v_new
        self.ego_y = self.ego_y + v_new * cfg.step_length
        self.o_y = self.o_y + self.o_v * cfg.step_length
        changing = self.lc_left > 0
        self.lc_left = (self.lc_left - 1).clamp_min(0)
        switch = (self.lc_left == self.lc_frames // 2) & (self.lc_dir != 0) & ~want
        self.ego_lane = torch.where(switch, self.ego_lane + self.lc_dir, self.ego_lane)
        self.frame += 1
        collision, kind, slot = self._contact(changing, seen)
        outcome = torch.where(
            collision,
            K.COLLIDED,
            torch.where(
                self.ego_y > cfg.section_length,
                K.LEFT_SECTION,
                torch.where(self.frame >= cfg.max_steps, K.MAX_STEPS, K.RUNNING),
            ),
        )
        out = self._output(self._observe(), collision, outcome, kind, slot)
        col = collision.float()
        write_rewards(out, reward_terms(self.ego_v, self.accel, want.float(), col, cfg), self.ego_v)
        return out

    def _set_seed(self, seed: int | None) -> None:
        self._seed = 0 if seed is None else int(seed)
        self.episode_count.zero_()
