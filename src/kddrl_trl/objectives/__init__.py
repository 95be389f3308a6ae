"""Loss factories of the agents (TorchRL losses, target updaters and exploration modules), and the PASAC loss
TorchRL lacks."""

from .d3qn import D3QNParts, make_d3qn
from .ddpg import DDPGParts, make_ddpg
from .pasac import HybridActionSampler, PASACLoss, PASACParts, make_pasac
from .priority import td_priority
from .targets import PolyakUpdate, module_tensors, soft_update_tensors
from .td3 import TD3Parts, make_td3

__all__ = [
    "D3QNParts",
    "DDPGParts",
    "HybridActionSampler",
    "PASACLoss",
    "PASACParts",
    "PolyakUpdate",
    "TD3Parts",
    "make_d3qn",
    "make_ddpg",
    "make_pasac",
    "make_td3",
    "module_tensors",
    "soft_update_tensors",
    "td_priority",
]
