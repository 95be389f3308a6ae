"""Gymnasium view of the highway: one road, Dict spaces, registered as ``kddrl_trl/SumoHighway-v0``.

Example:
    >>> import gymnasium as gym
    >>> import kddrl_trl  # registers the id
    >>> env = gym.make("kddrl_trl/SumoHighway-v0", scenario="braking")
    >>> obs, info = env.reset(seed=0)
    >>> obs, reward, terminated, truncated, info = env.step({"lc": 1, "cf": [0.5]})

Observations are the raw keys of ``kddrl_trl.keys`` as nested dicts (booleans as 0/1 ``int8``); the action
is ``{"lc": 0|1|2 (left, keep, right), "cf": [acceleration m/s²]}``. Gymnasium wants one scalar reward:
``reward="sum"`` (default) returns r_D3QN + r_TD3, ``"lc"`` or ``"cf"`` one agent's; both are always in
``info["reward_lc"]`` and ``info["reward_cf"]``. When an episode ends, ``info["episode"]`` holds its metrics
(:class:`~kddrl_trl.eval.EpisodeTracker`, as in training and evaluation).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDict
from torchrl.data import Bounded, Composite

from .envs.config import make_config
from .envs.episode_metrics import EpisodeTracker
from .envs.sim import HighwaySim
from .envs.specs import observation_spec

ENV_ID = "kddrl_trl/SumoHighway-v0"


def _nest(flat: dict) -> dict:
    out: dict = {}
    for key, value in flat.items():
        node = out
        if isinstance(key, tuple):
            for part in key[:-1]:
                node = node.setdefault(part, {})
            node[key[-1]] = value
        else:
            out[key] = value
    return out


def _space(spec) -> spaces.Space:
    """The Gymnasium space of a TorchRL spec of one road: nested ``Dict``, ``MultiBinary`` for booleans, ``Box``."""
    if isinstance(spec, Composite):
        return spaces.Dict({name: _space(sub) for name, sub in spec.items()})
    if spec.dtype == torch.bool:
        return spaces.MultiBinary(tuple(spec.shape))
    dtype = torch.empty(0, dtype=spec.dtype).numpy().dtype
    if isinstance(spec, Bounded):
        return spaces.Box(spec.space.low.numpy(), spec.space.high.numpy(), tuple(spec.shape), dtype)
    return spaces.Box(-np.inf, np.inf, tuple(spec.shape), dtype)


class SumoHighwayGymEnv(gym.Env):
    """One ego on one road of the SUMO highway, as a Gymnasium environment (same simulator as the TorchRL env)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        scenario: str = "baseline",
        seed: int = 0,
        reward: str = "sum",
        render_mode: str | None = None,
        **overrides,
    ):
        if reward not in ("sum", "lc", "cf"):
            raise ValueError(f"reward must be 'sum', 'lc' or 'cf', got {reward!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self._frame: dict | None = None
        self.config = make_config(scenario, overrides)
        self.reward_mode = reward
        self._seed = seed
        self.sim: HighwaySim | None = None
        self.tracker = EpisodeTracker()
        self.observation_space = _space(observation_spec(self.config, ()))
        self.action_space = spaces.Dict(
            {
                "lc": spaces.Discrete(3),
                "cf": spaces.Box(self.config.accel_low, self.config.accel_high, (1,), np.float32),
            }
        )

    def _obs(self) -> dict:
        flat = {}
        for key, arr in self.sim.obs.items():
            value = arr[0]
            flat[key] = value.astype(np.int8) if value.dtype == bool else value.copy()
        return _nest(flat)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if self.sim is None:
            self.sim = HighwaySim(self.config, 1, seed=self._seed if seed is None else seed)
        elif seed is not None:
            self.sim.reseed(seed)
        self.sim.reset_roads([0])
        finished, self.tracker = self.tracker.finished, EpisodeTracker()  # a running episode is dropped
        self.tracker.finished = finished
        self._draw(first=True)
        return self._obs(), {"ego": self.sim.ego[0]}

    def _draw(self, first: bool) -> None:
        """Keep the current frame for :meth:`render` (the renderer of ``kddrl_trl.eval.render``)."""
        if self.render_mode is None:
            return
        from .eval.trace import TraceRecorder

        if first:
            c = self.config
            self._recorder = TraceRecorder(
                1,
                scenario=c.scenario,
                algo="gym",
                num_lanes=c.num_lanes,
                lane_width=c.lane_width,
                section_length=c.section_length,
                step_length=c.step_length,
            )
        frame = TensorDict({key: torch.from_numpy(arr) for key, arr in self.sim.outputs(False).items()}, batch_size=[1])
        self._frame = self._recorder.frame(frame, 0, 0 if first else self._frame["t"] + 1, first)

    def render(self):
        """``rgb_array``: the current frame seen from above (ego and its six neighbours), ``uint8 [H, W, 3]``."""
        if self.render_mode is None:
            return None
        if self._frame is None:
            raise RuntimeError("call reset() before render()")
        from .eval.render import frame_rgb

        return frame_rgb(self._frame, self._recorder.meta)

    def step(self, action):
        if self.sim is None or self.sim.ego[0] is None:
            raise RuntimeError("call reset() before step() (and after an episode ended)")
        lc = np.asarray([int(action["lc"])])
        cf = np.asarray(action["cf"], np.float64).reshape(1)
        self.sim.step(lc, cf)
        r_lc, r_cf = float(self.sim.reward_lc[0, 0]), float(self.sim.reward_cf[0, 0])
        reward = {"sum": r_lc + r_cf, "lc": r_lc, "cf": r_cf}[self.reward_mode]
        info = {"reward_lc": r_lc, "reward_cf": r_cf}
        frame = TensorDict({key: torch.from_numpy(arr) for key, arr in self.sim.outputs().items()}, batch_size=[1])
        frame["done"] = frame["terminated"] | frame["truncated"]
        for episode in self.tracker(TensorDict({"next": frame}, batch_size=[1]).unsqueeze(-1)):
            info["episode"] = episode
        self._draw(first=False)
        return self._obs(), reward, bool(self.sim.terminated[0, 0]), bool(self.sim.truncated[0, 0]), info

    def close(self):
        if self.sim is not None:
            self.sim.close()
            self.sim = None


def register() -> None:
    """Register ``kddrl_trl/SumoHighway-v0`` with Gymnasium (idempotent; done on ``import kddrl_trl``)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="kddrl_trl.gym_env:SumoHighwayGymEnv", max_episode_steps=None)
