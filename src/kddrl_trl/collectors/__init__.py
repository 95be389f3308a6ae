"""Multi-timescale collection (docs/design.md, "Clocks"; paper Algorithm 1): a policy acting on two clocks (the
clock itself is a transform: :class:`kddrl_trl.transforms.DecisionClock`), and the writer of the lane-change agent's
macro-transitions. None of it is specific to
SUMO: any TorchRL env batch and any pair of TensorDict policies."""

from .collector import MultiTimescaleCollector
from .macro import MacroTransitionWriter
from .overlap import OverlappedCollector
from .policy import MultiRatePolicy
from .snapshot import PolicySnapshot

__all__ = [
    "MacroTransitionWriter",
    "MultiRatePolicy",
    "MultiTimescaleCollector",
    "OverlappedCollector",
    "PolicySnapshot",
]
