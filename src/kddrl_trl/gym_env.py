"""Gymnasium view of the highway: one road, registered as ``kddrl_trl/SumoHighway-v0``.

Example:
    >>> import gymnasium as gym
    >>> import kddrl_trl  # registers the id
    >>> env = gym.make("kddrl_trl/SumoHighway-v0", scenario="braking")
    >>> obs, info = env.reset(seed=0)
    >>> obs, reward, terminated, truncated, info = env.step({"lc": 1, "cf": [0.5]})

Observations are what a driver senses: the keys ``keys.SENSED_KEYS`` as nested dicts (booleans as 0/1 ``int8``). The
episode's labels (``keys.EPISODE_LABEL_KEYS``: the collision flag, the outcome, the contact's kind and slot, the
braking event's phase and distance, as codes of ``kddrl_trl.keys``) are in ``info["labels"]``, nested the same way.
The action is ``{"lc": 0|1|2 (left, keep, right), "cf": [acceleration m/s²]}``.

``flatten=True`` gives the form generic agents (Stable-Baselines3's ``MlpPolicy``) take: the observation is one
``float32`` ``Box``, the sensed keys in ``keys.SENSED_KEYS`` order, each flattened row-major (its columns are named by
:attr:`SumoHighwayGymEnv.feature_names`); the action is ``Box(-1, 1, (2,))``: ``a[0] > 1/3`` changes left,
``a[0] < -1/3`` changes right, keep otherwise, and ``a[1]`` maps linearly onto the acceleration bounds (``-1`` the
lower, ``1`` the upper).

Gymnasium wants one scalar reward: ``reward="sum"`` (default) returns r_D3QN + r_TD3, ``"lc"`` or ``"cf"`` one
agent's; both are always in ``info["reward_lc"]`` and ``info["reward_cf"]``. When an episode ends, ``info["episode"]``
holds its metrics (:class:`~kddrl_trl.eval.EpisodeTracker`, as in training and evaluation).

Several envs in one process work: libsumo runs one simulation per process, so an env whose process already runs one
starts its simulation in a spawned worker process (``process="auto"``, :mod:`kddrl_trl.envs.road_sim`); ``"here"``
and ``"worker"`` force either. Its frames are the same either way.
"""

from __future__ import annotations

import logging
import os

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDict
from torchrl.data import Bounded

from . import keys as K
from .envs.episode_metrics import EpisodeTracker
from .envs.road_sim import EGO, check_process, open_road_sim
from .envs.specs import observation_spec
from .gym_registration import ENV_ID, register  # noqa: F401  (the id and its registration, re-exported)
from .highway_config import make_config

#: ``a[0]`` of the flat action beyond this changes lane (left above, right below the negative)
FLAT_LANE_THRESHOLD = 1.0 / 3.0


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


def _name(key) -> str:
    return "/".join(key) if isinstance(key, tuple) else key


def _leaf_space(spec) -> spaces.Space:
    """The Gymnasium space of one TorchRL leaf spec of one road: ``MultiBinary`` for booleans, else ``Box``."""
    if spec.dtype == torch.bool:
        return spaces.MultiBinary(tuple(spec.shape))
    dtype = torch.empty(0, dtype=spec.dtype).numpy().dtype
    if isinstance(spec, Bounded):
        return spaces.Box(spec.space.low.numpy(), spec.space.high.numpy(), tuple(spec.shape), dtype)
    return spaces.Box(-np.inf, np.inf, tuple(spec.shape), dtype)


def _dict_space(leaves: dict) -> spaces.Dict:
    """Nested ``Dict`` of leaf spaces by (nested) key."""
    nested = _nest(leaves)

    def build(node):
        return spaces.Dict({k: build(v) for k, v in node.items()}) if isinstance(node, dict) else node

    return build(nested)


def _flat_bounds(space: spaces.Space) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(space, spaces.MultiBinary):
        return np.zeros(space.n, np.float32).ravel(), np.ones(space.n, np.float32).ravel()
    low = np.broadcast_to(space.low, space.shape).astype(np.float32).ravel()
    return low, np.broadcast_to(space.high, space.shape).astype(np.float32).ravel()


