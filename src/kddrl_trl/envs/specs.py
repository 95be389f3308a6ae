"""TorchRL specs of the raw highway keys (docs/design.md, "Key contract") and the base class shared by the SUMO
and the fake env (constructor, config validation, specs)."""

from __future__ import annotations

import torch
from torchrl.data import Bounded, Categorical, Composite, OneHot, Unbounded
from torchrl.envs import EnvBase

from .. import keys as K
from ..highway_config import HighwayConfig, make_config
from .rewards import car_following_total, lane_change_total


def observation_spec(cfg: HighwayConfig, batch: tuple[int, ...]) -> Composite:
    """Raw observation written by the environment, with units in the comments (see keys.py)."""
    b = tuple(batch)
    f32 = torch.float32
    return Composite(
        ego=Composite(
            state=Unbounded(shape=(*b, 3), dtype=f32),  # y (m), v_y (m/s), v_x (m/s)
            lane=Bounded(0, cfg.num_lanes - 1, shape=(*b, 1), dtype=torch.int64),
            accel=Bounded(cfg.accel_low, cfg.accel_high, shape=(*b, 1), dtype=f32),  # m/s²
            lane_offset=Unbounded(shape=(*b, 1), dtype=f32),  # m from the lane's centre, + = left
            shape=b,
        ),
        neighbors=Composite(
            rel=Unbounded(shape=(*b, 6, 4), dtype=f32),  # dx, dy (m), dvx, dvy (m/s)
            mask=Categorical(2, shape=(*b, 6), dtype=torch.bool),
            kin=Unbounded(shape=(*b, 6, 3), dtype=f32),  # y (m), v (m/s), a (m/s²)
            lane_offset=Unbounded(shape=(*b, 6), dtype=f32),  # m from each one's lane centre, + = left; 0 absent
            shape=b,
        ),
        leaders=Composite(
            ahead=Unbounded(shape=(*b, 3, 3), dtype=f32),  # y (m), v (m/s), present (0/1)
            history=Unbounded(shape=(*b, 3, cfg.history_len, 2), dtype=f32),  # y (m), v (m/s)
            shape=b,
        ),
        lc=Composite(
            action_mask=Categorical(2, shape=(*b, 3), dtype=torch.bool),
            active=Categorical(2, shape=(*b, 1), dtype=torch.bool),
            started=Categorical(2, shape=(*b, 1), dtype=torch.bool),
            shape=b,
        ),
        collision=Categorical(2, shape=(*b, 1), dtype=torch.bool),
        episode=Composite(  # codes of keys.OUTCOMES, COLLISION_KINDS, SLOT
            outcome=Bounded(0, len(K.OUTCOMES) - 1, shape=(*b, 1), dtype=torch.int64),
            collision_kind=Bounded(0, len(K.COLLISION_KINDS) - 1, shape=(*b, 1), dtype=torch.int64),
            collision_slot=Bounded(-1, len(K.NEIGHBOR_SLOTS) - 1, shape=(*b, 1), dtype=torch.int64),
            shape=b,
        ),
        braking=Composite(
            phase=Bounded(0, len(K.BRAKING_PHASES) - 1, shape=(*b, 1), dtype=torch.int64),  # keys.BRAKING_PHASES
            distance=Unbounded(shape=(*b, 1), dtype=f32),  # m
            gap=Unbounded(shape=(*b, 1), dtype=f32),  # m, ego front to the event car's rear
            speed=Unbounded(shape=(*b, 1), dtype=f32),  # m/s, the event car's
            lane_changes=Unbounded(shape=(*b, 1), dtype=torch.int64),  # the event car's, since its release
            contact=Categorical(2, shape=(*b, 1), dtype=torch.bool),  # the ego's collision was with it
            slot=Bounded(-1, 2, shape=(*b, 1), dtype=torch.int64),  # its leader slot a, b, c; -1
            future=Unbounded(shape=(*b, 2), dtype=f32),  # m, its scripted position 10 and 20 frames ahead
            future_known=Categorical(2, shape=(*b, 2), dtype=torch.bool),  # where the script fixes it
            shape=b,
        ),
        shape=b,
    )


