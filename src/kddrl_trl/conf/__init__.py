"""Hydra configs of kddrl_trl, shipped inside the package (found from an installed package too).

Importing this module registers the typed schema of the ``env`` group in Hydra's ConfigStore, so every
:class:`~kddrl_trl.envs.config.HighwayConfig` field can be overridden on the command line
(``env.flow_vph=2658``) and a misspelt key or a wrong type fails at composition, naming the key. It also
registers the resolvers of :mod:`kddrl_trl.conf.resolvers` (run folders chosen before Hydra creates them).
"""
from dataclasses import dataclass

from hydra.core.config_store import ConfigStore

from ..envs.config import HighwayConfig
from . import resolvers


@dataclass
class EnvNode(HighwayConfig):
    """The ``env`` node: the highway config plus the number of roads simulated side by side."""

    num_roads: int = 8


ConfigStore.instance().store(group="env", name="highway_schema", node=EnvNode)
resolvers.register()
