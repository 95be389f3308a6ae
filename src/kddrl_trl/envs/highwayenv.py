"""``HighwayEnvAdapter``: KDDRL on HighwayEnv (the ``highway-env`` package, optional extra ``.[highway]``), a
simulator not written here. K instances of ``highway-v0`` (3 lanes, 10 Hz policy frequency) form a batched TorchRL
env writing the raw keys of :mod:`kddrl_trl.keys` with the specs of :func:`kddrl_trl.envs.specs.observation_spec`
(all of them but ``("leaders","history")``, which the stack's ``LeaderHistory`` keeps), and the paper's two rewards
(:mod:`kddrl_trl.envs.rewards`) computed from the same raw quantities.

Actions: HighwayEnv has no "continuous acceleration + left/keep/right" action type, so the adapter installs its own
(:class:`LaneAccelAction`): ``("cf","action")`` is the ego's acceleration (m/s², the command itself, kept so that the
speed stays in [0, v_max]) and ``("lc","action")`` moves HighwayEnv's target lane one lane left or right, exactly as
its ``DiscreteMetaAction`` ``LANE_LEFT`` / ``LANE_RIGHT`` do; the lateral motion is HighwayEnv's own steering
controller (:class:`highway_env.vehicle.controller.ControlledVehicle`). A command outside ``("lc","action_mask")``
keeps the lane, as on SUMO. With ``HighwayEnvOptions.ego_driver="highwayenv"`` the ego is one more of HighwayEnv's
own IDM/MOBIL vehicles instead (a reference driver): the commands are ignored, and ``lc.started`` is set when that
driver moves its target lane; ``"highwayenv_idm"`` is the same IDM vehicle with its lane changes switched off (the
reference of a policy that only accelerates).

Observation: HighwayEnv's ``Kinematics`` observation (features presence, x, y, vx, vy of the ego and its
``observed_vehicles - 1`` nearest vehicles, sorted by longitudinal distance, see-behind) configured with
``absolute=True, normalize=False, clip=False`` so that it is already in SI units (the default normalised, relative,
clipped form loses the ego's absolute position: x is clipped at ±200 m). Mapping to our keys (HighwayEnv: x along
the road, y to the *right*, lane id 0 = leftmost, lanes 4 m wide; ours: ``keys.py``):

=================================  ==============================================================================
our quantity                       from HighwayEnv
=================================  ==============================================================================
y (longitudinal, m)                x - x of the ego at the episode's start: the 420 m "study section" starts where
                                   the ego starts (HighwayEnv has no section; every other vehicle starts ahead)
x (lateral, m from right edge)     (lanes - 1/2) * 4 - y; so Δx = -(Δy_hw), lateral speeds v_x = -vy
v (longitudinal speed, m/s)        vx
lane (0 = rightmost)               floor(x_lateral / 4): the lane the vehicle's centre is in (a lane change
                                   switches lane half way, as SUMO)
neighbour slots a-f                the nearest observed vehicle ahead (Δy > 0) / behind (Δy <= 0) in the left,
                                   own, right lane within ``sensing_range``; only the observed vehicles count
neighbour acceleration (``kin``)   NOT in the Kinematics observation: read from the observed vehicle objects
                                   (``Vehicle.action["acceleration"]``, what HighwayEnv's IDM vehicle executes)
``leaders.ahead``                  the nearest observed vehicle ahead of each leader in its lane (else 0 and
                                   present 0)
``ego.accel``                      (speed after - speed before) / step: the executed acceleration
``lc.active``                      a lane change is in progress: the ego's target lane is not its lane, or its
                                   centre is more than ``lc_done_offset`` from the target lane's centre line
``lc.started``                     a left/right command was executed in this frame (allowed by the mask)
``lc.action_mask``                 keep always; left / right where no lane change is active and the lane exists
``collision``                      the ego's ``crashed`` flag (HighwayEnv's collision check)
``episode.collision_kind`` /       the other crashed vehicle nearest the ego: ``side`` while a lane change was
``collision_slot``                 active, else ``rear_end`` (it is ahead) / ``hit_from_behind``; its slot in the
                                   last observation (-1 if it was in none)
=================================  ==============================================================================

What cannot be provided, and what it is filled with: ``("leaders","history")`` (not written: the stack's
:class:`~kddrl_trl.transforms.LeaderHistory` builds it from ``kin``/``mask``); the braking event
(``braking.phase`` = ``none``, ``braking.distance`` = 0; ``braking.enabled=true`` is refused); a vehicle further than
the ``observed_vehicles - 1`` nearest is absent from every slot even within ``sensing_range``.

Episodes: they end as on SUMO: a collision or the ego past ``section_length`` (420 m from its start) terminate,
``max_steps`` frames truncate (HighwayEnv's own ``duration`` is not used). Which :class:`HighwayConfig` fields act
here: ``num_lanes``, ``lane_width`` (must be HighwayEnv's 4 m), ``step_length`` (policy frequency 1/step_length,
a whole number of Hz), ``section_length``, ``max_steps``, ``sensing_range`` (at most HighwayEnv's 200 m perception
distance), ``accel_low/high``, ``v_max`` (the ego's top speed; HighwayEnv's default is 40 m/s), ``ego_lane``
(HighwayEnv's ``initial_lane_id``), ``flow_scale`` (multiplies ``vehicles_density``: a denser start, HighwayEnv
inserts no vehicles during an episode) and the reward fields. The SUMO traffic fields (``flow_vph``, ``drivers``,
``warmup_s``, ``entry_length``, ``exit_length``, ``pick_window``, ``ego_start``, ``lc_duration``) do not apply:
HighwayEnv's traffic is its own ``IDMVehicle`` population (``randomize_behavior``), its lane-change duration that of
its steering controller.

Example:
    >>> from torchrl.envs import TransformedEnv
    >>> from kddrl_trl.envs.highwayenv import HighwayEnvAdapter
    >>> from kddrl_trl.transforms import make_kddrl_transforms
    >>> env = TransformedEnv(HighwayEnvAdapter(num_roads=2, seed=0), make_kddrl_transforms())
    >>> env.rollout(5)["next", "pred", "key_gaps"].shape
    torch.Size([2, 5, 3, 2])
"""

