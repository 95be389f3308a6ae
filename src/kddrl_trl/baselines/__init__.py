"""Rule-based and random ego policies, and builders for the comparison systems."""

from .idm_mobil import IDMMobilPolicy
from .random_policy import RandomDrivingPolicy

__all__ = ["IDMMobilPolicy", "RandomDrivingPolicy"]
