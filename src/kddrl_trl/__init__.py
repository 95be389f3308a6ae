"""kddrl_trl: the KDDRL system (knowledge-data dual-driven RL for highway driving) as a TorchRL pipeline.

Importing the package registers the Gymnasium id ``kddrl_trl/SumoHighway-v0``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("kddrl_trl")  # one place for it: pyproject.toml
except PackageNotFoundError:  # imported from a source tree that was never installed
    __version__ = "0+unknown"

from .gym_registration import register as _register_gym

_register_gym()
