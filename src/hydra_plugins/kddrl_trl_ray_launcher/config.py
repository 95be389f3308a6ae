"""The config of ``hydra/launcher=ray``, registered in Hydra's ConfigStore (Hydra's plugin scan imports it)."""
# (no "from __future__ import annotations": Hydra's plugin scan runs this module before it is in sys.modules,
# where a dataclass cannot resolve string annotations)

from dataclasses import dataclass, field
from typing import Any, Dict, Optional

from hydra.core.config_store import ConfigStore


@dataclass
class RayLauncherConf:
    _target_: str = "hydra_plugins.kddrl_trl_ray_launcher.ray_launcher.RayLauncher"
    # the Ray cluster: null starts a local Ray (ray.init()); else ray.init(address=...), e.g. "auto" on a node of a
    # running cluster or "ray://<head>:10001"
    address: Optional[str] = None
    # resources of each run (one Ray task, holding a worker process to itself): CPUs and GPUs Ray reserves for it
    num_cpus: float = 1
    num_gpus: float = 0
    # further keyword arguments of ray.init, e.g. num_cpus (of a local Ray: the runs it holds at once)
    init: Dict[str, Any] = field(default_factory=dict)


ConfigStore.instance().store(group="hydra/launcher", name="ray", node=RayLauncherConf, provider="kddrl_trl")
