"""Loss factories of the two agents (TorchRL losses, target updaters and exploration modules)."""
from .d3qn import D3QNParts, make_d3qn
from .td3 import TD3Parts, make_td3

__all__ = ["D3QNParts", "TD3Parts", "make_d3qn", "make_td3"]
