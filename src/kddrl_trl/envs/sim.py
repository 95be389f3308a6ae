"""``HighwaySim``: K independent study roads in one libsumo simulation, one ego per road, numpy in and out.

This is the simulator core under :class:`~kddrl_trl.envs.SumoHighwayEnv`; it has no TorchRL in it, so the
throughput benchmark can measure the simulator's own limit with exactly the same per-ego queries.

Ego control (paper §III.G, Eq. 25 and 31):

* The ego is a background vehicle designated at reset: one chosen at random among those driving in the
  last ``pick_window`` metres of the entry stretch, not changing lanes (paper §IV.C: "one vehicle is
  randomly designated as the controlled ego AV in each episode"). From then on SUMO's speed and
  lane-change safety overrides are off for it (speed mode 0, lane-change mode 0), so a bad command
  really collides and SUMO's collision detection reports it.
* Acceleration: every frame v' = max(v + a·dt, 0) with a clipped to [accel_low, accel_high]; the
  executed acceleration (v' - v)/dt is what the observation and the comfort reward use.
* Lane change: a left/right command starts a ``lc_duration`` manoeuvre (SUMO's continuous lane change,
  20 frames) if no manoeuvre is in progress and the target lane exists. Otherwise the command is a no-op
  (the lane is kept); ``action_mask`` says which commands would be executed now.
* The episode ends *terminated* on a collision or when the ego leaves the study section
  (y > section_length), *truncated* after ``max_steps`` frames or when SUMO loses the ego (an error,
  logged and counted in ``stats``). A finished ego drives on as an ordinary human driver.
"""
from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .. import keys as K
from .config import HighwayConfig
from .network import build_road_files, edge_ids, sumo_args
from .rewards import car_following_reward, lane_change_reward

log = logging.getLogger(__name__)

_ACTIVE: "HighwaySim | None" = None  # libsumo holds one simulation per process
SPEED_MODE_DEFAULT, LC_MODE_DEFAULT = 31, 1621
_BRAKE_SEEK, _BRAKE_BRAKING, _BRAKE_STANDING, _BRAKE_DONE = 0, 1, 2, 3


def _libsumo():
    import libsumo

    return libsumo


@dataclass
class EpisodeStats:
    """Running sums of one ego episode, turned into the per-episode metrics of evaluation."""

    road: int
    ego: str
    driver: str
    index: int  # episodes are numbered in the order they start
    frames: int = 0
    speed_sum: float = 0.0
    speed_sq_sum: float = 0.0
    accel_sum: float = 0.0
    accel_sq_sum: float = 0.0
    abs_accel_sum: float = 0.0
    lane_changes: int = 0
    return_lc: float = 0.0
    return_cf: float = 0.0
    braking_distance: float = float("nan")
    extra: dict = field(default_factory=dict)

    def finish(self, outcome: str) -> dict:
        n = max(self.frames, 1)
        return {
            "index": self.index, "road": self.road, "ego": self.ego, "driver": self.driver, "frames": self.frames,
            "mean_speed": float(self.speed_sum / n), "mean_speed_kmh": float(3.6 * self.speed_sum / n),
            "mean_accel": float(self.accel_sum / n), "mean_abs_accel": float(self.abs_accel_sum / n),
            "mean_sq_speed": float(self.speed_sq_sum / n), "mean_sq_accel": float(self.accel_sq_sum / n),
            "lane_changes": self.lane_changes, "collision": outcome == "collision",
            "outcome": outcome, "return_lc": self.return_lc, "return_cf": self.return_cf,
            "braking_distance": self.braking_distance, **self.extra,
        }