def action_spec(cfg: HighwayConfig, batch: tuple[int, ...]) -> Composite:
    """(left, keep, right) one-hot lane-change command (Eq. 25) and acceleration in m/s² (Eq. 31)."""
    b = tuple(batch)
    return Composite(
        lc=Composite(action=OneHot(3, shape=(*b, 3), dtype=torch.float32), shape=b),
        cf=Composite(action=Bounded(cfg.accel_low, cfg.accel_high, shape=(*b, 1), dtype=torch.float32), shape=b),
        shape=b,
    )


def reward_spec(batch: tuple[int, ...]) -> Composite:
    """Per-agent rewards, lane change Eq. 26-29 and car following Eq. 32-33, and their named terms
    (``keys.TERM_KEYS``, :func:`kddrl_trl.envs.rewards.reward_terms`)."""
    b = tuple(batch)
    terms = {key[-1]: Unbounded(shape=(*b, 1), dtype=torch.float32) for key in K.TERM_KEYS}
    return Composite(
        lc=Composite(reward=Unbounded(shape=(*b, 1), dtype=torch.float32), shape=b),
        cf=Composite(reward=Unbounded(shape=(*b, 1), dtype=torch.float32), shape=b),
        **{K.REWARD_TERMS: Composite(terms, shape=b)},
        shape=b,
    )


def done_spec(batch: tuple[int, ...]) -> Composite:
    b = tuple(batch)
    return Composite(
        done=Categorical(2, shape=(*b, 1), dtype=torch.bool),
        terminated=Categorical(2, shape=(*b, 1), dtype=torch.bool),
        truncated=Categorical(2, shape=(*b, 1), dtype=torch.bool),
        shape=b,
    )


def set_specs(env, cfg: HighwayConfig, batch: tuple[int, ...]) -> None:
    env.observation_spec = observation_spec(cfg, batch)
    env.action_spec = action_spec(cfg, batch)
    env.reward_spec = reward_spec(batch)
    env.done_spec = done_spec(batch)


def lc_command(action: torch.Tensor) -> torch.Tensor:
    """Index (0 left, 1 keep, 2 right) of a one-hot lane-change action; an all-zero row means keep."""
    idx = action.argmax(-1)
    return torch.where(action.amax(-1) > 0, idx, torch.full_like(idx, K.KEEP))


class HighwayEnvBase(EnvBase):
    """``(scenario, num_roads, seed, device, **overrides)``: validates everything before any simulator
    starts, builds :attr:`config` and the specs; subclasses add the dynamics."""

    batch_locked = True

    def __init__(self, scenario: str = "baseline", num_roads: int = 1, seed: int = 0, device=None, **overrides):
        if not isinstance(num_roads, int) or isinstance(num_roads, bool) or num_roads < 1:
            raise ValueError(f"num_roads must be an integer >= 1, got {num_roads!r}")
        self.config: HighwayConfig = make_config(scenario, overrides)
        super().__init__(device=device, batch_size=torch.Size([num_roads]))
        self.num_roads = num_roads
        set_specs(self, self.config, (num_roads,))


def write_rewards(out, terms: dict, like: torch.Tensor) -> None:
    """Writes into a step's output ``out`` the two rewards (Eqs. 26 and 32) and their named terms
    (:func:`kddrl_trl.envs.rewards.reward_terms`, tensors or numbers), each float32 ``[B, 1]`` for a batch shaped as
    ``like`` ``[B]``."""
    rewards = {K.LC_REWARD: lane_change_total(terms), K.CF_REWARD: car_following_total(terms), **terms}
    for key, value in rewards.items():
        out.set(key, torch.as_tensor(value, dtype=torch.float32, device=like.device).expand_as(like)[:, None].clone())
