"""Per-frame rewards of the two agents (paper §III.G), one function per term. Work on floats, numpy arrays or
torch tensors.

``HighwayConfig.reward`` chooses the variant (every learning algo alike):

* ``paper`` (default): Eq. 26-29 and 32-33 as written.
* ``safe``: the efficiency term is non-negative below ``v_min`` (:func:`safe_efficiency_reward`); every other term
  is the paper's. Why: under ``paper`` a stop costs more than a crash. Below 72 km/h Eq. 27 pays -1 per frame,
  and Eq. 33 another -1 at -5 m/s², so standing behind a stopped leader costs ~-1 per frame forever, about
  -1/(1 - γ) = -100 discounted at γ = 0.99 per frame, as much as the -100 collision (Eq. 29), which moreover
  comes discounted by γ^t. Toy case (``tests/envs/test_rewards.py``): ego at 36 m/s, a leader 100 m ahead brakes at
  8 m/s² to a stop; the best constant-deceleration stop scores below the best crash under ``paper`` and clearly
  above any crash of that family under ``safe``. A slow ego is already punished by earning nothing; the -1 made
  stopping for safety the worst thing it could do.
"""

from __future__ import annotations

from .. import keys as K
from ..highway_config import HighwayConfig


def _where(cond, a, b):
    """Elementwise ``a if cond else b`` for floats, numpy arrays and torch tensors (cond as 0/1)."""
    c = cond * 1.0
    return a * c + b * (1.0 - c)


def efficiency_reward(v, cfg: HighwayConfig):
    """r_eff, Eq. 27: (v - v_min)/(v_max - v_min) inside the speed limits, -1 outside."""
    inside = (v >= cfg.v_min) * (v <= cfg.v_max)
    return _where(inside, (v - cfg.v_min) / (cfg.v_max - cfg.v_min), -1.0)


def safe_efficiency_reward(v, cfg: HighwayConfig):
    """r_eff of ``reward=safe``: Eq. 27 with 0 (not -1) below v_min: (v - v_min)/(v_max - v_min) clipped at 0, and
    -1 above v_max (speeding stays penalised). Continuous at v_min, never below 0 for a legal speed."""
    scaled = (v - cfg.v_min) / (cfg.v_max - cfg.v_min)
    return _where(v > cfg.v_max, -1.0, _where(v < cfg.v_min, 0.0, scaled))


def efficiency_term(v, cfg: HighwayConfig):
    """The efficiency term of the configured variant (``cfg.reward``): :func:`efficiency_reward` (``paper``) or
    :func:`safe_efficiency_reward` (``safe``). Also what the D3QN's ``lc_reward=decision`` reading averages."""
    return safe_efficiency_reward(v, cfg) if cfg.reward == "safe" else efficiency_reward(v, cfg)


def lane_change_penalty(started, cfg: HighwayConfig):
    """r_lc, Eq. 28: ``lane_change_penalty`` (-1) in the frame a lane change starts, 0 otherwise."""
    return cfg.lane_change_penalty * started


def collision_reward(collision, cfg: HighwayConfig):
    """r_collision, Eq. 29: ``collision_penalty`` (-100) in the frame of a collision, 0 otherwise."""
    return cfg.collision_penalty * collision


def comfort_reward(accel, cfg: HighwayConfig):
    """r_acc, Eq. 33: -(|a| - 4)² above ``accel_comfort`` = 4 m/s², 0 otherwise."""
    excess = abs(accel) - cfg.accel_comfort
    return -((excess * ((excess > 0) * 1.0)) ** 2)


def reward_terms(v, accel, started, collision, cfg: HighwayConfig) -> dict:
    """The rewards' named terms of a frame, by their keys in :mod:`kddrl_trl.keys` (``TERM_KEYS``): r_eff (Eq. 27
    or its ``safe`` variant), r_lc (Eq. 28), r_collision (Eq. 29), r_acc (Eq. 33). The env writes them beside the
    rewards, so that a reading of the rewards that weighs a term differently (``algo.lc_reward=decision``) reads it
    instead of computing it again."""
    return {
        K.EFFICIENCY_TERM: efficiency_term(v, cfg),
        K.LANE_CHANGE_TERM: lane_change_penalty(started, cfg),
        K.COLLISION_TERM: collision_reward(collision, cfg),
        K.COMFORT_TERM: comfort_reward(accel, cfg),
    }


def lane_change_total(terms: dict):
    """r_D3QN = r_eff + r_lc + r_collision, Eq. 26, of the terms of :func:`reward_terms` (per frame; buffer H
    sums them)."""
    return terms[K.EFFICIENCY_TERM] + terms[K.LANE_CHANGE_TERM] + terms[K.COLLISION_TERM]


def car_following_total(terms: dict):
    """r_TD3 = r_eff + r_acc + r_collision, Eq. 32, of the terms of :func:`reward_terms`."""
    return terms[K.EFFICIENCY_TERM] + terms[K.COMFORT_TERM] + terms[K.COLLISION_TERM]


def lane_change_reward(v, started, collision, cfg: HighwayConfig):
    """r_D3QN of a speed, a lane-change start and a collision (Eq. 26 with Eq. 27-29)."""
    terms = {K.EFFICIENCY_TERM: efficiency_term(v, cfg), K.LANE_CHANGE_TERM: lane_change_penalty(started, cfg)}
    return lane_change_total({**terms, K.COLLISION_TERM: collision_reward(collision, cfg)})


def car_following_reward(v, accel, collision, cfg: HighwayConfig):
    """r_TD3 of a speed, an acceleration and a collision (Eq. 32 with Eq. 27, 29 and 33)."""
    terms = {K.EFFICIENCY_TERM: efficiency_term(v, cfg), K.COMFORT_TERM: comfort_reward(accel, cfg)}
    return car_following_total({**terms, K.COLLISION_TERM: collision_reward(collision, cfg)})
