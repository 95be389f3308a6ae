"""Scenario 2 of the paper (§IV.D, ``+scenario=braking``): once per episode, a leader 100-300 m ahead in
the ego's lane brakes to a stop at ``decel``, stands for ``stand_time`` and drives on. With ``braking.probability``
below 1 (``+scenario=mixed``, a training curriculum) only that share of the episodes has the event.

How it drives on is ``braking.release``. ``sumo`` hands it back to SUMO at once: its own IDM acceleration (up to
its class's ``a``, 3.5-6.5 m/s²) and its own lane changes. ``programmed`` follows the paper's "gradually resume its
normal speed": the car keeps its lane and its speed rises by ``resume_accel`` per second (never above what SUMO
deems safe behind its own leader) until it has the speed it had before braking, then SUMO takes it back.

:class:`BrakingEvents` runs the event on every road of a :class:`~kddrl_trl.envs.sim.HighwaySim` and writes its
phase (``keys.BRAKING_PHASE``, codes of ``keys.BRAKING_PHASES``), the gap at which it started
(``keys.BRAKING_DISTANCE``) and, every frame from then on, the event car's gap, speed and lane changes since its
release (``keys.BRAKING_GAP``, ``BRAKING_SPEED``, ``BRAKING_LANE_CHANGES``) into the simulator's observation arrays,
from which the episode metrics (``braking_distance``, ``braking_start_frame``, the onset and crash fields of
:class:`~kddrl_trl.envs.episode_metrics.EpisodeTracker`) are read. These are labels for the records, never observed by
a policy (``keys.EPISODE_LABEL_KEYS``).
"""

from __future__ import annotations

import math

from .. import keys as K
from .network import LC_MODE_DEFAULT, edge_ids
from .observe import _libsumo, longitudinal

#: frames ahead of ``keys.BRAKING_FUTURE`` (the key steps of Eq. 24, 1 s and 2 s at 0.1 s a frame)
FUTURE_FRAMES = (10, 20)


