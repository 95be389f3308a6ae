"""Physics priors: IDM car following (paper Eq. 11-12) and MOBIL lane changing (Eq. 20-22)."""

from kddrl_trl.physics.idm import MIN_GAP, IDMParams, idm_acceleration, idm_rollout
from kddrl_trl.physics.mobil import MOBILParams, mobil_prior, mobil_utilities

__all__ = [
    "MIN_GAP",
    "IDMParams",
    "idm_acceleration",
    "idm_rollout",
    "MOBILParams",
    "mobil_prior",
    "mobil_utilities",
]
