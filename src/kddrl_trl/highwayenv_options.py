"""What only HighwayEnv has: the options of the HighwayEnv adapter (:mod:`kddrl_trl.envs.highwayenv`, the
``env.highwayenv`` node of ``conf/env/highwayenv.yaml``) and HighwayEnv's own road facts, with the check of both
against a :class:`~kddrl_trl.highway_config.HighwayConfig`. Pure Python, so that the schema checks a config before
HighwayEnv (an optional dependency) or torch is imported.
"""

from __future__ import annotations

from dataclasses import dataclass

from .highway_config import HighwayConfig

#: HighwayEnv's lane width (``StraightLane.DEFAULT_WIDTH``, m) and perception distance (``AbstractEnv``, m)
HW_LANE_WIDTH = 4.0
HW_PERCEPTION = 200.0
#: length of HighwayEnv's straight road (``RoadNetwork.straight_road_network``'s default, m)
HW_ROAD_LENGTH = 10_000.0
#: who drives the ego (``HighwayEnvOptions.ego_driver``): the policy, HighwayEnv's own IDM/MOBIL vehicle, or that
#: vehicle with its lane kept (its IDM only)
EGO_DRIVERS = ("agent", "highwayenv", "highwayenv_idm")


@dataclass
class HighwayEnvOptions:
    """What only HighwayEnv has (the ``env.highwayenv`` node of ``conf/env/highwayenv.yaml``)."""

    vehicles_count: int = 30  # background vehicles per episode (highway-v0: 50), all placed ahead of the ego
    #                                 about 23 m apart: the 30th starts ~700 m ahead, beyond what a 420 m episode
    #                                 brings within the 200 m sensing range; HighwayEnv's cost grows as n²
    vehicles_density: float = 1.0  # highway-v0's spacing factor (x env.flow_scale)
    observed_vehicles: int = 15  # rows of the Kinematics observation, the ego included
    simulation_frequency: int = 10  # Hz; a multiple of the policy frequency 1/step_length (10 Hz)
    lc_done_offset: float = 0.2  # m from the target lane's centre line at which a lane change is over
    ego_driver: str = "agent"  # agent: the policy's commands drive the ego | highwayenv: HighwayEnv's own IDM/MOBIL
    #                            vehicle drives it (the commands are ignored), a reference driver | highwayenv_idm:
    #                            the same vehicle with its lane kept (IDM only)
    record_episode_s: float = 60.0  # s: a recording of HighwayEnv traffic (kddrl_trl.data.highwayenv_to_highd) is
    #                                 a sequence of highway-v0 episodes of this length, each from a fresh reset

    def validate(self, cfg: HighwayConfig) -> "HighwayEnvOptions":
        """Range checks, and the :class:`HighwayConfig` values HighwayEnv cannot honour; ``ValueError`` naming the
        key."""

        def need(key: str, ok: bool, why: str) -> None:
            if not ok:
                raise ValueError(f"highwayenv config: '{key}' {why}")

        need("highwayenv.vehicles_count", self.vehicles_count >= 0, f"= {self.vehicles_count!r} must be >= 0")
        need("highwayenv.vehicles_density", self.vehicles_density > 0, f"= {self.vehicles_density!r} must be > 0")
        need("highwayenv.observed_vehicles", self.observed_vehicles >= 2, f"= {self.observed_vehicles!r} must be >= 2")
        need("highwayenv.lc_done_offset", self.lc_done_offset > 0, f"= {self.lc_done_offset!r} must be > 0 (m)")
        need(
            "highwayenv.ego_driver",
            self.ego_driver in EGO_DRIVERS,
            f"= {self.ego_driver!r}: known drivers are {', '.join(EGO_DRIVERS)}",
        )
        need(
            "highwayenv.record_episode_s",
            0 < self.record_episode_s * cfg.v_max <= HW_ROAD_LENGTH / 2,
            f"= {self.record_episode_s!r} s must be > 0 and short enough that traffic at v_max = {cfg.v_max} m/s "
            f"covers at most half of HighwayEnv's {HW_ROAD_LENGTH:g} m road",
        )
        hz = 1.0 / cfg.step_length
        need(
            "step_length",
            abs(hz - round(hz)) < 1e-6,
            f"= {cfg.step_length!r} s must give a whole policy "
            "frequency in Hz (HighwayEnv's policy_frequency is an int)",
        )
        need(
            "highwayenv.simulation_frequency",
            self.simulation_frequency >= 1 and self.simulation_frequency % round(hz) == 0,
            f"= {self.simulation_frequency!r} must be a multiple of the policy frequency {round(hz)} Hz",
        )
        need(
            "lane_width",
            cfg.lane_width == HW_LANE_WIDTH,
            f"= {cfg.lane_width!r}: HighwayEnv's lanes are {HW_LANE_WIDTH} m wide (set env.lane_width={HW_LANE_WIDTH})",
        )
        need(
            "sensing_range",
            cfg.sensing_range <= HW_PERCEPTION,
            f"= {cfg.sensing_range!r} m is beyond HighwayEnv's perception distance ({HW_PERCEPTION} m)",
        )
        need("braking.enabled", not cfg.braking.enabled, "= True: HighwayEnv has no braking event (scenario braking)")
        return self


def check_config(cfg: HighwayConfig, options: HighwayEnvOptions | dict | None = None) -> HighwayEnvOptions:
    """The validated options of an adapter on ``cfg`` (before any HighwayEnv starts)."""
    if options is None:
        options = HighwayEnvOptions()
    elif not isinstance(options, HighwayEnvOptions):
        options = HighwayEnvOptions(**dict(options))
    return options.validate(cfg)