class SumoHighwayGymEnv(gym.Env):
    """One ego on one road of the SUMO highway, as a Gymnasium environment (same simulator as the TorchRL env)."""

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 10}

    def __init__(
        self,
        scenario: str = "baseline",
        seed: int = 0,
        reward: str = "sum",
        render_mode: str | None = None,
        flatten: bool = False,
        process: str = "auto",
        **overrides,
    ):
        if reward not in ("sum", "lc", "cf"):
            raise ValueError(f"reward must be 'sum', 'lc' or 'cf', got {reward!r}")
        if render_mode not in (None, "rgb_array", "human"):
            raise ValueError(f"render_mode must be None, 'rgb_array' or 'human', got {render_mode!r}")
        if not isinstance(flatten, bool):
            raise ValueError(f"flatten must be True or False, got {flatten!r}")
        check_process(process)  # before any simulator starts
        self.render_mode = render_mode
        self.config = make_config(scenario, overrides)
        self.reward_mode, self.flatten, self.process = reward, flatten, process
        self._seed = seed
        self.sim = None  # a RoadSim, here or in a worker process, from the first reset()
        self._frame: dict | None = None  # the last frame the simulation returned
        self._drawn: dict | None = None  # the renderer's frame
        self.tracker = EpisodeTracker(self.config)
        spec = observation_spec(self.config, ())
        sensed = {key: _leaf_space(spec[key]) for key in K.SENSED_KEYS}
        self.dict_observation_space = _dict_space(sensed)
        cf_low, cf_high = float(self.config.accel_low), float(self.config.accel_high)
        self._cf_bounds = (cf_low, cf_high)
        if flatten:
            bounds = [_flat_bounds(space) for space in sensed.values()]
            low, high = np.concatenate([b[0] for b in bounds]), np.concatenate([b[1] for b in bounds])
            self.observation_space = spaces.Box(low, high, low.shape, np.float32)
            self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        else:
            self.observation_space = self.dict_observation_space
            self.action_space = spaces.Dict(
                {"lc": spaces.Discrete(3), "cf": spaces.Box(cf_low, cf_high, (1,), np.float32)}
            )

    @property
    def feature_names(self) -> list[str]:
        """The name of each column of the flat observation: ``<key>`` or ``<key>[i,j]``, in ``keys.SENSED_KEYS``
        order."""
        names = []
        for key, space in zip(K.SENSED_KEYS, self._sensed_leaves()):
            shape = space.n if isinstance(space, spaces.MultiBinary) else space.shape
            shape = (shape,) if isinstance(shape, int) else tuple(shape)
            for index in np.ndindex(*shape):
                names.append(f"{_name(key)}[{','.join(map(str, index))}]" if shape != (1,) else _name(key))
        return names

    def _sensed_leaves(self) -> list[spaces.Space]:
        leaves = []
        for key in K.SENSED_KEYS:
            node = self.dict_observation_space
            for part in key if isinstance(key, tuple) else (key,):
                node = node[part]
            leaves.append(node)
        return leaves

    def _obs(self):
        frame = self._frame
        if self.flatten:
            return np.concatenate([np.asarray(frame[key], np.float32).ravel() for key in K.SENSED_KEYS])
        return _nest({key: _as_obs(frame[key]) for key in K.SENSED_KEYS})

    def _labels(self) -> dict:
        return _nest({key: np.array(self._frame[key]) for key in K.EPISODE_LABEL_KEYS})

    def decode_action(self, action) -> tuple[int, float]:
        """(lane command as a ``keys.LC_ACTIONS`` index, acceleration in m/s²) of an action of this env's form."""
        if self.flatten:
            a = np.asarray(action, np.float64).reshape(-1)
            if a.shape != (2,) or not np.all(np.isfinite(a)):
                raise ValueError(f"the flat action must be 2 finite numbers, got {action!r}")
            lc = K.LEFT if a[0] > FLAT_LANE_THRESHOLD else K.RIGHT if a[0] < -FLAT_LANE_THRESHOLD else K.KEEP
            low, high = self._cf_bounds
            return lc, low + (float(np.clip(a[1], -1.0, 1.0)) + 1.0) / 2.0 * (high - low)
        cf = np.asarray(action["cf"], np.float64).reshape(-1)
        if cf.shape != (1,) or not np.isfinite(cf[0]):
            raise ValueError(f"action['cf'] must be one finite acceleration (m/s²), got {action['cf']!r}")
        return int(action["lc"]), float(cf[0])

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if self.sim is None:
            self.sim = open_road_sim(self.config, self._seed if seed is None else seed, self.process, gui=self._gui())
            seed = None  # just started with it
        self._frame = self.sim.reset(seed)
        finished, self.tracker = self.tracker.finished, EpisodeTracker(self.config)  # a running episode is dropped
        self.tracker.finished = finished
        self._draw(first=True)
        return self._obs(), {"ego": self._frame[EGO], "labels": self._labels()}

    def _gui(self) -> bool:
        """Whether this env's road runs in sumo-gui: ``render_mode="human"`` with a display. Without one (a headless
        machine, or Gymnasium's ``check_env`` making one env per render mode) it runs headless, and says so in the log."""
        if self.render_mode != "human":
            return False
        if os.environ.get("DISPLAY"):
            return True
        logging.getLogger(__name__).warning(
            "render_mode='human' needs a display for sumo-gui and DISPLAY is not set: this env runs without a window "
            "(xvfb-run -a python ... gives it a virtual one)"
        )
        return False

    def _batch(self, keys) -> TensorDict:
        return TensorDict({key: torch.from_numpy(np.asarray(self._frame[key]))[None] for key in keys}, batch_size=[1])

    def _draw(self, first: bool) -> None:
        """Keep the current frame for :meth:`render` (the renderer of ``kddrl_trl.eval.render``)."""
        if self.render_mode != "rgb_array":
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
        frame = self._batch((*K.RAW_OBSERVATION_KEYS, "terminated", "truncated"))
        self._drawn = self._recorder.frame(frame, 0, 0 if first else self._drawn["t"] + 1, first)

    def render(self):
        """``rgb_array``: the current frame seen from above (ego and its six neighbours), ``uint8 [H, W, 3]``.
        ``human``: None; the simulation runs in ``sumo-gui``, whose window follows the ego in real time (it needs a
        display: ``xvfb-run`` on a headless machine)."""
        if self.render_mode != "rgb_array":
            return None
        if self._drawn is None:
            raise RuntimeError("call reset() before render()")
        from .eval.render import frame_rgb

        return frame_rgb(self._drawn, self._recorder.meta)

    def step(self, action):
        if self.sim is None or self._frame is None or self._frame[EGO] is None:
            raise RuntimeError("call reset() before step() (and after an episode ended)")
        lc, cf = self.decode_action(action)
        self._frame = self.sim.step(lc, cf)
        r_lc, r_cf = float(self._frame[K.LC_REWARD][0]), float(self._frame[K.CF_REWARD][0])
        reward = {"sum": r_lc + r_cf, "lc": r_lc, "cf": r_cf}[self.reward_mode]
        info = {"reward_lc": r_lc, "reward_cf": r_cf, "labels": self._labels()}
        frame = self._batch((*K.RAW_OBSERVATION_KEYS, K.LC_REWARD, K.CF_REWARD, "terminated", "truncated"))
        frame["done"] = frame["terminated"] | frame["truncated"]
        step = TensorDict({"next": frame}, batch_size=[1])
        step.set(K.LC_ACTION, torch.nn.functional.one_hot(torch.tensor([lc]), 3).float())  # the commands, for the
        step.set(K.CF_ACTION, torch.tensor([[cf]], dtype=torch.float32))  # episode's crash fields
        for episode in self.tracker(step.unsqueeze(-1)):
            info["episode"] = episode
        self._draw(first=False)
        terminated, truncated = bool(self._frame["terminated"][0]), bool(self._frame["truncated"][0])
        return self._obs(), reward, terminated, truncated, info

    def close(self):
        if self.sim is not None:
            self.sim.close()
            self.sim = None
        self._frame = None


def _as_obs(value: np.ndarray) -> np.ndarray:
    return value.astype(np.int8) if value.dtype == bool else np.array(value)
