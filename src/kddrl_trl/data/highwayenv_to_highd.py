"""Record HighwayEnv's traffic (``highway-v0``'s own ``IDMVehicle`` population) in the HighD format, as
:mod:`.sumo_to_highd` records our SUMO traffic, so that trajGAN and lcGAN can be pretrained on the traffic of the
simulator they run in (4 m lanes, HighwayEnv's IDM/MOBIL drivers and its lane-change steering controller).

A recording of ``duration_s`` is a sequence of highway-v0 episodes of ``options.record_episode_s`` each, every one
from a fresh reset (its seed drawn from (seed, recording, episode)) of the road the RL env runs
(:func:`~kddrl_trl.envs.highwayenv.highway_settings`: lanes, ``vehicles_count``, ``vehicles_density``, simulation
frequency). In it the ego is replaced by one more of HighwayEnv's ``other_vehicles_type`` vehicles, its behaviour
randomised as highway-v0 randomises the others', so every vehicle drives by HighwayEnv's own models. highway-v0
inserts no vehicle during an episode; a vehicle that crashes leaves the road at once (HighwayEnv stops a crashed
vehicle where it is, which would block its lane for the rest of the episode). The vehicles of an episode end their
tracks at its end and the next episode's vehicles start new ones.

Each policy step (``step_length``, 0.1 s) is one sample of every vehicle in :mod:`.sumo_to_highd`'s sample format
and the same code turns the samples into the 25 Hz HighD tables. Coordinates: x is HighwayEnv's x along the road
and the field of view is the whole road (every vehicle is in view); lateral positions, speeds and lanes are mapped
as :mod:`kddrl_trl.envs.highwayenv` maps them (lane 0 = rightmost; a vehicle's lane is the lane its centre is in,
so it switches half way through a lane change, as SUMO's; at 25 Hz too, as HighwayEnv's switches fall between
samples); the acceleration is the one HighwayEnv executed (``action["acceleration"]``
after its speed limits).

``XX_driverParams.csv`` holds HighwayEnv's IDM parameters per vehicle: ``v0`` its target speed, ``T``
``TIME_WANTED``, ``s0`` the bumper-to-bumper part of ``DISTANCE_WANTED`` (HighwayEnv measures the desired gap
between centres), ``a`` ``COMFORT_ACC_MAX`` and ``b`` ``-COMFORT_ACC_MIN``; the driver type is ``unknown``
(HighwayEnv has no driver classes).
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from ..envs.highwayenv import (
    highway_settings,
    highwayenv_drives_ego,
    make_highway,
)
from ..envs.observe import lane_and_offset
from ..highway_config import HighwayConfig
from ..highwayenv_options import HW_ROAD_LENGTH, HighwayEnvOptions, check_config
from .sumo_to_highd import RecordedTraffic, _build_recording, recording_steps

log = logging.getLogger(__name__)

__all__ = ["record_highwayenv_traffic"]


def _params(vehicle) -> dict:
    """The true IDM parameters of a HighwayEnv vehicle (module docstring)."""
    return {
        "driver": "unknown",
        "v0": float(vehicle.target_speed),
        "T": float(vehicle.TIME_WANTED),
        "s0": float(vehicle.DISTANCE_WANTED - vehicle.LENGTH),
        "a": float(vehicle.COMFORT_ACC_MAX),
        "b": float(-vehicle.COMFORT_ACC_MIN),
    }


class _Episodes:
    """Samples one recording's episodes: ``rows`` (per sample ``[g, k, front, x_lat, v, v_lat, a, lane]``),
    ``names`` (vehicle g's name ``"<recording>.<episode>.<i>"``) and ``params`` (name -> :func:`_params`)."""

    def __init__(self, cfg: HighwayConfig, recording: int):
        self.cfg, self.recording = cfg, recording
        self.rows: list[np.ndarray] = []
        self.names: list[str] = []
        self.params: dict[str, dict] = {}
        self.crashed = 0
        self._index: dict[int, int] = {}

    def start(self, env, episode: int) -> None:
        self._index = {}
        for i, v in enumerate(env.road.vehicles):
            name = f"{self.recording}.{episode}.{i}"
            self._index[id(v)] = len(self.names)
            self.names.append(name)
            self.params[name] = _params(v)

    def sample(self, env, k: int) -> None:
        crashed = [v for v in env.road.vehicles if v.crashed]
        if crashed:
            self.crashed += len(crashed)
            env.road.vehicles = [v for v in env.road.vehicles if not v.crashed]
        n, w = self.cfg.num_lanes, self.cfg.lane_width
        rows = np.array(
            [
                (
                    self._index[id(v)],
                    k,
                    v.position[0] + v.LENGTH / 2.0,
                    (n - 0.5) * w - v.position[1],
                    v.velocity[0],
                    -v.velocity[1],
                    v.action.get("acceleration", 0.0) if v.action else 0.0,
                    0.0,
                )
                for v in env.road.vehicles
            ],
            np.float64,
        ).reshape(-1, 8)
        rows[:, 7] = lane_and_offset(rows[:, 3], w, n)[0]  # the lane of the centre, as the adapter reads it
        self.rows.append(rows)


def record_highwayenv_traffic(
    cfg: HighwayConfig,
    duration_s: float,
    num_roads: int = 4,
    seed: int = 0,
    progress: bool = True,
    options: HighwayEnvOptions | dict | None = None,
) -> list[RecordedTraffic]:
    """Record ``num_roads`` recordings (ids 1..K) of ``duration_s`` simulated seconds of HighwayEnv traffic on
    ``cfg`` with ``options`` (:class:`~kddrl_trl.highwayenv_options.HighwayEnvOptions`), in the HighD format at 25 Hz
    (module docstring). The same arguments as :func:`~kddrl_trl.data.sumo_to_highd.record_traffic`, which records
    our SUMO traffic."""
    from highway_env.vehicle.kinematics import Vehicle
    from tqdm.auto import tqdm

    options = check_config(cfg, options)
    if cfg.vehicle_length != Vehicle.LENGTH:  # the boxes written are env.vehicle_length long
        raise ValueError(
            f"env.vehicle_length={cfg.vehicle_length} m, but HighwayEnv's vehicles are {Vehicle.LENGTH} m long: "
            f"set env.vehicle_length={Vehicle.LENGTH}"
        )
    dt = cfg.step_length
    num_steps, num_frames = recording_steps(duration_s, num_roads, dt)
    episode_steps = max(1, round(options.record_episode_s / dt))
    substeps = round(options.simulation_frequency * dt)
    config, action = highway_settings(cfg, options)
    env = make_highway(config, action)
    # every vehicle is in view
    view = replace(cfg, section_length=HW_ROAD_LENGTH, entry_length=0.0, exit_length=0.0)
    out, crashed = [], 0
    with tqdm(
        total=round(num_roads * num_steps * dt),
        unit="s",
        desc="recording HighwayEnv",
        disable=not progress,
        bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} simulated s [{elapsed}<{remaining}]",
    ) as bar:
        for r in range(int(num_roads)):
            episodes = _Episodes(cfg, r)
            for k in range(num_steps + 1):
                if k % episode_steps == 0:
                    e = k // episode_steps
                    env.reset(seed=int(np.random.SeedSequence([int(seed), r, e]).generate_state(1)[0]))
                    highwayenv_drives_ego(env)
                    episodes.start(env, e)
                else:
                    for _ in range(substeps):
                        env.road.act()
                        env.road.step(1.0 / options.simulation_frequency)
                episodes.sample(env, k)
                if k % 10 == 0:
                    bar.update(round(r * num_steps * dt + k * dt - bar.n, 6))
            rows = np.concatenate(episodes.rows)
            out.append(
                _build_recording(
                    view,
                    r,
                    rows,
                    episodes.names,
                    episodes.params,
                    duration_s,
                    num_frames,
                    seed,
                    y_lat_offset=0.0,
                    lanes_from_position=True,
                )
            )
            crashed += episodes.crashed
    env.close()
    if crashed:
        log.info("%d HighwayEnv vehicles crashed and left the road during the recordings", crashed)
    return out
