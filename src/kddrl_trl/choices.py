"""The values a config chooses among, and their checks, in one leaf module: the schema (``conf/schema.py``) checks a
config against them before any simulator, network or worker is built, and the parts that act on a choice read it
from here. Pure Python: parsing a config imports neither torch nor a simulator.
"""

from __future__ import annotations

import importlib.util

#: ``collector.backend``: where the collection workers run, their own processes or Ray actors
BACKENDS = ("process", "ray")
#: the validation score a ``best`` checkpoint maximises (``train.best_metric``): name -> score of a summary,
#: higher is better
BEST_METRICS = {
    "return": lambda s: s["return_lc"] + s["return_cf"],  # both agents' undiscounted returns (Eq. 26 + Eq. 32)
    "mean_speed_kmh": lambda s: s["mean_speed_kmh"],
    "collision_rate": lambda s: -s["collision_rate"],
}
#: ``algo.learner.cf_agent``: the car-following agent of a hierarchical learner (its loss:
#: :data:`kddrl_trl.training.hierarchical.CF_LOSSES`)
CF_AGENTS = ("td3", "ddpg")
#: the traffic the shipped GAN weights were trained on (``algo.transforms.weights``)
SHIPPED_TRAFFIC = ("sumo", "highwayenv")
#: the optional state features of ``algo.state_extras`` (not in the paper), in state order
STATE_EXTRAS = ("thw", "ttc")


def check_backend(backend: str) -> None:
    """``backend`` must be one of :data:`BACKENDS`; ``ray`` needs Ray installed (the ``.[ray]`` extra)."""
    if backend not in BACKENDS:
        raise ValueError(f"collector.backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if backend == "ray" and importlib.util.find_spec("ray") is None:
        raise ValueError(
            "collector.backend=ray needs Ray, which is not installed: pip install '.[ray]' (the optional "
            "extra), or use collector.backend=process"
        )


def check_extras(extras) -> tuple[str, ...]:
    """``extras`` in :data:`STATE_EXTRAS` order; an unknown or repeated name raises ``ValueError`` naming it."""
    extras = tuple(extras or ())
    bad = [e for e in extras if e not in STATE_EXTRAS]
    if bad or len(set(extras)) != len(extras):
        raise ValueError(
            f"algo.state_extras={list(extras)}: each must be one of {', '.join(STATE_EXTRAS)}, at most once"
        )
    return tuple(e for e in STATE_EXTRAS if e in extras)
