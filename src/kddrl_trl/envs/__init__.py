"""Environments: the batched SUMO highway (TorchRL and Gymnasium) and a SUMO-free fake with the same specs."""

from ..highway_config import BrakingEvent, DriverClass, HighwayConfig, make_config, scenario_names
from .fake import FakeHighwayEnv
from .sumo_env import SumoHighwayEnv

__all__ = [
    "BrakingEvent",
    "DriverClass",
    "FakeHighwayEnv",
    "HighwayConfig",
    "SumoHighwayEnv",
    "make_config",
    "scenario_names",
]
