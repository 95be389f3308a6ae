"""``HighwaySim``: K independent study roads in one libsumo simulation, one ego per road, numpy in and out.

This is the simulator core under :class:`~kddrl_trl.envs.SumoHighwayEnv`; it runs no TorchRL (the env's
observation spec only shapes its arrays), so the throughput benchmark can measure the simulator's own limit with
exactly the same per-ego queries. It does
traffic and physics: the observation is built by :mod:`~kddrl_trl.envs.observe`, the scenario-2 braking event
runs in :mod:`~kddrl_trl.envs.braking`, and the episode metrics are computed from the output arrays by
:class:`~kddrl_trl.eval.EpisodeTracker`.

Ego control (paper §III.G, Eq. 25 and 31):

* The ego is a background vehicle designated at reset among those driving in the last ``pick_window`` metres
  of the entry stretch, not changing lanes (paper §IV.C: "one vehicle is randomly designated as the controlled
  ego AV in each episode"): with ``ego_start="entry"`` (default) the one nearest the section entry, i.e. the
  next vehicle to enter the study area, so that the episode is as close as the traffic allows to "the complete
  traversal of a vehicle from the entry to the exit of the study area" (§IV.B); with ``"window"`` any of them
  at random (the ego then starts up to 150 m, on average ~75 m, before the section). Which vehicle is nearest
  is random through the traffic. From then on SUMO's speed and lane-change safety overrides are off for it (speed
  mode 0, lane-change mode 0), so a bad command really collides and SUMO's collision detection reports it.
* Acceleration: every frame v' = max(v + a·dt, 0) with a clipped to [accel_low, accel_high]; the
  executed acceleration (v' - v)/dt is what the observation and the comfort reward use.
* Lane change: a left/right command starts a ``lc_duration`` manoeuvre (SUMO's continuous lane change,
  20 frames) if no manoeuvre is in progress and the target lane exists. Otherwise the command is a no-op
  (the lane is kept); ``action_mask`` says which commands would be executed now.
* The episode ends *terminated* on a collision or when the ego leaves the study section
  (y > section_length), *truncated* after ``max_steps`` frames or when SUMO loses the ego (an error,
  logged and counted in ``stats``); ``keys.OUTCOME`` says which, and a collision's kind and the other
  vehicle's neighbour slot are in ``keys.COLLISION_KIND`` / ``COLLISION_SLOT``. A finished ego drives on
  as an ordinary human driver.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import numpy as np

from .. import keys as K
from ..highway_config import HighwayConfig
from .braking import BrakingEvents
from .network import (
    GUI_VIEW,
    GUI_ZOOM,
    LC_MODE_DEFAULT,
    SPEED_MODE_DEFAULT,
    build_road_files,
    edge_ids,
    gui_args,
    sumo_args,
)
from .observe import Observer, _libsumo, longitudinal, observation_arrays, use_traci
from .rewards import car_following_total, lane_change_total, reward_terms

log = logging.getLogger(__name__)

_ACTIVE: "HighwaySim | None" = None  # libsumo holds one simulation per process


def simulation_open() -> bool:
    """Whether a :class:`HighwaySim` runs in this process now (libsumo allows one per process)."""
    return _ACTIVE is not None


def road_streams(seed: int, offsets: Sequence[int]) -> list[list[int]]:
    """Each road's random stream ``[its seed, j]``: its seed ``seed + offsets[r]``, ``j`` the number of earlier
    roads of the same seed (``[seed, r]`` for roads of one seed)."""
    count: dict[int, int] = {}
    out = []
    for off in offsets:
        s = int(seed) + int(off)
        out.append([s, count.get(s, 0)])
        count[s] = count.get(s, 0) + 1
    return out


class HighwaySim:
    """K disconnected copies of the road in one SUMO simulation; numpy arrays of shape [K, ...] out.

    Args:
        cfg: validated :class:`HighwayConfig`.
        num_roads: K >= 1.
        seed: seeds SUMO (traffic arrivals, driver classes) and the numpy generator (per-vehicle
            parameter draws, ego designation, braking events). Same seed -> identical rollouts.
        gui: run the simulation in ``sumo-gui`` (a live view that follows road 0's ego, in real time;
            :func:`~kddrl_trl.envs.network.gui_args`): the same simulation, watched.
        road_seeds: the seed whose traffic each road carries (None: ``seed`` for every road). Road ``r`` draws from
            the stream ``[road_seeds[r], j]``, ``j`` the number of earlier roads with the same seed, so the roads of
            seed ``s`` carry, road for road, the traffic of a simulation of their own with ``seed=s`` (N seeds'
            K roads each in one simulation: a seed batch). SUMO's own generator draws nothing here (every driver's
            ``sigma`` and ``speedDev`` are 0), so the roads' traffic is their streams' alone: bit for bit, but for
            the lateral offsets, which carry a road's place in the network in their rounding (1e-14 m) and at a
            lane change's mid-point may fall on the other side of the lane boundary (``+w/2`` for ``-w/2``).

    Outputs of a frame (:meth:`outputs`): ``obs`` (every raw key of ``kddrl_trl.keys``), ``reward_lc``,
    ``reward_cf`` and their named ``terms``, ``terminated``, ``truncated``. A road whose episode ended keeps the outputs
    of its final frame until it is reset.
    """

    def __init__(
        self,
        cfg: HighwayConfig,
        num_roads: int,
        seed: int = 0,
        gui: bool = False,
        road_seeds: Sequence[int] | None = None,
    ):
        if not isinstance(num_roads, (int, np.integer)) or num_roads < 1:
            raise ValueError(f"num_roads must be an integer >= 1, got {num_roads!r}")
        if road_seeds is not None and len(road_seeds) != num_roads:
            raise ValueError(f"road_seeds holds {len(road_seeds)} seeds for num_roads={num_roads}: one per road")
        #: each road's seed as an offset from ``seed`` (a reseed moves them together)
        self._road_offsets = [0] * int(num_roads) if road_seeds is None else [int(r) - int(seed) for r in road_seeds]
        self.cfg, self.num_roads, self.gui = cfg, int(num_roads), bool(gui)
        self.dt = cfg.step_length
        self.lc_frames = int(round(cfg.lc_duration / cfg.step_length))
        self.files = build_road_files(cfg, self.num_roads)
        self.stats = {
            "episodes": 0,
            "collisions": 0,
            "sumo_errors": 0,
            "insert_steps": 0,
            "braking_events": 0,
            "braking_missed": 0,
            "braking_inserted": 0,
            "braking_skipped": 0,
            "designation_fallbacks": 0,
        }
        self.vehicle_params: dict[str, dict] = {}  # per background vehicle: driver class and IDM draw
        self._started = False
        self.seed = int(seed)
        self._start(self.seed)

    # ------------------------------------------------------------------------------------ lifecycle
    def _alloc(self) -> None:
        k = self.num_roads
        self.obs = observation_arrays(self.cfg, k)
        self.reward_lc = np.zeros((k, 1), np.float32)
        self.reward_cf = np.zeros((k, 1), np.float32)
        self.terms = {key: np.zeros((k, 1), np.float32) for key in K.TERM_KEYS}
        self.terminated = np.zeros((k, 1), bool)
        self.truncated = np.zeros((k, 1), bool)
        self.ego: list[str | None] = [None] * k
        self.speed = np.zeros(k)
        self.frame = np.zeros(k, np.int64)
        self.lc_left = np.zeros(k, np.int64)  # frames left in the ego's manoeuvre
        self.observer = Observer(self.cfg, self.obs, k)
        self.braking = BrakingEvents(self)

    def _start(self, seed: int) -> None:
        global _ACTIVE
        if not self._started:
            use_traci(self.gui)  # the live view: sumo-gui over TraCI
            if self.gui:
                log.info("gui: sumo-gui (over TraCI) follows road 0's ego in real time")
        ls = _libsumo()
        if _ACTIVE is not None and _ACTIVE is not self:
            raise RuntimeError(
                "libsumo runs one simulation per process and another HighwaySim/SumoHighwayEnv "
                "is open: close() it first, or run several envs in separate processes "
                "(torchrl ParallelEnv) or as roads of one env (num_roads=K)"
            )
        args = sumo_args(self.cfg, self.files, seed)
        if self.gui:
            args = gui_args(args, self.cfg)
        if self._started:
            ls.load(args[1:])
        else:
            ls.start(args)
        _ACTIVE, self._started = self, True
        # one random stream per road (arrivals, driver draws, ego designation, braking): a road's traffic
        # never depends on what happens on another road
        self.rngs = [np.random.default_rng(stream) for stream in road_streams(int(seed), self._road_offsets)]
        self.rate = self.cfg.flow / 3600.0  # vehicles per second per road
        self.next_arrival = np.array([self._interarrival(r) for r in range(self.num_roads)])
        self.arrivals = np.zeros(self.num_roads, np.int64)
        self.t = 0
        self.vehicle_params.clear()
        self._alloc()
        self._released: set[str] = set()
        for _ in range(int(round(self.cfg.warmup_s / self.dt))):
            self._sim_step()
        self._next_frame = time.monotonic()  # the live view paces the frames from here (:meth:`_pace`)

    def _pace(self) -> None:
        """The live view in real time: each frame waits until ``step_length`` after the one before (a slow frame
        is not made up for)."""
        wait = self._next_frame - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        self._next_frame = max(self._next_frame, time.monotonic() - self.dt) + self.dt

    def reseed(self, seed: int) -> None:
        """Restart the simulation from scratch with a new seed (warm-up included); roads of other seeds
        (``road_seeds``) keep their offsets from it."""
        self.seed = int(seed)
        self._start(self.seed)

    def close(self) -> None:
        global _ACTIVE
        if self._started:
            _libsumo().close()
            self._started = False
            use_traci(False)
        if _ACTIVE is self:
            _ACTIVE = None

    @property
    def closed(self) -> bool:
        return not self._started

    def outputs(self, with_reward: bool = True) -> dict:
        """The arrays of one frame's output by key (views, overwritten by the next frame): every raw key, the
        two rewards (``with_reward``), ``terminated`` and ``truncated``."""
        out = {**self.obs, "terminated": self.terminated, "truncated": self.truncated}
        if with_reward:
            out.update({K.LC_REWARD: self.reward_lc, K.CF_REWARD: self.reward_cf, **self.terms})
        return out

    # ----------------------------------------------------------------------------------- traffic
    def _sim_step(self) -> dict[str, tuple[str, bool]]:
        """One SUMO step; configure departing humans; return the contacts of this step: for every vehicle that
        collided, (the other vehicle, whether it was the one behind)."""
        ls = _libsumo()
        now = self.t * self.dt
        for r in np.flatnonzero(self.next_arrival <= now):
            while self.next_arrival[r] <= now:
                self.add_human(int(r))
                self.next_arrival[r] += self._interarrival(int(r))
        ls.simulationStep()
        self.t += 1
        if self.t % 200 == 0:
            self.observer.forget_old(self.t)
            self._forget_gone()
        contacts: dict[str, tuple[str, bool]] = {}
        for c in ls.simulation.getCollisions():  # SUMO's collider is the vehicle behind, the victim the one ahead
            contacts.setdefault(c.collider, (c.victim, True))
            contacts.setdefault(c.victim, (c.collider, False))
        return contacts

    def _forget_gone(self) -> None:
        """Drop the parameters and the release marks of vehicles no longer in the simulation (arrived, removed
        after a collision, teleported out): kept, they grow with every vehicle ever inserted (the soak measured
        about 6 KB per evaluation episode, +13 % RSS over 10,000 episodes). Vehicles waiting for insertion stay."""
        ls = _libsumo()
        alive = set(ls.vehicle.getIDList())
        alive.update(ls.simulation.getPendingVehicles())
        for vid in [v for v in self.vehicle_params if v not in alive]:
            del self.vehicle_params[vid]
        self._released &= alive

    def _interarrival(self, r: int) -> float:
        """Poisson arrivals: exponential gaps with mean 3600 / flow seconds (inf when the flow is 0)."""
        return float(self.rngs[r].exponential(1.0 / self.rate)) if self.rate > 0 else np.inf

    def add_human(
        self, r: int, lane: int | None = None, route: str | None = None, pos: float | None = None, prefix: str = "h"
    ) -> str:
        """Insert one human driver on road r (by default at the start of the road, in a uniformly random
        lane): driver class with probability ``share``, then each IDM parameter from a normal around the
        class value (sd = ``spread`` x value, truncated at ±2 sd); SUMO inserts it at the highest safe
        speed up to its desired speed. Returns its id; its parameters go to ``vehicle_params``."""
        ls, cfg, rng = _libsumo(), self.cfg, self.rngs[r]
        shares = np.array([d.share for d in cfg.drivers])
        cls = cfg.drivers[int(rng.choice(len(shares), p=shares / shares.sum()))]
        z = np.clip(rng.standard_normal(5), -2.0, 2.0)
        v0, T, s0, a, b = (
            float(base * (1.0 + cls.spread * zi)) for base, zi in zip((cls.v0, cls.T, cls.s0, cls.a, cls.b), z)
        )
        lane = int(rng.integers(cfg.num_lanes)) if lane is None else lane
        vid = f"{prefix}{r}.{self.arrivals[r]}"
        self.arrivals[r] += 1
        ls.vehicle.add(
            vid,
            route or f"route_r{r}",
            typeID=cls.name,
            departLane=str(lane),
            departSpeed="max",
            departPos="base" if pos is None else f"{pos:.2f}",
        )
        ls.vehicle.setMaxSpeed(vid, v0)
        ls.vehicle.setTau(vid, T)
        ls.vehicle.setMinGap(vid, s0)
        ls.vehicle.setAccel(vid, a)
        ls.vehicle.setDecel(vid, b)
        self.vehicle_params[vid] = {
            "driver": cls.name,
            "v0": v0,
            "T": T,
            "s0": s0,
            "a": a,
            "b": b,
            "road": r,
            "lane": lane,
            "time": self.t * self.dt,
        }
        return vid

    def road_vehicles(self, road: int) -> list[str]:
        ls = _libsumo()
        return [v for e in edge_ids(road) for v in ls.edge.getLastStepVehicleIDs(e)]

    def longitudinal(self, vid: str) -> float:
        """Front-bumper position along the road, metres from the start of the study section."""
        return longitudinal(vid, self.cfg)

    # ----------------------------------------------------------------------------------- episodes
    def reset_roads(self, roads, depth: int = 0) -> None:
        """Designate a new ego on each road in ``roads`` (a running episode there ends, unrecorded); one lost
        while it is first observed is replaced (``depth``: replacements so far)."""
        roads = [int(r) for r in roads]
        pending = []
        for r in roads:
            if self.ego[r] is not None:
                self._end_episode(r, None)
            if not self._designate(r):
                pending.append(r)
        tries = 0
        while pending:  # no vehicle to designate (empty road): insert one; costs extra simulation steps
            if tries > 200:
                raise RuntimeError(f"could not place an ego on roads {pending} after {tries} steps")
            if tries % 50 == 0:
                for r in pending:
                    self.add_human(
                        r, lane=self.cfg.ego_lane, pos=self.cfg.entry_length - self.cfg.pick_window, prefix="x"
                    )
            self._clear_frame(self.ego_present)  # no command in an extra step
            contacts = self._sim_step()
            self.stats["insert_steps"] += 1
            self._finish(self._after_step(contacts, np.zeros(self.num_roads)))  # other egos keep their speed
            pending = [r for r in pending if not self._designate(r)]
            tries += 1
        self._observe(roads if tries == 0 else range(self.num_roads))  # extra steps moved every road
        retry = [r for r in roads if self.ego[r] is None]  # lost while observed at reset: designate another
        if retry:
            if depth >= 3:
                raise RuntimeError(f"roads {retry}: SUMO lost {depth + 1} egos in a row at reset")
            self.reset_roads(retry, depth + 1)

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
        if cfg.ego_start == "entry":  # the next vehicle to enter the study section (paper §IV.B)
            vid = max(cands, key=ls.vehicle.getLanePosition)
        else:
            vid = cands[int(self.rngs[r].integers(len(cands)))]
        ls.vehicle.setSpeedMode(vid, 0)
        ls.vehicle.setLaneChangeMode(vid, 0)
        ls.vehicle.setColor(vid, (255, 0, 0, 255))
        self.ego[r] = vid
        if self.gui and r == 0:  # the live view follows the first road's ego
            ls.gui.trackVehicle(GUI_VIEW, vid)
            ls.gui.setZoom(GUI_VIEW, GUI_ZOOM)
        self.speed[r] = ls.vehicle.getSpeed(vid)
        ls.vehicle.setSpeed(vid, self.speed[r])
        self.frame[r] = 0
        self.lc_left[r] = 0
        self.terminated[r] = self.truncated[r] = False
        self._clear_frame(r)
        self.obs[K.EGO_ACCEL][r] = 0.0
        self.obs[K.COLLISION][r] = False
        self.braking.start(r)
        return True

    def _end_episode(self, r: int, outcome: int | None) -> None:
        """Close road ``r``'s episode with its ``keys.OUTCOMES`` code (``None``: cut short by a reset, not
        recorded). A car still on the road is handed back to SUMO: it drives on as a human."""
        ls = _libsumo()
        vid = self.ego[r]
        if vid is not None and outcome not in (K.COLLIDED, K.LOST):
            try:
                ls.vehicle.setSpeed(vid, -1)
                ls.vehicle.setSpeedMode(vid, SPEED_MODE_DEFAULT)
                ls.vehicle.setLaneChangeMode(vid, LC_MODE_DEFAULT)
            except ls.TraCIException:
                pass
        if vid is not None:
            self._released.add(vid)
        self.braking.end(r, recorded=outcome is not None)
        if outcome is not None:
            self.stats["episodes"] += 1
        self.ego[r] = None

    # --------------------------------------------------------------------------------------- step
    def _clear_frame(self, roads) -> None:
        """Per-frame outputs of ``roads`` (a mask or an index) before a frame: no lane change started, zero
        rewards, episode running, no contact."""
        self.obs[K.LC_STARTED][roads] = False
        self.reward_lc[roads] = 0.0
        self.reward_cf[roads] = 0.0
        for term in self.terms.values():
            term[roads] = 0.0
        self.obs[K.OUTCOME][roads] = K.RUNNING
        self.obs[K.COLLISION_KIND][roads] = K.NO_CONTACT
        self.obs[K.COLLISION_SLOT][roads] = -1
        self.obs[K.BRAKING_CONTACT][roads] = False

    def step(self, lc_cmd: np.ndarray, accel: np.ndarray) -> None:
        """Advance every road by one frame. ``lc_cmd`` [K] int in (left, keep, right); ``accel`` [K] m/s².

        Roads without an ego (their episode ended and was not reset yet) ignore their commands.
        """
        ls = _libsumo()
        cfg = self.cfg
        accel = np.clip(
            np.nan_to_num(np.asarray(accel, np.float64).reshape(-1), nan=0.0), cfg.accel_low, cfg.accel_high
        )
        lc_cmd = np.asarray(lc_cmd).reshape(-1)
        # roads without an ego keep the outputs of the frame that ended their episode (done stays set
        # until they are reset, as TorchRL expects); every other road gets this frame's
        active = self.ego_present
        self._clear_frame(active)
        started = self.obs[K.LC_STARTED]
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
        contacts = self._sim_step()
        if self.gui:
            self._pace()
        for r, why in lost.items():
            self._lose(r, why)
        self.speed = new_speed
        self.obs[K.EGO_ACCEL][active, 0] = executed[active]
        self._finish(self._after_step(contacts, executed))

    def _finish(self, finished: list[tuple[int, int]]) -> None:
        """Observe every road (an ending episode's final observation is of this frame; a collided ego is
        gone, so its road keeps the previous frame's), then close the episodes that ended."""
        gone = {r for r, outcome in finished if outcome == K.COLLIDED}
        self._observe([r for r in range(self.num_roads) if r not in gone])
        for r, outcome in finished:
            if self.ego[r] is not None:  # not lost while it was observed
                self._end_episode(r, outcome)

    def _observe(self, roads) -> None:
        """Observe the egos of ``roads``; a road whose observation SUMO cannot answer (a ``TraCIException``: a
        vehicle gone mid-query, ...) is truncated as lost (:meth:`_lose`), the others go on."""
        roads = [r for r in roads if self.ego[r] is not None]
        failed = self.observer.observe(roads, [self.ego[r] for r in roads], self.t, self.lc_left[roads] > 0)
        for r, why in failed.items():
            self._lose(r, why)
        if self.cfg.braking.enabled:
            for r in roads:
                if self.ego[r] is not None:
                    self.braking.observed(r, self.observer.slots[r])

    def _is_terminated(self, collided: bool, y: float | None) -> int:
        """``COLLIDED`` on a collision, ``LEFT_SECTION`` once the ego is past the study section, else
        ``RUNNING`` (codes of ``keys.OUTCOMES``)."""
        if collided:
            return K.COLLIDED
        return K.LEFT_SECTION if y > self.cfg.section_length else K.RUNNING

    def _is_truncated(self, r: int) -> int:
        """``MAX_STEPS`` after ``max_steps`` frames, else ``RUNNING`` (a lost ego is truncated by :meth:`_lose`)."""
        return K.MAX_STEPS if self.frame[r] >= self.cfg.max_steps else K.RUNNING

    def _after_step(self, contacts: dict[str, tuple[str, bool]], executed: np.ndarray) -> list[tuple[int, int]]:
        """Rewards (Eq. 26-29, 32-33), episode outcome and contact, scenario events; returns the (road, outcome)
        of the episodes that ended in this frame (closed by :meth:`_finish`)."""
        ls = _libsumo()
        cfg = self.cfg
        finished = []
        for r, vid in enumerate(self.ego):
            if vid is None:
                continue
            self.frame[r] += 1
            changing = self.lc_left[r] > 0
            self.lc_left[r] = max(self.lc_left[r] - 1, 0)
            contact = contacts.get(vid)
            y = None
            if contact is None:
                try:
                    y = self.longitudinal(vid)
                except ls.TraCIException as err:
                    self._lose(r, str(err))
                    continue
            outcome = self._is_terminated(contact is not None, y) or self._is_truncated(r)
            collision = contact is not None
            a, v = float(executed[r]), float(self.speed[r])
            terms = reward_terms(v, a, bool(self.obs[K.LC_STARTED][r, 0]), collision, cfg)
            self.reward_lc[r, 0] = lane_change_total(terms)
            self.reward_cf[r, 0] = car_following_total(terms)
            for key, value in terms.items():
                self.terms[key][r, 0] = value
            self.obs[K.COLLISION][r] = collision
            if collision:
                self._contact(r, *contact, changing)
            if outcome != K.RUNNING:
                self.obs[K.OUTCOME][r] = outcome
                self.terminated[r] = outcome in (K.COLLIDED, K.LEFT_SECTION)
                self.truncated[r] = not self.terminated[r]
                self.stats["collisions"] += int(collision)
                finished.append((r, outcome))
            else:
                self.braking.update(r)
        return finished

    def _contact(self, r: int, other: str, ego_behind: bool, changing: bool) -> None:
        """Kind of road ``r``'s collision (``keys.COLLISION_KINDS``: any contact during a lane change is a side
        contact) and the slot of the other vehicle in the last observation (-1 if it was not a neighbour)."""
        kind = K.SIDE_CONTACT if changing else K.REAR_END if ego_behind else K.HIT_FROM_BEHIND
        slots = self.observer.slots[r]
        self.obs[K.COLLISION_KIND][r] = kind
        self.obs[K.COLLISION_SLOT][r] = slots.index(other) if other in slots else -1
        self.obs[K.BRAKING_CONTACT][r] = self.braking.is_event_car(r, other)

    def _lose(self, r: int, why: str) -> None:
        """SUMO no longer knows road r's ego (removed, teleported, ...): log, count, truncate the episode.
        The other roads are not affected."""
        log.warning("road %d: SUMO lost ego %s (%s); episode truncated", r, self.ego[r], why)
        self.stats["sumo_errors"] += 1
        self.terminated[r], self.truncated[r] = False, True
        self._clear_frame(r)
        self.obs[K.OUTCOME][r] = K.LOST
        self._end_episode(r, K.LOST)

    @property
    def ego_present(self) -> np.ndarray:
        return np.array([e is not None for e in self.ego])