from __future__ import annotations

import functools

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

from .. import keys as K
from ..highway_config import HighwayConfig
from ..highwayenv_options import HW_LANE_WIDTH, HighwayEnvOptions, check_config
from .observe import lane_and_offset
from .rewards import reward_terms
from .specs import HighwayEnvBase, lc_command, write_rewards

#: HighwayConfig fields the adapter sets when it builds its own config (a scenario name, not a ready config)
PRESET = {"lane_width": HW_LANE_WIDTH}
_FEATURES = ["presence", "x", "y", "vx", "vy"]


def _highway_classes():
    """The HighwayEnv subclasses, built on first use: ``highway_env`` is an optional dependency."""
    try:
        from highway_env.envs.common.action import ActionType
        from highway_env.envs.highway_env import HighwayEnv
        from highway_env.vehicle.controller import ControlledVehicle
        from highway_env.vehicle.kinematics import Vehicle
    except ImportError as err:
        raise ImportError(
            "env.simulator=highwayenv needs the highway-env package: pip install 'kddrl_trl[highway]'"
        ) from err
    from gymnasium import spaces

    class CommandedVehicle(ControlledVehicle):
        """The ego: lateral motion by HighwayEnv's lane controller, longitudinal by the commanded acceleration."""

        def __init__(self, *args, dt: float = 0.1, v_max: float = 40.0, **kwargs):
            super().__init__(*args, **kwargs)
            self.dt, self.MAX_SPEED, self.MIN_SPEED, self.command = dt, v_max, 0.0, 0.0

        def act(self, action: dict | None = None) -> None:
            self.follow_road()
            if isinstance(action, dict):  # once per policy step, from LaneAccelAction
                if action["lane"] != K.KEEP:  # ours: left = HighwayEnv's lane id - 1 (as LANE_LEFT)
                    _from, _to, _id = self.target_lane_index
                    self.target_lane_index = (_from, _to, _id - 1 if action["lane"] == K.LEFT else _id + 1)
                self.command = float(action["acceleration"])
            low, high = -self.speed / self.dt, (self.MAX_SPEED - self.speed) / self.dt  # speed stays in [0, v_max]
            steering = float(
                np.clip(
                    self.steering_control(self.target_lane_index), -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE
                )
            )
            Vehicle.act(self, {"steering": steering, "acceleration": min(max(self.command, low), high)})

    class LaneAccelAction(ActionType):
        """(lane command 0 left / 1 keep / 2 right, acceleration m/s²); the mask is checked by the adapter."""

        def __init__(self, env, dt: float, v_max: float, low: float, high: float):
            super().__init__(env)
            self.dt, self.v_max, self.low, self.high = dt, v_max, low, high

        def space(self):
            return spaces.Tuple((spaces.Discrete(3), spaces.Box(self.low, self.high, shape=(1,), dtype=np.float32)))

        @property
        def vehicle_class(self):
            return functools.partial(CommandedVehicle, dt=self.dt, v_max=self.v_max)

        def act(self, action) -> None:
            self.controlled_vehicle.act({"lane": int(action[0]), "acceleration": float(np.asarray(action[1]).item())})

    class KDDRLHighway(HighwayEnv):
        """highway-v0 with :class:`LaneAccelAction`; rewards, termination and truncation are the adapter's."""

        def __init__(self, config: dict, action: dict):
            self._kddrl_action = action
            super().__init__(config=config)

        def define_spaces(self) -> None:
            super().define_spaces()
            self.action_type = LaneAccelAction(self, **self._kddrl_action)
            self.action_space = self.action_type.space()

        def _reward(self, action) -> float:
            return 0.0

        def _info(self, obs, action=None) -> dict:
            return {}

        def _is_terminated(self) -> bool:
            return bool(self.vehicle.crashed)

        def _is_truncated(self) -> bool:
            return False

    return KDDRLHighway


