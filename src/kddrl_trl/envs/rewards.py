"""Per-frame rewards of the two agents (paper §III.G). Work on floats, numpy arrays or torch tensors."""
from __future__ import annotations

from .config import HighwayConfig


def efficiency_reward(v, cfg: HighwayConfig):
    """r_eff, Eq. 27: (v - v_min)/(v_max - v_min) inside the speed limits, -1 outside."""
    inside = ((v >= cfg.v_min) * (v <= cfg.v_max)) * 1.0
    scaled = (v - cfg.v_min) / (cfg.v_max - cfg.v_min)
    return scaled * inside - (1.0 - inside)


def lane_change_reward(v, started, collision, cfg: HighwayConfig):
    """r_D3QN = r_eff + r_lc + r_collision, Eq. 26 with Eq. 27-29 (per frame; buffer H sums them)."""
    return efficiency_reward(v, cfg) + cfg.lane_change_penalty * started + cfg.collision_penalty * collision


def car_following_reward(v, accel, collision, cfg: HighwayConfig):
    """r_TD3 = r_eff + r_acc + r_collision, Eq. 32 with Eq. 27, 29 and 33 (r_acc = -(|a| - 4)² above 4 m/s²)."""
    excess = abs(accel) - cfg.accel_comfort
    r_acc = -(excess * ((excess > 0) * 1.0)) ** 2
    return efficiency_reward(v, cfg) + r_acc + cfg.collision_penalty * collision
