"""kddrl_trl: the KDDRL system (knowledge-data dual-driven RL for highway driving) as a TorchRL pipeline.

Importing the package registers the Gymnasium id ``kddrl_trl/SumoHighway-v0``.
"""

__version__ = "0.1.0"

from .gym_env import register as _register_gym

_register_gym()
