"""Build the highway env from the Hydra ``env`` node (``conf/env/highway.yaml`` + scenario overrides)."""
from __future__ import annotations

from typing import Any, Mapping

from omegaconf import OmegaConf

from .highway import SumoHighwayEnv


def make_env(env_cfg: Mapping[str, Any], seed: int, fake: bool = False):
    """``SumoHighwayEnv`` (or ``FakeHighwayEnv`` with ``fake=True``) from a config node holding
    ``num_roads``, ``scenario`` and any :class:`~kddrl_trl.envs.config.HighwayConfig` field."""
    params = OmegaConf.to_container(OmegaConf.create(dict(env_cfg)), resolve=True) if not isinstance(env_cfg, dict) else dict(env_cfg)
    num_roads = params.pop("num_roads", 1)
    scenario = params.pop("scenario", "baseline")
    if fake:
        from .fake import FakeHighwayEnv

        return FakeHighwayEnv(scenario, num_roads=num_roads, seed=seed, **params)
    return SumoHighwayEnv(scenario, num_roads=num_roads, seed=seed, **params)