class BrakingEvents:
    """Per-road state of the braking event: seek a leader at a drawn target distance (phase ``none``), brake
    it to a stop (``braking``), hold it (``standing``), release it (``resumed``, or ``vanished`` if it left the
    simulation). No vehicle in range within ``trigger_frames``: one is inserted at the target distance.

    ``sim`` is the simulator (its egos, frame counters, random streams, counters ``stats`` and vehicle insertion).
    """

    def __init__(self, sim):
        self.sim, self.cfg = sim, sim.cfg.braking
        self.state = [dict(phase=K.BRAKE_NONE, target=math.nan) for _ in range(sim.num_roads)]

    def _write(self, r: int, phase: int, distance: float | None = None) -> None:
        self.state[r]["phase"] = phase
        self.sim.obs[K.BRAKING_PHASE][r, 0] = phase
        if distance is not None:
            self.sim.obs[K.BRAKING_DISTANCE][r, 0] = distance

    def start(self, r: int) -> None:
        """A new episode on road ``r``: whether it has the event (``braking.probability``, drawn from the road's
        stream only when below 1, so a scenario with the event in every episode draws exactly as before; episodes
        drawn without it count in ``stats["braking_skipped"]``), then the target distance (nothing to do if the
        scenario has no event)."""
        self.state[r] = dict(phase=K.BRAKE_NONE, target=math.nan, active=False)
        self._write(r, K.BRAKE_NONE, 0.0)
        obs = self.sim.obs
        obs[K.BRAKING_GAP][r, 0] = obs[K.BRAKING_SPEED][r, 0] = obs[K.BRAKING_LANE_CHANGES][r, 0] = 0
        obs[K.BRAKING_CONTACT][r, 0] = False
        obs[K.BRAKING_SLOT][r, 0] = -1
        obs[K.BRAKING_FUTURE][r] = 0.0
        obs[K.BRAKING_FUTURE_KNOWN][r] = False
        if not self.cfg.enabled:
            return
        if self.cfg.probability < 1.0 and not self.sim.rngs[r].random() < self.cfg.probability:
            self.sim.stats["braking_skipped"] += 1
            return
        self.state[r].update(
            active=True, target=float(self.sim.rngs[r].uniform(self.cfg.min_distance, self.cfg.max_distance))
        )

    def update(self, r: int) -> None:
        """One frame of road ``r``'s running episode (called after the simulation step)."""
        if not self.state[r].get("active"):
            return
        br = self.state[r]
        if br["phase"] == K.BRAKE_NONE:
            self._seek(r)
        elif br["phase"] in (K.BRAKE_BRAKING, K.BRAKE_STANDING):
            self._hold(r)
        elif br.get("ramping"):
            self._ramp(r)
        if "vid" in br and br["phase"] != K.BRAKE_VANISHED:
            self._track(r)

    def _track(self, r: int) -> None:
        """The event car's gap to the ego, speed, and lane changes since its release, this frame (kept as they
        were once SUMO no longer knows it)."""
        ls, sim, br = _libsumo(), self.sim, self.state[r]
        vid = br["vid"]
        try:
            y, length = longitudinal(vid, sim.cfg), ls.vehicle.getLength(vid)
            speed, lane = ls.vehicle.getSpeed(vid), ls.vehicle.getLaneIndex(vid)
            y_ego = longitudinal(sim.ego[r], sim.cfg)
        except ls.TraCIException:
            return
        sim.obs[K.BRAKING_GAP][r, 0] = y - length - y_ego
        sim.obs[K.BRAKING_SPEED][r, 0] = speed
        if br["phase"] == K.BRAKE_RESUMED:
            if lane != br["lane"]:
                sim.obs[K.BRAKING_LANE_CHANGES][r, 0] += 1
                br["lane"] = lane

    def observed(self, r: int, slots: list) -> None:
        """After road ``r`` 's observation (``slots``: its neighbours' ids in slot order): the event car's leader slot
        and its scripted future (:meth:`scripted_future`)."""
        obs, br = self.sim.obs, self.state[r]
        vid = br.get("vid")
        slot = slots.index(vid) if vid is not None and vid in slots[:3] else -1
        obs[K.BRAKING_SLOT][r, 0] = slot
        future, known = self.scripted_future(r) if slot >= 0 else ((0.0, 0.0), (False, False))
        obs[K.BRAKING_FUTURE][r] = future
        obs[K.BRAKING_FUTURE_KNOWN][r] = known

    def scripted_future(self, r: int) -> tuple[tuple[float, ...], tuple[bool, ...]]:
        """Road ``r`` 's event car, :data:`FUTURE_FRAMES` frames ahead, as its script moves it: (positions in m,
        whether the script fixes each). The script is this class's, frame by frame as SUMO executes it (Euler: the
        speed changes by at most ``decel`` or ``resume_accel`` a second, then the car moves by its new speed): it
        brakes to a stop, stands ``stand_time``, and with ``release=programmed`` ramps back to its earlier speed. A
        ``sumo`` release, or the end of a programmed ramp, hands the car to SUMO: from that frame on, no position is
        known. The car's own leader is assumed not to hold it back."""
        ls, sim, cfg, br = _libsumo(), self.sim, self.cfg, self.state[r]
        phase, dt = br["phase"], sim.dt
        try:
            y, v = longitudinal(br["vid"], sim.cfg), ls.vehicle.getSpeed(br["vid"])
        except ls.TraCIException:
            return (0.0,) * len(FUTURE_FRAMES), (False,) * len(FUTURE_FRAMES)
        t, stop, ramping = sim.t, br.get("stop"), bool(br.get("ramping"))
        if phase not in (K.BRAKE_BRAKING, K.BRAKE_STANDING) and not ramping:  # SUMO drives it already
            return (0.0,) * len(FUTURE_FRAMES), (False,) * len(FUTURE_FRAMES)
        positions, known, handed_back = {}, {}, False
        # the speed commanded for the next frame: 0 while it brakes and stands, the ramp's next step after its release
        command = min(br["v_before"], v + cfg.resume_accel * dt) if ramping else 0.0
        for k in range(1, max(FUTURE_FRAMES) + 1):
            if handed_back:
                break
            v = max(v - cfg.decel * dt, command) if command < v else min(command, v + cfg.resume_accel * dt)
            y += v * dt
            t += 1
            positions[k], known[k] = y, True
            # this class's update of that frame: stop, release, ramp
            if phase == K.BRAKE_BRAKING and v < 1e-3:
                phase, stop = K.BRAKE_STANDING, t
            elif phase == K.BRAKE_STANDING and (t - stop) * dt >= cfg.stand_time - 1e-9:
                if cfg.release != "programmed":
                    handed_back = True
                phase, ramping, command = K.BRAKE_RESUMED, True, cfg.resume_accel * dt
            elif ramping:
                if v >= br["v_before"] - 1e-6:
                    handed_back = True
                else:
                    command = min(br["v_before"], v + cfg.resume_accel * dt)
        return (
            tuple(float(positions.get(k, 0.0)) for k in FUTURE_FRAMES),
            tuple(k in known for k in FUTURE_FRAMES),
        )

    def is_event_car(self, r: int, vid: str) -> bool:
        """Whether ``vid`` is road ``r``'s event car."""
        return self.state[r].get("vid") == vid

    def _seek(self, r: int) -> None:
        ls, sim, cfg, br = _libsumo(), self.sim, self.cfg, self.state[r]
        ego = sim.ego[r]
        lane, y_ego = ls.vehicle.getLaneIndex(ego), longitudinal(ego, sim.cfg)
        best, best_err, best_d = None, math.inf, math.nan
        for e in edge_ids(r):
            for vid in ls.lane.getLastStepVehicleIDs(f"{e}_{lane}"):
                d = longitudinal(vid, sim.cfg) - y_ego
                if vid != ego and cfg.min_distance <= d <= cfg.max_distance and abs(d - br["target"]) < best_err:
                    best, best_err, best_d = vid, abs(d - br["target"]), d
        if best is not None:
            br["v_before"] = ls.vehicle.getSpeed(best)
            ls.vehicle.setDecel(best, cfg.decel)
            ls.vehicle.setEmergencyDecel(best, max(cfg.decel, 9.0))
            ls.vehicle.setLaneChangeMode(best, 0)
            ls.vehicle.setSpeed(best, 0.0)
            br.update(vid=best, start=sim.t)
            self._write(r, K.BRAKE_BRAKING, best_d)
            sim.stats["braking_events"] += 1
        elif sim.frame[r] >= cfg.trigger_frames and not br.get("inserted"):
            self._insert(r, lane, y_ego + br["target"])
            br["inserted"] = True

    def _hold(self, r: int) -> None:
        ls, sim, br = _libsumo(), self.sim, self.state[r]
        try:
            speed = ls.vehicle.getSpeed(br["vid"])
        except ls.TraCIException:
            self._write(r, K.BRAKE_VANISHED)
            return
        if br["phase"] == K.BRAKE_BRAKING and speed < 1e-3:
            br["stop"] = sim.t
            self._write(r, K.BRAKE_STANDING)
        elif br["phase"] == K.BRAKE_STANDING and (sim.t - br["stop"]) * sim.dt >= self.cfg.stand_time - 1e-9:
            if self.cfg.release == "programmed":
                br["ramping"] = True
                ls.vehicle.setSpeed(br["vid"], self.cfg.resume_accel * sim.dt)
            else:
                self._release(r)
            br["lane"] = ls.vehicle.getLaneIndex(br["vid"])  # its lane changes are counted from here
            self._write(r, K.BRAKE_RESUMED)

    def _ramp(self, r: int) -> None:
        """One frame of a programmed release: the commanded speed rises by ``resume_accel`` per second from the
        speed the car has, until it reaches the speed it had before braking; then SUMO takes it back."""
        ls, sim, br = _libsumo(), self.sim, self.state[r]
        try:
            speed = ls.vehicle.getSpeed(br["vid"])
        except ls.TraCIException:
            br["ramping"] = False
            self._write(r, K.BRAKE_VANISHED)
            return
        if speed >= br["v_before"] - 1e-6:
            self._release(r)
        else:
            ls.vehicle.setSpeed(br["vid"], min(br["v_before"], speed + self.cfg.resume_accel * sim.dt))

    def _insert(self, r: int, lane: int, y: float) -> None:
        """No vehicle in range within ``trigger_frames``: insert one in the ego's lane at ``y`` (it is found
        as the braking leader on a later frame; counted in ``stats["braking_inserted"]``)."""
        road = self.sim.cfg
        y = min(y, road.section_length + road.exit_length - 2 * road.vehicle_length)
        route, offset = f"route_r{r}_main", 0.0
        if y >= road.section_length:
            route, offset = f"route_r{r}_out", road.section_length
        if y < 0:
            route, offset = f"route_r{r}", -road.entry_length
        self.sim.add_human(r, lane=lane, route=route, pos=y - offset, prefix="b")
        self.sim.stats["braking_inserted"] += 1

    def _release(self, r: int) -> None:
        """Give a braking or standing vehicle back to SUMO (its own deceleration and lane changes)."""
        ls, br = _libsumo(), self.state[r]
        if br["phase"] not in (K.BRAKE_BRAKING, K.BRAKE_STANDING) and not br.get("ramping"):
            return
        br["ramping"] = False
        vid = br["vid"]
        params = self.sim.vehicle_params.get(vid)
        try:
            ls.vehicle.setSpeed(vid, -1)
            ls.vehicle.setLaneChangeMode(vid, LC_MODE_DEFAULT)
            if params:
                ls.vehicle.setDecel(vid, params["b"])
        except ls.TraCIException:
            pass

    def end(self, r: int, recorded: bool) -> None:
        """Road ``r``'s episode ends: release the vehicle if it still brakes or stands; a ``recorded`` episode
        (not cut short by a reset) without an event counts in ``stats["braking_missed"]``. The observation
        arrays keep the phase of the final frame."""
        self._release(r)
        if recorded and self.state[r].get("active") and "vid" not in self.state[r]:
            self.sim.stats["braking_missed"] += 1
        self.state[r] = dict(phase=K.BRAKE_NONE, target=math.nan)
