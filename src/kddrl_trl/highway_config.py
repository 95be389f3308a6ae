"""Configuration of the SUMO highway: road, traffic, driver population, ego, rewards, scenarios.

One dataclass holds every default, with its unit, in one place (paper Table A.1, docs/design.md, "Traffic
model"). The same schema validates Hydra configs (``conf/env/highway.yaml``) and keyword overrides of
:class:`~kddrl_trl.envs.SumoHighwayEnv`, so a misspelt key or a malformed value fails before SUMO starts
with a message naming the key.

Scenarios (``baseline``, ``congested``, ``congested_text``, ``braking``, ``mixed``) are the presets of
:data:`SCENARIOS`, defined once here: ``SumoHighwayEnv(scenario="braking")`` / ``make_config("braking")`` apply them,
and ``kddrl_trl.conf`` registers each as the Hydra option ``+scenario=<name>`` (an ``env:`` block in the global
package), which Hydra applies while composing; a config built from the composed ``env`` node is not given its preset
again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

KMH = 1.0 / 3.6
#: values of ``HighwayConfig.ego_start``
EGO_STARTS = ("entry", "window")
#: values of ``HighwayConfig.reward``: the reward variants of envs/rewards.py
REWARDS = ("paper", "safe")


@dataclass
class DriverClass:
    """One type of human driver: IDM parameters (paper Eq. 11-12) and SUMO LC2013 lane-change eagerness.

    Each background vehicle draws its class with probability ``share``, then every IDM parameter from a
    normal distribution around the class value with relative standard deviation ``spread`` (truncated at
    ±2 sd). The drawn values are recorded per vehicle (``SumoHighwayEnv.vehicle_params``).
    """

    name: str = "normal"
    share: float = 1.0
    v0: float = 130 * KMH  # desired speed (m/s)
    T: float = 1.5  # desired time headway (s)
    s0: float = 5.0  # minimum gap (m)
    a: float = 5.0  # maximum acceleration (m/s²)
    b: float = 4.0  # comfortable deceleration (m/s²)
    lc_speed_gain: float = 1.0  # SUMO lcSpeedGain: eagerness for lane changes that gain speed
    lc_keep_right: float = 1.0  # SUMO lcKeepRight: eagerness to return to the right lane
    spread: float = 0.05  # relative sd of the per-vehicle draw around the class values


def default_drivers() -> list[DriverClass]:
    """Three classes around Table A.1 (the 'normal' class *is* Table A.1; shares weight it as the centre).

    Lane-change eagerness (SUMO LC2013 ``lcSpeedGain``, ``lcKeepRight``) is calibrated so that the share of
    vehicles changing lane within the 420 m section is close to HighD's (15.8 %, paper §IV.B): with SUMO's
    defaults (1, 1) only ~4 % of our drivers changed lane. This is a calibration target, not a result.
    """
    return [
        DriverClass("timid", 0.25, v0=115 * KMH, T=2.0, s0=6.0, a=3.5, b=3.0, lc_speed_gain=3.0, lc_keep_right=3.0),
        DriverClass("normal", 0.50, v0=130 * KMH, T=1.5, s0=5.0, a=5.0, b=4.0, lc_speed_gain=8.0, lc_keep_right=2.0),
        DriverClass(
            "aggressive", 0.25, v0=145 * KMH, T=1.0, s0=4.0, a=6.5, b=5.0, lc_speed_gain=15.0, lc_keep_right=1.5
        ),
    ]


#: how the braking car drives on after standing (:attr:`BrakingEvent.release`)
RELEASES = ("sumo", "programmed")


@dataclass
class BrakingEvent:
    """Scenario 2 (paper §IV.D): a leader in the ego's lane brakes hard to a stop, stands, then resumes.

    ``probability`` (a mixed-traffic curriculum, not in the paper, whose braking scenario has the event in
    every episode): when ``enabled``, each episode has the event with this probability, drawn per episode and per
    road from the road's seeded random stream (:class:`~kddrl_trl.envs.braking.BrakingEvents`), so a seed gives the
    same mix every time. 1.0 draws nothing: the stream, and every run saved before the key existed, is unchanged.
    """

    enabled: bool = False
    probability: float = 1.0  # share of episodes with the event when enabled (scenario mixed: 0.5)
    min_distance: float = 100.0  # m ahead of the ego (front bumper to front bumper)
    max_distance: float = 300.0  # m
    decel: float = 8.0  # m/s², hard braking
    stand_time: float = 3.0  # s standing still
    trigger_frames: int = 50  # frames after the episode start within which the event must begin
    # how the car drives on after standing (paper: "and then gradually resume its normal speed"):
    # sumo: handed back to SUMO at once (its own IDM acceleration, up to its class's a, and its own lane changes)
    # programmed: kept in its lane and brought back to the speed it had before braking at resume_accel, then
    #   handed back to SUMO
    release: str = "sumo"
    resume_accel: float = 2.0  # m/s², programmed release (ISO 15622's bound on an ACC's acceleration)


@dataclass
class HighwayConfig:
    """Everything that defines the simulated highway. Units in the comments; defaults = paper Table A.1."""

    scenario: str = "baseline"
    # --- road (Table A.1)
    num_lanes: int = 3
    section_length: float = 420.0  # m, the study section; the ego's episode ends when it leaves it
    entry_length: float = 300.0  # m of road before the section, where traffic settles and the ego is picked
    exit_length: float = 150.0  # m after the section
    lane_width: float = 3.2  # m
    v_min: float = 72 * KMH  # m/s, lower speed limit (reward Eq. 27)
    v_max: float = 180 * KMH  # m/s, upper speed limit = SUMO lane speed (reward Eq. 27)
    step_length: float = 0.1  # s per frame
    lc_duration: float = 2.0  # s per lane-change manoeuvre (ego and background)
    vehicle_length: float = 5.0  # m, every vehicle
    # --- traffic
    flow_vph: float = 2325.0  # veh/h entering each road over all lanes (Table A.1; 3 x 886 = 2658 also valid)
    flow_scale: float = 1.0  # multiplier on flow_vph (congested = 1.5)
    drivers: list[DriverClass] = field(default_factory=default_drivers)
    warmup_s: float = 40.0  # s of simulated traffic before the first episode
    # --- ego
    sensing_range: float = 200.0  # m, neighbours further away are absent (mask False)
    history_len: int = 10  # frames of leader history
    max_steps: int = 1000  # frames before truncation
    accel_low: float = -5.0  # m/s² (Eq. 31)
    accel_high: float = 5.0  # m/s²
    pick_window: float = 150.0  # m before the section in which the ego is designated
    ego_start: str = "entry"  # entry: the vehicle nearest the section entry in the pick window (the next to
    #                                enter the study area, paper §IV.B) | window: any vehicle in it
    ego_lane: int | None = None  # start lane of the ego (None = any)
    # --- rewards (Eq. 26-29, 32-33)
    collision_penalty: float = -100.0
    lane_change_penalty: float = -1.0
    accel_comfort: float = 4.0  # m/s², |a| above it is penalised quadratically
    reward: str = "paper"  # paper: Eq. 26-29, 32-33 as written | safe: no -1 below v_min (envs/rewards.py)
    # --- scenario events
    braking: BrakingEvent = field(default_factory=BrakingEvent)

    @property
    def flow(self) -> float:
        """Vehicles per hour actually inserted per road."""
        return self.flow_vph * self.flow_scale

    @property
    def road_length(self) -> float:
        return self.entry_length + self.section_length + self.exit_length

    def validate(self) -> "HighwayConfig":
        """Range checks; raise ``ValueError`` naming the offending key."""
        positive = (
            "section_length",
            "entry_length",
            "exit_length",
            "lane_width",
            "v_max",
            "step_length",
            "lc_duration",
            "vehicle_length",
            "flow_scale",
            "sensing_range",
            "pick_window",
        )
        for key in positive:
            _check(key, getattr(self, key), getattr(self, key) > 0, "must be > 0")
        _check("flow_vph", self.flow_vph, self.flow_vph >= 0, "must be >= 0 (vehicles per hour)")
        _check("num_lanes", self.num_lanes, self.num_lanes >= 1, "must be >= 1")
        _check("v_min", self.v_min, 0 <= self.v_min < self.v_max, "must satisfy 0 <= v_min < v_max")
        _check("warmup_s", self.warmup_s, self.warmup_s >= 0, "must be >= 0")
        _check("history_len", self.history_len, self.history_len >= 1, "must be >= 1")
        _check("max_steps", self.max_steps, self.max_steps >= 1, "must be >= 1")
        _check("accel_low", self.accel_low, self.accel_low < 0 < self.accel_high, "need accel_low < 0 < accel_high")
        _check("pick_window", self.pick_window, self.pick_window <= self.entry_length, "must be <= entry_length")
        _check("ego_start", self.ego_start, self.ego_start in EGO_STARTS, f"must be one of {', '.join(EGO_STARTS)}")
        _check("reward", self.reward, self.reward in REWARDS, f"must be one of {', '.join(REWARDS)}")
        if self.ego_lane is not None:
            _check(
                "ego_lane",
                self.ego_lane,
                0 <= self.ego_lane < self.num_lanes,
                f"must be in [0, {self.num_lanes - 1}] (num_lanes={self.num_lanes})",
            )
        lc_frames = self.lc_duration / self.step_length
        _check(
            "lc_duration",
            self.lc_duration,
            abs(lc_frames - round(lc_frames)) < 1e-6,
            f"must be a whole number of steps of {self.step_length} s",
        )
        if not self.drivers:
            raise ValueError("drivers: at least one driver class is required")
        names = [d.name for d in self.drivers]
        if len(set(names)) != len(names):
            raise ValueError(f"drivers: class names must be unique, got {names}")
        for i, d in enumerate(self.drivers):
            for key in ("share", "v0", "T", "s0", "a", "b"):
                value = getattr(d, key)
                _check(f"drivers[{i}].{key}", value, value > 0 and math.isfinite(value), "must be finite and > 0")
            _check(f"drivers[{i}].spread", d.spread, 0 <= d.spread < 0.5, "must be in [0, 0.5)")
        br = self.braking
        _check(
            "braking.min_distance",
            br.min_distance,
            0 < br.min_distance <= br.max_distance,
            "need 0 < min_distance <= max_distance",
        )
        _check("braking.decel", br.decel, br.decel > 0, "must be > 0")
        _check("braking.stand_time", br.stand_time, br.stand_time >= 0, "must be >= 0")
        _check("braking.trigger_frames", br.trigger_frames, br.trigger_frames >= 1, "must be >= 1")
        _check("braking.release", br.release, br.release in RELEASES, f"must be one of {RELEASES}")
        _check(
            "braking.resume_accel",
            br.resume_accel,
            br.resume_accel > 0 and math.isfinite(br.resume_accel),
            "must be finite and > 0",
        )
        _check(
            "braking.probability",
            br.probability,
            0 < br.probability <= 1,
            "must be in (0, 1] (the share of episodes with the event; braking.enabled=false for none)",
        )
        return self


def _check(key: str, value: Any, ok: bool, why: str) -> None:
    if not ok:
        raise ValueError(f"highway config: '{key}' = {value!r} {why}")


#: the scenario presets: HighwayConfig fields each scenario sets (every other field keeps its default)
SCENARIOS: dict[str, dict[str, Any]] = {
    # baseline traffic (paper §IV.C, Table A.1): 2325 veh/h over 3 lanes, heterogeneous IDM drivers
    "baseline": {},
    # scenario 1 (paper §IV.D): traffic flow +50 % over the baseline: 1.5 x 2325 = 3487 veh/h (Table A.1's flow)
    "congested": {"flow_scale": 1.5},
    # scenario 1 as the text quotes it: "from 886 veh/h/lane to 1329 veh/h/lane", 1.5 x 3 x 886 = 3987 veh/h
    "congested_text": {"flow_vph": 2658.0, "flow_scale": 1.5},
    # scenario 2 (paper §IV.D): in every episode a leader 100-300 m ahead of the ego in its lane brakes hard
    # to a stop, stands 3 s, then resumes
    "braking": {"braking": {"enabled": True, "min_distance": 100.0, "max_distance": 300.0, "stand_time": 3.0}},
    # training curriculum (not in the paper): half of the episodes are scenario 2's, half the baseline's
    # (drawn per episode and road from the seeded stream); evaluate on each with eval_scenarios=[baseline,braking]
    "mixed": {
        "braking": {
            "enabled": True,
            "min_distance": 100.0,
            "max_distance": 300.0,
            "stand_time": 3.0,
            "probability": 0.5,
        }
    },
}


def scenario_names() -> list[str]:
    """The scenarios of :data:`SCENARIOS`."""
    return sorted(SCENARIOS)


def make_config(
    scenario: str | HighwayConfig = "baseline", overrides: Mapping[str, Any] | None = None
) -> HighwayConfig:
    """Build a validated :class:`HighwayConfig`: a scenario's preset (or a ready config) plus keyword overrides.

    ``scenario`` is a name of :data:`SCENARIOS` (its preset applies under the overrides), or a
    :class:`HighwayConfig` used as it is (e.g. one built from the composed Hydra ``env`` node, whose
    ``+scenario=`` Hydra already applied: no preset is applied again). Unknown keys and values of the wrong type
    raise ``ValueError`` naming the key; nothing starts SUMO. ``overrides`` may be a dict, a DictConfig, or
    contain a ``scenario`` key (which is then used).
    """
    overrides = dict(OmegaConf.to_container(OmegaConf.create(dict(overrides or {})), resolve=True))
    scenario = overrides.pop("scenario", scenario)
    if isinstance(scenario, HighwayConfig):
        base, name = OmegaConf.structured(scenario), scenario.scenario
    elif isinstance(scenario, str):
        if scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {scenario!r}; known scenarios: {', '.join(scenario_names())}")
        base, name = SCENARIOS[scenario], scenario
    else:
        raise ValueError(f"highway config: 'scenario' must be a string, got {scenario!r}")
    try:
        merged = OmegaConf.merge(OmegaConf.structured(HighwayConfig), base, overrides)
    except OmegaConfBaseException as err:  # unknown key, wrong type, ...
        key = getattr(err, "full_key", None) or "?"
        reason = str(getattr(err, "msg", err)).splitlines()[0]
        raise ValueError(f"highway config: bad value for key '{key}': {reason}") from None
    cfg: HighwayConfig = OmegaConf.to_object(merged)
    cfg.scenario = name
    return cfg.validate()


def _preset_paths(preset: Mapping[str, Any], prefix: tuple = ()) -> list[tuple]:
    out = []
    for key, value in preset.items():
        out += _preset_paths(value, (*prefix, key)) if isinstance(value, Mapping) else [(*prefix, key)]
    return out


def scenario_label(name: str, simulator: str) -> str:
    """The ``scenario`` a preset gives an env node of ``simulator``: the preset's name on our SUMO highway,
    ``<simulator>_<name>`` on another simulator (``env=highwayenv +scenario=congested`` is ``highwayenv_congested``),
    so that run folders and reports never pool another simulator's runs with the SUMO scenario of that name."""
    return name if simulator == "sumo" else f"{simulator}_{name}"