class HighwaySim:
    """K disconnected copies of the road in one SUMO simulation; numpy arrays of shape [K, ...] out.

    Args:
        cfg: validated :class:`HighwayConfig`.
        num_roads: K >= 1.
        seed: seeds SUMO (traffic arrivals, driver classes) and the numpy generator (per-vehicle
            parameter draws, ego designation, braking events). Same seed -> identical rollouts.
    """

    def __init__(self, cfg: HighwayConfig, num_roads: int, seed: int = 0):
        if not isinstance(num_roads, (int, np.integer)) or num_roads < 1:
            raise ValueError(f"num_roads must be an integer >= 1, got {num_roads!r}")
        self.cfg, self.num_roads = cfg, int(num_roads)
        self.dt = cfg.step_length
        self.lc_frames = int(round(cfg.lc_duration / cfg.step_length))
        self.files = build_road_files(cfg, self.num_roads)
        self.stats = {"episodes": 0, "collisions": 0, "sumo_errors": 0, "insert_steps": 0,
                      "braking_events": 0, "braking_missed": 0, "braking_inserted": 0,
                      "designation_fallbacks": 0}
        self.episodes: list[dict] = []        # finished-episode metrics, in order of completion
        self.vehicle_params: dict[str, dict] = {}  # per background vehicle: driver class and IDM draw
        self._started = False
        self.seed = int(seed)
        self._start(self.seed)

    # ------------------------------------------------------------------------------------ lifecycle
    def _alloc(self) -> None:
        k, h = self.num_roads, self.cfg.history_len
        self.obs = {
            K.EGO_STATE: np.zeros((k, 3), np.float32), K.EGO_LANE: np.zeros((k, 1), np.int64),
            K.EGO_ACCEL: np.zeros((k, 1), np.float32), K.NEIGHBORS_REL: np.zeros((k, 6, 4), np.float32),
            K.NEIGHBORS_MASK: np.zeros((k, 6), bool), K.NEIGHBORS_KIN: np.zeros((k, 6, 3), np.float32),
            K.LEADERS_AHEAD: np.zeros((k, 3, 3), np.float32),
            K.LEADERS_HISTORY: np.zeros((k, 3, h, 2), np.float32),
            K.LC_ACTION_MASK: np.ones((k, 3), bool), K.LC_ACTIVE: np.zeros((k, 1), bool),
            K.LC_STARTED: np.zeros((k, 1), bool), K.COLLISION: np.zeros((k, 1), bool),
        }
        self.reward_lc = np.zeros((k, 1), np.float32)
        self.reward_cf = np.zeros((k, 1), np.float32)
        self.terminated = np.zeros((k, 1), bool)
        self.truncated = np.zeros((k, 1), bool)
        self.ego: list[str | None] = [None] * k
        self.speed = np.zeros(k)
        self.frame = np.zeros(k, np.int64)
        self.lc_left = np.zeros(k, np.int64)   # frames left in the ego's manoeuvre
        self.episode: list[EpisodeStats | None] = [None] * k
        self.brake = [dict(phase=_BRAKE_DONE) for _ in range(k)]
        self.history: list[dict[str, deque]] = [{} for _ in range(k)]

    def _start(self, seed: int) -> None:
        global _ACTIVE
        ls = _libsumo()
        if _ACTIVE is not None and _ACTIVE is not self:
            raise RuntimeError("libsumo runs one simulation per process and another HighwaySim/SumoHighwayEnv "
                               "is open: close() it first, or run several envs in separate processes "
                               "(torchrl ParallelEnv) or as roads of one env (num_roads=K)")
        args = sumo_args(self.cfg, self.files, seed)
        if self._started:
            ls.load(args[1:])
        else:
            ls.start(args)
        _ACTIVE, self._started = self, True
        # one random stream per road (arrivals, driver draws, ego designation, braking): a road's traffic
        # never depends on what happens on another road
        self.rngs = [np.random.default_rng([int(seed), r]) for r in range(self.num_roads)]
        self.rate = self.cfg.flow / 3600.0  # vehicles per second per road
        self.next_arrival = np.array([self._interarrival(r) for r in range(self.num_roads)])
        self.arrivals = np.zeros(self.num_roads, np.int64)
        self.t = 0
        self.vehicle_params.clear()
        self.episodes.clear()
        self._alloc()
        self._released: set[str] = set()
        self.episodes_started = 0
        for _ in range(int(round(self.cfg.warmup_s / self.dt))):
            self._sim_step()

    def reseed(self, seed: int) -> None:
        """Restart the simulation from scratch with a new seed (warm-up included)."""
        self.seed = int(seed)
        self._start(self.seed)

    def close(self) -> None:
        global _ACTIVE
        if self._started:
            _libsumo().close()
            self._started = False
        if _ACTIVE is self:
            _ACTIVE = None

    @property
    def closed(self) -> bool:
        return not self._started

    # ----------------------------------------------------------------------------------- traffic
    def _sim_step(self) -> set[str]:
        """One SUMO step; configure departing humans; return the ids that collided in this step."""
        ls = _libsumo()
        now = self.t * self.dt
        for r in np.flatnonzero(self.next_arrival <= now):
            while self.next_arrival[r] <= now:
                self._add_human(int(r))
                self.next_arrival[r] += self._interarrival(int(r))
        ls.simulationStep()
        self.t += 1
        if self.t % 200 == 0:
            self._forget_old()
        return set(ls.simulation.getCollidingVehiclesIDList())

    def _interarrival(self, r: int) -> float:
        """Poisson arrivals: exponential gaps with mean 3600 / flow seconds (inf when the flow is 0)."""
        return float(self.rngs[r].exponential(1.0 / self.rate)) if self.rate > 0 else np.inf

    def _add_human(self, r: int, lane: int | None = None, route: str | None = None, pos: float | None = None,
                   prefix: str = "h") -> str:
        """Insert one human driver on road r (by default at the start of the road, in a uniformly random
        lane): driver class with probability ``share``, then each IDM parameter from a normal around the
        class value (sd = ``spread`` x value, truncated at ±2 sd); SUMO inserts it at the highest safe
        speed up to its desired speed. Returns its id; its parameters go to ``vehicle_params``."""
        ls, cfg, rng = _libsumo(), self.cfg, self.rngs[r]
        shares = np.array([d.share for d in cfg.drivers])
        cls = cfg.drivers[int(rng.choice(len(shares), p=shares / shares.sum()))]
        z = np.clip(rng.standard_normal(5), -2.0, 2.0)
        v0, T, s0, a, b = (float(base * (1.0 + cls.spread * zi))
                           for base, zi in zip((cls.v0, cls.T, cls.s0, cls.a, cls.b), z))
        lane = int(rng.integers(cfg.num_lanes)) if lane is None else lane
        vid = f"{prefix}{r}.{self.arrivals[r]}"
        self.arrivals[r] += 1
        ls.vehicle.add(vid, route or f"route_r{r}", typeID=cls.name, departLane=str(lane), departSpeed="max",
                       departPos="base" if pos is None else f"{pos:.2f}")
        ls.vehicle.setMaxSpeed(vid, v0)
        ls.vehicle.setTau(vid, T)
        ls.vehicle.setMinGap(vid, s0)
        ls.vehicle.setAccel(vid, a)
        ls.vehicle.setDecel(vid, b)
        self.vehicle_params[vid] = {"driver": cls.name, "v0": v0, "T": T, "s0": s0, "a": a, "b": b, "road": r,
                                    "lane": lane, "time": self.t * self.dt}
        return vid

    def _forget_old(self) -> None:
        horizon = self.t - self.cfg.history_len - 1
        for hist in self.history:
            for vid in [v for v, d in hist.items() if d[-1][0] < horizon]:
                del hist[vid]

    def road_vehicles(self, road: int) -> list[str]:
        ls = _libsumo()
        return [v for e in edge_ids(road) for v in ls.edge.getLastStepVehicleIDs(e)]

    def longitudinal(self, vid: str) -> float:
        """Front-bumper position along the road, metres from the start of the study section."""
        return _libsumo().vehicle.getPosition(vid)[0] - self.cfg.entry_length

    # ----------------------------------------------------------------------------------- episodes
    def reset_roads(self, roads) -> None:
        """Designate a new ego on each road in ``roads`` (a running episode there ends, unrecorded)."""
        roads = [int(r) for r in roads]
        pending = []
        for r in roads:
            if self.ego[r] is not None:
                self._end_episode(r, "reset")
            if not self._designate(r):
                pending.append(r)
        tries = 0
        while pending:  # no vehicle to designate (empty road): insert one; costs extra simulation steps
            if tries > 200:
                raise RuntimeError(f"could not place an ego on roads {pending} after {tries} steps")
            if tries % 50 == 0:
                for r in pending:
                    self._add_human(r, lane=self.cfg.ego_lane, pos=self.cfg.entry_length - self.cfg.pick_window,
                                    prefix="x")
            self.obs[K.LC_STARTED][self.ego_present] = False  # no command in an extra step
            collided = self._sim_step()
            self.stats["insert_steps"] += 1
            self._finish(self._after_step(collided, np.zeros(self.num_roads)))  # other egos keep their speed
            pending = [r for r in pending if not self._designate(r)]
            tries += 1
        self._observe(roads if tries == 0 else None)  # extra steps moved every road: observe them all

    def _designate(self, r: int) -> bool:
        ls = _libsumo()
        cfg = self.cfg
        e_in = edge_ids(r)[0]
        # tiers: in the pick window and keeping its lane; anywhere on the entry stretch keeping its lane;
        # anywhere on the entry stretch. Lower tiers are counted in stats["designation_fallbacks"].
        tiers: list[list[str]] = [[], [], []]
        for vid in ls.edge.getLastStepVehicleIDs(e_in):
            if vid in self._released:
                continue
            if cfg.ego_lane is not None and ls.vehicle.getLaneIndex(vid) != cfg.ego_lane:
                continue
            steady = ls.vehicle.getLateralSpeed(vid) == 0.0
            in_window = ls.vehicle.getLanePosition(vid) >= cfg.entry_length - cfg.pick_window
            tiers[0 if steady and in_window else 1 if steady else 2].append(vid)
        tier = next((i for i, t in enumerate(tiers) if t), None)
        if tier is None:
            return False
        cands = tiers[tier]
        self.stats["designation_fallbacks"] += int(tier > 0)
        vid = cands[int(self.rngs[r].integers(len(cands)))]
        ls.vehicle.setSpeedMode(vid, 0)
        ls.vehicle.setLaneChangeMode(vid, 0)
        ls.vehicle.setColor(vid, (255, 0, 0, 255))
        self.ego[r] = vid
        self.speed[r] = ls.vehicle.getSpeed(vid)
        ls.vehicle.setSpeed(vid, self.speed[r])
        self.frame[r] = 0
        self.lc_left[r] = 0
        driver = self.vehicle_params.get(vid, {}).get("driver", "inserted")
        self.episode[r] = EpisodeStats(road=r, ego=vid, driver=driver, index=self.episodes_started)
        self.episodes_started += 1
        self.terminated[r] = self.truncated[r] = False
        self.obs[K.EGO_ACCEL][r] = 0.0
        self.obs[K.COLLISION][r] = False
        self.obs[K.LC_STARTED][r] = False
        self.reward_lc[r] = self.reward_cf[r] = 0.0
        if cfg.braking.enabled:
            self.brake[r] = dict(phase=_BRAKE_SEEK, target=float(self.rngs[r].uniform(cfg.braking.min_distance,
                                                                                 cfg.braking.max_distance)))
        return True

    def _end_episode(self, r: int, outcome: str) -> None:
        ls = _libsumo()
        vid, ep = self.ego[r], self.episode[r]
        if vid is not None and outcome not in ("collision", "lost"):
            try:  # hand the car back to SUMO: it drives on as a human
                ls.vehicle.setSpeed(vid, -1)
                ls.vehicle.setSpeedMode(vid, SPEED_MODE_DEFAULT)
                ls.vehicle.setLaneChangeMode(vid, LC_MODE_DEFAULT)
            except ls.TraCIException:
                pass
        if vid is not None:
            self._released.add(vid)
        self._release_brake(r)
        if ep is not None and outcome != "reset":
            if self.cfg.braking.enabled and not math.isfinite(ep.braking_distance):
                self.stats["braking_missed"] += 1
            self.episodes.append(ep.finish(outcome))
            self.stats["episodes"] += 1
        self.ego[r], self.episode[r] = None, None

    # --------------------------------------------------------------------------------------- step
    def step(self, lc_cmd: np.ndarray, accel: np.ndarray) -> None:
        """Advance every road by one frame. ``lc_cmd`` [K] int in (left, keep, right); ``accel`` [K] m/s².

        Roads without an ego (their episode ended and was not reset yet) ignore their commands.
        """
        ls = _libsumo()
        cfg = self.cfg
        accel = np.clip(np.nan_to_num(np.asarray(accel, np.float64).reshape(-1), nan=0.0), cfg.accel_low, cfg.accel_high)
        lc_cmd = np.asarray(lc_cmd).reshape(-1)
        # roads without an ego keep the outputs of the frame that ended their episode (done stays set
        # until they are reset, as TorchRL expects); every other road gets this frame's
        active = self.ego_present
        started = self.obs[K.LC_STARTED]
        started[active] = False
        self.reward_lc[active] = 0.0
        self.reward_cf[active] = 0.0
        executed = np.zeros(self.num_roads)
        new_speed = self.speed.copy()
        lost: dict[int, str] = {}
        for r, vid in enumerate(self.ego):
            if vid is None:
                continue
            v_new = max(self.speed[r] + accel[r] * self.dt, 0.0)
            executed[r] = (v_new - self.speed[r]) / self.dt
            new_speed[r] = v_new
            cmd = int(lc_cmd[r])
            try:
                ls.vehicle.setSpeed(vid, v_new)
                if cmd != K.KEEP and self.obs[K.LC_ACTION_MASK][r, cmd]:
                    lane = int(self.obs[K.EGO_LANE][r, 0])
                    ls.vehicle.changeLane(vid, lane + 1 if cmd == K.LEFT else lane - 1, cfg.lc_duration)
                    self.lc_left[r] = self.lc_frames
                    started[r] = True
            except ls.TraCIException as err:
                lost[r] = str(err)
        collided = self._sim_step()
        for r, why in lost.items():
            self._lose(r, why)
        self.speed = new_speed
        self.obs[K.EGO_ACCEL][active, 0] = executed[active]
        self._finish(self._after_step(collided, executed))

    def _finish(self, finished: list[tuple[int, str]]) -> None:
        """Observe every road (an ending episode's final observation is of this frame; a collided ego is
        gone, so its road keeps the previous frame's), then close the episodes that ended."""
        gone = {r for r, outcome in finished if outcome == "collision"}
        self._observe([r for r in range(self.num_roads) if r not in gone])
        for r, outcome in finished:
            self._end_episode(r, outcome)

    def _after_step(self, collided: set[str], executed: np.ndarray) -> list[tuple[int, str]]:
        """Rewards (Eq. 26-29, 32-33), termination, episode sums, scenario events; returns the (road,
        outcome) of the episodes that ended in this frame (closed by :meth:`_finish`)."""
        ls = _libsumo()
        cfg = self.cfg
        finished = []
        for r, vid in enumerate(self.ego):
            if vid is None or self.episode[r] is None:
                continue
            ep = self.episode[r]
            self.frame[r] += 1
            self.lc_left[r] = max(self.lc_left[r] - 1, 0)
            collision = vid in collided
            outcome = None
            if collision:
                outcome = "collision"
            else:
                try:
                    y = self.longitudinal(vid)
                except ls.TraCIException as err:
                    self._lose(r, str(err))
                    continue
                if y > cfg.section_length:
                    outcome = "left_section"
                elif self.frame[r] >= cfg.max_steps:
                    outcome = "max_steps"
            a, v = float(executed[r]), float(self.speed[r])
            self.reward_lc[r, 0] = lane_change_reward(v, bool(self.obs[K.LC_STARTED][r, 0]), collision, cfg)
            self.reward_cf[r, 0] = car_following_reward(v, a, collision, cfg)
            ep.frames += 1
            ep.speed_sum += v
            ep.speed_sq_sum += v * v
            ep.accel_sum += a
            ep.accel_sq_sum += a * a
            ep.abs_accel_sum += abs(a)
            ep.lane_changes += int(self.obs[K.LC_STARTED][r, 0])
            ep.return_lc += float(self.reward_lc[r, 0])
            ep.return_cf += float(self.reward_cf[r, 0])
            self.obs[K.COLLISION][r] = collision
            if outcome is not None:
                self.terminated[r] = outcome in ("collision", "left_section")
                self.truncated[r] = not self.terminated[r]
                if collision:
                    self.stats["collisions"] += 1
                finished.append((r, outcome))
            elif cfg.braking.enabled:
                self._braking_event(r)
        return finished

    def _lose(self, r: int, why: str) -> None:
        """SUMO no longer knows road r's ego (removed, teleported, ...): log, count, truncate the episode.
        The other roads are not affected."""
        log.warning("road %d: SUMO lost ego %s (%s); episode truncated", r, self.ego[r], why)
        self.stats["sumo_errors"] += 1
        self.terminated[r], self.truncated[r] = False, True
        self.reward_lc[r] = self.reward_cf[r] = 0.0
        self.obs[K.LC_STARTED][r] = False
        self._end_episode(r, "lost")

    # ---------------------------------------------------------------------------- braking scenario
    def _braking_event(self, r: int) -> None:
        """Scenario 2: a leader 100-300 m ahead in the ego's lane brakes to a stop, stands, resumes."""
        ls = _libsumo()
        br, cfg = self.brake[r], self.cfg.braking
        phase = br["phase"]
        if phase == _BRAKE_SEEK:
            ego = self.ego[r]
            lane, y_ego = ls.vehicle.getLaneIndex(ego), self.longitudinal(ego)
            best, best_err = None, math.inf
            for e in edge_ids(r):
                for vid in ls.lane.getLastStepVehicleIDs(f"{e}_{lane}"):
                    d = self.longitudinal(vid) - y_ego
                    if vid != ego and cfg.min_distance <= d <= cfg.max_distance and abs(d - br["target"]) < best_err:
                        best, best_err, best_d = vid, abs(d - br["target"]), d
            if best is not None:
                ls.vehicle.setDecel(best, cfg.decel)
                ls.vehicle.setEmergencyDecel(best, max(cfg.decel, 9.0))
                ls.vehicle.setLaneChangeMode(best, 0)
                ls.vehicle.setSpeed(best, 0.0)
                br.update(phase=_BRAKE_BRAKING, vid=best, start=self.t, distance=best_d)
                self.episode[r].braking_distance = best_d
                self.episode[r].extra.update(braking_vehicle=best, braking_start_frame=int(self.frame[r]))
                self.stats["braking_events"] += 1
            elif self.frame[r] >= cfg.trigger_frames and not br.get("inserted"):
                self._insert_braker(r, lane, y_ego + br["target"])
                br["inserted"] = True
            return
        if phase in (_BRAKE_BRAKING, _BRAKE_STANDING):
            vid = br["vid"]
            try:
                speed = ls.vehicle.getSpeed(vid)
            except ls.TraCIException:
                br["phase"] = _BRAKE_DONE
                return
            if phase == _BRAKE_BRAKING and speed < 1e-3:
                br.update(phase=_BRAKE_STANDING, stop=self.t)
                self.episode[r].extra["braking_stop_frame"] = int(self.frame[r])
            elif phase == _BRAKE_STANDING and (self.t - br["stop"]) * self.dt >= cfg.stand_time - 1e-9:
                self.episode[r].extra["braking_resume_frame"] = int(self.frame[r])
                self._release_brake(r)

    def _insert_braker(self, r: int, lane: int, y: float) -> None:
        """No vehicle in range within ``trigger_frames``: insert one in the ego's lane at ``y`` (it is found
        as the braking leader on a later frame; counted in ``stats["braking_inserted"]``)."""
        y = min(y, self.cfg.section_length + self.cfg.exit_length - 2 * self.cfg.vehicle_length)
        route, offset = (f"route_r{r}_main", 0.0) if y < self.cfg.section_length else (f"route_r{r}_out", self.cfg.section_length)
        if y < 0:
            route, offset = f"route_r{r}", -self.cfg.entry_length
        self._add_human(r, lane=lane, route=route, pos=y - offset, prefix="b")
        self.stats["braking_inserted"] += 1

    def _release_brake(self, r: int) -> None:
        ls = _libsumo()
        br = self.brake[r]
        if br.get("phase") in (_BRAKE_BRAKING, _BRAKE_STANDING):
            vid = br["vid"]
            params = self.vehicle_params.get(vid)
            try:
                ls.vehicle.setSpeed(vid, -1)
                ls.vehicle.setLaneChangeMode(vid, LC_MODE_DEFAULT)
                if params:
                    ls.vehicle.setDecel(vid, params["b"])
            except ls.TraCIException:
                pass
        self.brake[r] = dict(phase=_BRAKE_DONE)

    # ---------------------------------------------------------------------------------- observation
    def _kin(self, vid: str) -> tuple[float, float, float, float, float]:
        """(y, x_lateral, v, v_lateral, a) of a vehicle in road coordinates."""
        vmod = _libsumo().vehicle
        px, py = vmod.getPosition(vid)
        return px - self.cfg.entry_length, py, vmod.getSpeed(vid), vmod.getLateralSpeed(vid), vmod.getAcceleration(vid)

    def _observe(self, roads=None) -> None:
        """Fill the raw observation arrays (keys.py) of ``roads`` (default: all) that have an ego."""
        ls = _libsumo()
        vmod = ls.vehicle
        cfg, o = self.cfg, self.obs
        rng_ = cfg.sensing_range
        h = cfg.history_len
        for r in range(self.num_roads) if roads is None else roads:
            ego = self.ego[r]
            if ego is None:
                continue
            y, px_lat, v, vx, _ = self._kin(ego)
            lane = vmod.getLaneIndex(ego)
            o[K.EGO_STATE][r] = (y, v, vx)
            o[K.EGO_LANE][r, 0] = lane
            # neighbours a..f
            found = [None] * 6
            lead = vmod.getLeader(ego, rng_)
            if lead and lead[0]:
                found[1] = lead[0]
            follow = vmod.getFollower(ego, rng_)
            if follow and follow[0]:
                found[4] = follow[0]
            # getNeighbors mode: bit 0 set = right side, bit 1 set = leaders (checked in tests/test_env_sumo.py)
            for slot, mode in ((0, 2), (2, 3), (3, 0), (5, 1)):
                near = vmod.getNeighbors(ego, mode)
                if near:
                    found[slot] = min(near, key=lambda item: item[1])[0]
            rel, kin, mask = o[K.NEIGHBORS_REL][r], o[K.NEIGHBORS_KIN][r], o[K.NEIGHBORS_MASK][r]
            rel[:] = 0.0
            kin[:] = 0.0
            mask[:] = False
            hist = self.history[r]
            for slot, nid in enumerate(found):
                if nid is None:
                    continue
                ny, nlat, nv, nvx, na = self._kin(nid)
                if abs(ny - y) > rng_:
                    found[slot] = None
                    continue
                rel[slot] = (nlat - px_lat, ny - y, nvx - vx, nv - v)
                kin[slot] = (ny, nv, na)
                mask[slot] = True
                if slot < 3:
                    self._remember(hist, nid, ny, nv)
            # vehicles ahead of the leaders, and the leaders' history
            ahead, history = o[K.LEADERS_AHEAD][r], o[K.LEADERS_HISTORY][r]
            ahead[:] = 0.0
            history[:] = 0.0
            for slot in range(3):
                nid = found[slot]
                if nid is None:
                    continue
                nxt = vmod.getLeader(nid, rng_)
                if nxt and nxt[0]:
                    ahead[slot] = (self.longitudinal(nxt[0]), vmod.getSpeed(nxt[0]), 1.0)
                self._fill_history(history[slot], hist[nid], h)
            # lane-change mask: a command is executed only between manoeuvres and toward an existing lane
            active = self.lc_left[r] > 0
            o[K.LC_ACTIVE][r, 0] = active
            am = o[K.LC_ACTION_MASK][r]
            am[K.KEEP] = True
            am[K.LEFT] = (not active) and lane < cfg.num_lanes - 1
            am[K.RIGHT] = (not active) and lane > 0

    def _remember(self, hist: dict, vid: str, y: float, v: float) -> None:
        d = hist.get(vid)
        if d is None:
            d = hist[vid] = deque(maxlen=self.cfg.history_len)
        if not d or d[-1][0] != self.t:
            d.append((self.t, y, v))

    def _fill_history(self, out: np.ndarray, samples: deque, h: int) -> None:
        """Positions and speeds over the last h frames, oldest first. Frames in which the vehicle was not
        observed (it only just came into view as a leader) are filled by constant-speed back-extrapolation
        from the next known sample."""
        known = {t: (y, v) for t, y, v in samples}
        nxt_y, nxt_v = samples[-1][1], samples[-1][2]
        for j in range(h - 1, -1, -1):
            t = self.t - (h - 1 - j)
            if t in known:
                nxt_y, nxt_v = known[t]
            else:
                nxt_y = nxt_y - nxt_v * self.dt
            out[j, 0], out[j, 1] = nxt_y, nxt_v

    @property
    def ego_present(self) -> np.ndarray:
        return np.array([e is not None for e in self.ego])