def highway_settings(cfg: HighwayConfig, options: HighwayEnvOptions) -> tuple[dict, dict]:
    """(HighwayEnv's config dict, the ego's action settings) of a ``highway-v0`` road on ``cfg`` with ``options``
    (validated): what :class:`HighwayEnvAdapter` runs and :mod:`kddrl_trl.data.highwayenv_to_highd` records."""
    hz, o = round(1.0 / cfg.step_length), options
    config = {
        "observation": {
            "type": "Kinematics",
            "features": _FEATURES,
            "vehicles_count": o.observed_vehicles,
            "absolute": True,
            "normalize": False,
            "clip": False,
            "see_behind": True,
            "order": "sorted",
            "include_obstacles": False,
        },
        "lanes_count": cfg.num_lanes,
        "vehicles_count": o.vehicles_count,
        "vehicles_density": o.vehicles_density * cfg.flow_scale,
        "initial_lane_id": None if cfg.ego_lane is None else cfg.num_lanes - 1 - cfg.ego_lane,
        "policy_frequency": hz,
        "simulation_frequency": o.simulation_frequency,
        "duration": 10.0 * cfg.max_steps * cfg.step_length,  # never reached: max_steps truncates first
    }
    action = {"dt": 1.0 / o.simulation_frequency, "v_max": cfg.v_max, "low": cfg.accel_low, "high": cfg.accel_high}
    return config, action


def highwayenv_drives_ego(env, lane_changes: bool = True) -> None:
    """Replaces the ego of a freshly reset highway-v0 road ``env`` by one of its ``other_vehicles_type`` vehicles
    (HighwayEnv's IDM/MOBIL driver), its behaviour randomised as highway-v0 randomises the others'; without
    ``lane_changes``, MOBIL is switched off and the vehicle keeps its lane (``IDMVehicle.enable_lane_change``)."""
    from highway_env import utils

    road, ego = env.road, env.vehicle
    driver = utils.class_from_path(env.config["other_vehicles_type"]).create_from(ego)
    driver.randomize_behavior()
    driver.enable_lane_change = lane_changes
    road.vehicles[road.vehicles.index(ego)] = driver
    env.controlled_vehicles = [driver]


def make_highway(config: dict, action: dict):
    """One ``highway-v0`` road with the ego's :class:`LaneAccelAction` (settings from :func:`highway_settings`)."""
    return _highway_classes()(config, action)


