"""The Gymnasium id of the SUMO highway, registered on ``import kddrl_trl``: the registration names its entry point
as a string, so importing the package imports neither the env nor torch; ``gym.make`` does."""

from __future__ import annotations

ENV_ID = "kddrl_trl/SumoHighway-v0"


def register() -> None:
    """Register :data:`ENV_ID` with Gymnasium (idempotent; done on ``import kddrl_trl``)."""
    import gymnasium as gym

    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="kddrl_trl.gym_env:SumoHighwayGymEnv", max_episode_steps=None)
