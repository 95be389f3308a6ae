"""Policies of the comparison systems, by ``algo.name`` (DESIGN.md "Comparison systems")."""
from __future__ import annotations

from typing import Any, Mapping

from ..physics import IDMParams, MOBILParams
from .idm_mobil import IDMMobilPolicy

#: algos that need no learning and run as they are
RULE_BASED = ("idm_mobil",)


def make_rule_policy(algo_cfg: Mapping[str, Any], num_lanes: int = 3, lane_width: float = 3.2) -> IDMMobilPolicy:
    """The rule-based ego policy of ``algo=idm_mobil`` with the config's IDM and MOBIL parameters."""
    name = algo_cfg["name"]
    if name not in RULE_BASED:
        raise ValueError(f"algo '{name}' is not a rule-based policy; rule-based algos: {', '.join(RULE_BASED)}")
    idm = IDMParams(**dict(algo_cfg.get("idm", {})))
    mobil = MOBILParams(**dict(algo_cfg.get("mobil", {})))
    return IDMMobilPolicy(idm, mobil, num_lanes=num_lanes, lane_width=lane_width)