def preset_name(label: str) -> str | None:
    """The :data:`SCENARIOS` preset behind a scenario label (:func:`scenario_label`), None for a label of none
    (``highwayenv``, an env node's own name)."""
    if label in SCENARIOS:
        return label
    tail = label.split("_", 1)[-1]
    return tail if "_" in label and tail in SCENARIOS else None


def switch_scenario(values: Mapping[str, Any], scenario: str) -> dict:
    """The env ``values`` (a dict or DictConfig of :class:`HighwayConfig` fields, e.g. a composed ``env`` node, whose
    ``scenario`` preset is already applied) moved to another ``scenario``: every key the current scenario's preset
    sets goes back to its schema default, then ``scenario`` 's preset applies; every other key (``num_roads``,
    ``ego_start``, a ``flow_vph`` given on the command line, ...) is kept. How a run trained on one scenario
    (``mixed``) is evaluated on others (``eval_scenarios`` of ``kddrl_trl.train``)."""
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; known scenarios: {', '.join(scenario_names())}")
    out = OmegaConf.create(OmegaConf.to_container(OmegaConf.create(dict(values)), resolve=True))
    defaults = OmegaConf.structured(HighwayConfig)
    for path in _preset_paths(SCENARIOS.get(preset_name(str(out.get("scenario", "baseline"))) or "", {})):
        OmegaConf.update(out, ".".join(path), OmegaConf.select(defaults, ".".join(path)), merge=False)
    label = scenario_label(scenario, str(out.get("simulator", "sumo")))  # an env node names its simulator
    out = OmegaConf.merge(out, SCENARIOS[scenario], {"scenario": label})
    return OmegaConf.to_container(out)
