"""Build the highway config and env from the Hydra ``env`` node (``conf/env/highway.yaml`` + scenario)."""
from __future__ import annotations

from typing import Any, Mapping

from omegaconf import OmegaConf

from .config import HighwayConfig, make_config


def env_params(env_cfg: Mapping[str, Any]) -> tuple[str, int, dict]:
    """(scenario, num_roads, the remaining HighwayConfig overrides) of an ``env`` node."""
    params = OmegaConf.to_container(OmegaConf.create(dict(env_cfg)), resolve=True)
    num_roads = params.pop("num_roads", 1)
    scenario = params.pop("scenario", "baseline")
    return scenario, num_roads, params


def highway_config(env_cfg: Mapping[str, Any]) -> HighwayConfig:
    """The validated :class:`HighwayConfig` of an ``env`` node (its ``num_roads``, the RL batch size, dropped)."""
    scenario, _, params = env_params(env_cfg)
    return make_config(scenario, params)


def make_env(env_cfg: Mapping[str, Any], seed: int, fake: bool = False):
    """``SumoHighwayEnv`` (or ``FakeHighwayEnv`` with ``fake=True``) from a config node holding
    ``num_roads``, ``scenario`` and any :class:`~kddrl_trl.envs.config.HighwayConfig` field."""
    scenario, num_roads, params = env_params(env_cfg)
    if fake:
        from .fake import FakeHighwayEnv

        return FakeHighwayEnv(scenario, num_roads=num_roads, seed=seed, **params)
    from .highway import SumoHighwayEnv

    return SumoHighwayEnv(scenario, num_roads=num_roads, seed=seed, **params)
