"""Predictive-state transforms of KDDRL (paper §III.B-C, Algorithm 1 lines 15-20), one concept per file.

=====================  ==================================  ================================================
transform              writes                               paper
=====================  ==================================  ================================================
:class:`IDMPrior`       ``("pred", "prior_traj")`` [3, 20]   IDM prior trajectory TC, Eq. 11-12
:class:`TrajGANPrediction` ``("pred", "traj")`` [3, 20],     trajGAN TG, Eq. 13; key gaps y_lv^pre, Eq. 24
                        ``("pred", "key_gaps")`` [3, 2]
:class:`KeyGapsFromPrior` ``("pred", "key_gaps")`` [3, 2]    Eq. 24 from TC (stacks without trajGAN)
:class:`EventOracleKeyGaps` ``("pred", "key_gaps")`` [3, 2]  Eq. 24, the braking car's row from its script
                        (an oracle of the braking study, not in the paper)
:class:`MOBILPrior`     ``("prior", "p_mobil")`` [3]         P_MOBIL, Eq. 20-22
:class:`LCGANPrior`     ``("prior", "p_lcgan")`` [3]         P_lcGAN, Eq. 16
:class:`MOBILSafetyMask`  ``("lc", "action_mask")`` [3]      MOBIL's safety check as a hard mask, Eq. 20-21
:class:`SafetyShield`   ``("cf", "action")`` (executed),     car-following shield (not in the paper)
                        ``("next", "cf", "shield")`` [1]
:class:`RSSLaneMask`    ``("lc", "action_mask")`` [3]      RSS's lane-change gap check (``algo.shield=rss``)
:class:`LeaderHistory`  ``("leaders", "history")`` [3, H, 2] the leaders' last H (y, v), for envs without it
:class:`MOBILCriteria`  ``("prior", "mobil_incentive")`` [3], MOBIL utilities (Eq. 21-22) and safety flags
                        ``("prior", "mobil_safe")`` [3]       (Eq. 20-21): the state of Peng et al. (``algo=peng``)
:class:`DecisionClock`  ``("lc", "decide")`` [1], the held      the lane-change agent's clock, Algorithm 1 line 22
                        ``("lc", "held")`` [3]
=====================  ==================================  ================================================

:func:`make_kddrl_transforms` builds the stack (and its ablations) as a :class:`PredictiveStack`: a ``Compose``
that runs its members' maths as one function per frame (compiled with ``compile=True``: the transforms' only
compile site). All transforms read only raw keys of :mod:`kddrl_trl.keys` and keys of earlier transforms, are
stateless per frame (except :class:`LeaderHistory`, whose per-row window travels in the tensordicts as TorchRL's
``RewardSum`` does), and work on reset, step and replay-buffer samples (``forward``) of any batch shape.
"""

from .clock import DecisionClock
from .event_oracle import EventOracleKeyGaps
from .factory import make_kddrl_transforms
from .idm_prior import IDMPrior
from .key_gaps import KEY_STEPS, KeyGapsFromPrior, key_step_gaps
from .lcgan import LCGANPrior
from .leader_history import LeaderHistory
from .mobil_prior import MOBILCriteria, MOBILPrior, MOBILSafetyMask
from .rss_lane_mask import RSSLaneMask
from .shield import SafetyShield
from .stack import PredictiveStack
from .trajgan import TrajGANPrediction

__all__ = [
    "KEY_STEPS",
    "DecisionClock",
    "EventOracleKeyGaps",
    "IDMPrior",
    "KeyGapsFromPrior",
    "LCGANPrior",
    "LeaderHistory",
    "MOBILCriteria",
    "MOBILPrior",
    "MOBILSafetyMask",
    "PredictiveStack",
    "RSSLaneMask",
    "SafetyShield",
    "TrajGANPrediction",
    "key_step_gaps",
    "make_kddrl_transforms",
]