class HighwayEnvAdapter(HighwayEnvBase):
    """K HighwayEnv ``highway-v0`` roads as one TorchRL env with the keys, specs and rewards of
    :class:`~kddrl_trl.envs.SumoHighwayEnv` (no ``("leaders","history")``); see the module docstring for every
    mapping.

    Args:
        scenario: a :class:`HighwayConfig` used as it is (e.g. from the Hydra ``env`` node), or a scenario name whose
            preset applies with :data:`PRESET` (lane width 4 m) under ``overrides``.
        num_roads: K, the batch size (one HighwayEnv instance per road, stepped one after the other).
        seed: episode e of road k starts HighwayEnv with the seed drawn from (seed, k, e).
        options: :class:`HighwayEnvOptions` (or a mapping of its fields).
        **overrides: fields of :class:`HighwayConfig`.
    """

    def __init__(
        self,
        scenario: str | HighwayConfig = "baseline",
        num_roads: int = 1,
        seed: int = 0,
        device=None,
        options: HighwayEnvOptions | dict | None = None,
        **overrides,
    ):
        if not isinstance(scenario, HighwayConfig):
            overrides = {**PRESET, **overrides}
        super().__init__(scenario, num_roads, seed, device, **overrides)
        cfg = self.config
        self.options = check_config(cfg, options)
        del self.observation_spec[K.LEADERS_HISTORY]  # kept by the stack's LeaderHistory
        self._hw_config, action = highway_settings(cfg, self.options)
        self.roads = [make_highway(self._hw_config, action) for _ in range(num_roads)]
        b, n = num_roads, self.options.observed_vehicles
        self._obs = np.zeros((b, n, len(_FEATURES)))
        self._acc = np.zeros((b, n))
        self._vehicles: list[list] = [[] for _ in range(b)]  # observed vehicle objects, rows 1.. of _obs
        self._slots = np.full((b, 6), -1)  # row of each slot a..f in the last observation
        self._x0 = np.zeros(b)  # HighwayEnv x of the ego at the episode's start
        self._mask = np.ones((b, 3), dtype=bool)  # lc.action_mask of the last observation
        self._active = np.zeros(b, dtype=bool)
        self.frame = np.zeros(b, dtype=np.int64)
        self.episode_count = np.zeros(b, dtype=np.int64)
        self.stats = {"episodes": 0, "collisions": 0, "left_section": 0, "max_steps": 0}
        self._set_seed(seed)

    # ----------------------------------------------------------------------------------- observation
    def _read(self, r: int) -> None:
        """Row ``r`` 's Kinematics observation ``obs`` and the accelerations of the vehicles in it."""
        env = self.roads[r]
        ego = env.vehicle
        self._vehicles[r] = env.road.close_objects_to(
            ego,
            env.PERCEPTION_DISTANCE,
            count=self.options.observed_vehicles - 1,
            see_behind=True,
            sort=True,
            vehicles_only=True,
        )
        self._acc[r] = 0.0
        for i, v in enumerate(self._vehicles[r]):  # the rows of the observation, in its order
            self._acc[r, i + 1] = float(v.action["acceleration"])
        target = env.road.network.get_lane(ego.target_lane_index)
        offset = abs(target.local_coordinates(ego.position)[1])
        self._active[r] = ego.target_lane_index[2] != ego.lane_index[2] or offset > self.options.lc_done_offset

    def _observe(self) -> dict:
        """The raw keys of the current observations of every road (see the module docstring's table)."""
        cfg, b = self.config, self.num_roads
        w, lanes = cfg.lane_width, cfg.num_lanes
        obs = self._obs
        present = obs[..., 0] > 0.5
        y = obs[..., 1] - self._x0[:, None]  # longitudinal, from the ego's start
        lat = (lanes - 0.5) * w - obs[..., 2]  # from the right edge, growing to the left
        v, vlat = obs[..., 3], -obs[..., 4]
        lane, offset = lane_and_offset(lat, w, lanes)  # offset from the lane's centre, + = left
        ego_lane = lane[:, 0]
        dy = y - y[:, :1]
        others = present.copy()
        others[:, 0] = False
        slots, has = np.zeros((b, 6), dtype=np.int64), np.zeros((b, 6), dtype=bool)
        for s, (ahead, off) in enumerate((a, o) for a in (True, False) for o in (1, 0, -1)):
            ok = (
                others
                & (lane == (ego_lane + off)[:, None])
                & ((dy > 0) if ahead else (dy <= 0))
                & (np.abs(dy) <= cfg.sensing_range)
            )
            score = np.where(ok, np.abs(dy), np.inf)
            slots[:, s] = score.argmin(-1)
            has[:, s] = ok[np.arange(b), slots[:, s]]
        self._slots = np.where(has, slots, -1)
        take = lambda a: np.take_along_axis(a, slots, 1) * has  # noqa: E731
        ny, nv, nlat, nvlat, nacc = take(y), take(v), take(lat), take(vlat), take(self._acc)
        rel = np.stack(
            [nlat - lat[:, :1] * has, ny - y[:, :1] * has, nvlat - vlat[:, :1] * has, nv - v[:, :1] * has], -1
        )
        kin = np.stack([ny, nv, nacc], -1)
        ahead = np.zeros((b, 3, 3))
        for i in range(3):  # the vehicle ahead of leader a, b, c
            gap = y - ny[:, i : i + 1]
            ok = others & (lane == np.take_along_axis(lane, slots[:, i : i + 1], 1)) & (gap > 0) & has[:, i : i + 1]
            best = np.where(ok, gap, np.inf).argmin(-1)
            found = ok[np.arange(b), best]
            ahead[:, i] = np.stack([y[np.arange(b), best], v[np.arange(b), best], np.ones(b)], -1) * found[:, None]
        mask = np.ones((b, 3), dtype=bool)
        mask[:, K.LEFT] = ~self._active & (ego_lane < lanes - 1)
        mask[:, K.RIGHT] = ~self._active & (ego_lane > 0)
        self._mask = mask
        f32 = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
        return {
            K.EGO_STATE: f32(np.stack([y[:, 0], v[:, 0], vlat[:, 0]], -1)),
            K.EGO_LANE: torch.as_tensor(ego_lane[:, None]),
            K.EGO_LANE_OFFSET: f32(offset[:, :1]),
            K.NEIGHBORS_LANE_OFFSET: f32(take(offset)),
            K.NEIGHBORS_REL: f32(rel),
            K.NEIGHBORS_MASK: torch.as_tensor(has),
            K.NEIGHBORS_KIN: f32(kin),
            K.LEADERS_AHEAD: f32(ahead),
            K.LC_ACTION_MASK: torch.as_tensor(mask),
            K.LC_ACTIVE: torch.as_tensor(self._active[:, None].copy()),
        }

    def _output(self, obs: dict, accel, started, collision, outcome, kind, slot) -> TensorDictBase:
        """Observation, episode events ([B] numpy each; no braking event) and done flags as a TensorDict."""
        col = lambda a, dtype: torch.as_tensor(np.asarray(a)[:, None], dtype=dtype)  # noqa: E731
        terminated = (outcome == K.COLLIDED) | (outcome == K.LEFT_SECTION)
        truncated = outcome == K.MAX_STEPS
        zero = np.zeros(self.num_roads)
        out = {
            **obs,
            K.EGO_ACCEL: col(accel, torch.float32),
            K.LC_STARTED: col(started, torch.bool),
            K.COLLISION: col(collision, torch.bool),
            K.OUTCOME: col(outcome, torch.int64),
            K.COLLISION_KIND: col(kind, torch.int64),
            K.COLLISION_SLOT: col(slot, torch.int64),
            K.BRAKING_PHASE: col(zero, torch.int64),
            K.BRAKING_DISTANCE: col(zero, torch.float32),
            K.BRAKING_GAP: col(zero, torch.float32),
            K.BRAKING_SPEED: col(zero, torch.float32),
            K.BRAKING_LANE_CHANGES: col(zero, torch.int64),
            K.BRAKING_CONTACT: col(zero, torch.bool),
            K.BRAKING_SLOT: col(zero - 1, torch.int64),
            K.BRAKING_FUTURE: torch.zeros(self.num_roads, 2),
            K.BRAKING_FUTURE_KNOWN: torch.zeros(self.num_roads, 2, dtype=torch.bool),
            "terminated": col(terminated, torch.bool),
            "truncated": col(truncated, torch.bool),
            "done": col(terminated | truncated, torch.bool),
        }
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    # ------------------------------------------------------------------------------------ TorchRL
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        if tensordict is not None and "_reset" in tensordict.keys():
            rows = tensordict.get("_reset").reshape(-1).nonzero().flatten().tolist()
        else:
            rows = list(range(self.num_roads))
        for r in rows:
            seed = int(np.random.SeedSequence([self._seed, r, int(self.episode_count[r])]).generate_state(1)[0])
            self._obs[r] = self.roads[r].reset(seed=seed)[0]
            if self.options.ego_driver != "agent":  # the same position, heading and speed: the same observation
                highwayenv_drives_ego(self.roads[r], lane_changes=self.options.ego_driver == "highwayenv")
            self._x0[r] = self.roads[r].vehicle.position[0]
            self.frame[r] = 0
            self.episode_count[r] += 1
            self._read(r)
        none = np.zeros(self.num_roads, dtype=np.int64)
        return self._output(self._observe(), none, none, none, none, none, none - 1)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        cfg, b = self.config, self.num_roads
        cmd = lc_command(tensordict.get(K.LC_ACTION)).reshape(-1).cpu().numpy()
        acc = np.nan_to_num(tensordict.get(K.CF_ACTION).reshape(-1).detach().cpu().numpy().astype(np.float64))
        acc = acc.clip(cfg.accel_low, cfg.accel_high)
        started = (cmd != K.KEEP) & self._mask[np.arange(b), cmd]
        cmd = np.where(started, cmd, K.KEEP)
        changing = self._active.copy()
        slots, vehicles = self._slots.copy(), [list(v) for v in self._vehicles]
        accel, collision = np.zeros(b), np.zeros(b, dtype=bool)
        kind, slot = np.zeros(b, dtype=np.int64), np.full(b, -1)
        own = self.options.ego_driver != "agent"
        for r, env in enumerate(self.roads):
            ego = env.vehicle
            before, target = ego.speed, ego.target_lane_index
            self._obs[r] = env.step((int(cmd[r]), np.array([acc[r]], dtype=np.float32)))[0]
            accel[r] = (ego.speed - before) / cfg.step_length
            if own:  # HighwayEnv's driver ignored the commands: a lane change starts when it moves its target lane
                started[r] = ego.target_lane_index != target
            self._read(r)
            if ego.crashed:
                collision[r] = True
                kind[r], slot[r] = self._contact(env, ego, changing[r], slots[r], vehicles[r])
        self.frame += 1
        out_obs = self._observe()
        y = out_obs[K.EGO_STATE][:, 0].numpy()
        outcome = np.where(
            collision,
            K.COLLIDED,
            np.where(
                y > cfg.section_length, K.LEFT_SECTION, np.where(self.frame >= cfg.max_steps, K.MAX_STEPS, K.RUNNING)
            ),
        )
        done = outcome != K.RUNNING
        self.stats["episodes"] += int(done.sum())
        self.stats["collisions"] += int(collision.sum())
        self.stats["left_section"] += int((outcome == K.LEFT_SECTION).sum())
        self.stats["max_steps"] += int((outcome == K.MAX_STEPS).sum())
        out = self._output(out_obs, accel, started, collision, outcome, kind, slot)
        speed = out_obs[K.EGO_STATE][:, 1]
        col = torch.as_tensor(collision, dtype=torch.float32)
        accel, started = (torch.as_tensor(x, dtype=torch.float32) for x in (accel, started))
        write_rewards(out, reward_terms(speed, accel, started, col, cfg), speed)
        return out

    @staticmethod
    def _contact(env, ego, changing: bool, slots: np.ndarray, vehicles: list) -> tuple[int, int]:
        """(collision kind, slot) of the ego's crash: the other crashed vehicle nearest the ego; its slot in the last
        observation (-1 if in none)."""
        crashed = [v for v in env.road.vehicles if v is not ego and v.crashed]
        if not crashed:
            return (K.SIDE_CONTACT if changing else K.REAR_END), -1
        other = min(crashed, key=lambda v: float(np.linalg.norm(v.position - ego.position)))
        kind = (
            K.SIDE_CONTACT if changing else (K.REAR_END if other.position[0] > ego.position[0] else K.HIT_FROM_BEHIND)
        )
        rows = [i for i, v in enumerate(vehicles) if v is other]  # row i + 1 of the observation
        match = np.nonzero(slots == rows[0] + 1)[0] if rows else []
        return kind, int(match[0]) if len(match) else -1

    def _set_seed(self, seed: int | None) -> None:
        self._seed = 0 if seed is None else int(seed)
        self.episode_count[:] = 0

    def close(self, *, raise_if_closed: bool = True) -> None:
        for env in getattr(self, "roads", []):
            env.close()
        super().close(raise_if_closed=False)


__all__ = ["HighwayEnvAdapter", "HighwayEnvOptions", "check_config", "PRESET"]
