"""``RoadSim``: one road of the SUMO highway, frame by frame, in this process or in a spawned one of its own.

libsumo runs one simulation per process, so a second env in a process that already runs one (Gymnasium's
``check_env`` opening an env to render while the first is open, SB3's ``DummyVecEnv`` with ``n_envs=2``) cannot start
its own SUMO there. :func:`open_road_sim` then starts it in a spawned worker process (:class:`RoadSimProcess`), which
answers the same three calls over a pipe. Both give the same frames for the same seed: the simulation is the same
code, only its process differs.
"""

from __future__ import annotations

import multiprocessing as mp
from typing import Any

import numpy as np

from ..highway_config import HighwayConfig
from ..main_guard import require_main_guard
from .sim import HighwaySim, simulation_open

EGO = "ego_id"  # the frame's entry holding the ego's SUMO id (None once its episode ended)


class RoadSim:
    """A :class:`HighwaySim` of one road. :meth:`reset` and :meth:`step` return that road's frame, as copies:
    every raw key of ``kddrl_trl.keys`` without the road dimension, ``terminated``, ``truncated`` (and after a step
    the two rewards and their terms), plus :data:`EGO`."""

    def __init__(self, cfg: HighwayConfig, seed: int, gui: bool = False):
        self.sim = HighwaySim(cfg, 1, seed=seed, gui=gui)

    def reset(self, seed: int | None = None) -> dict:
        """A new episode; ``seed`` restarts the simulation with that seed first (warm-up included)."""
        if seed is not None:
            self.sim.reseed(seed)
        self.sim.reset_roads([0])
        return self._frame(with_reward=False)

    def step(self, lc: int, cf: float) -> dict:
        """One frame with lane command ``lc`` (``keys.LC_ACTIONS`` index) and acceleration ``cf`` (m/s²)."""
        self.sim.step(np.asarray([int(lc)]), np.asarray([float(cf)], np.float64))
        return self._frame(with_reward=True)

    def _frame(self, with_reward: bool) -> dict:
        frame = {key: np.array(value[0]) for key, value in self.sim.outputs(with_reward).items()}
        frame[EGO] = self.sim.ego[0]
        return frame

    def close(self) -> None:
        self.sim.close()


def _serve(conn, cfg: HighwayConfig, seed: int, gui: bool = False) -> None:
    """The worker's loop: build the road, then answer ``(method, args)`` with ``("ok", result)`` or ``("error", e)``."""
    try:
        road = RoadSim(cfg, seed, gui)
    except BaseException as error:  # noqa: BLE001  (sent to the parent, raised there)
        conn.send(("error", error))
        return
    conn.send(("ok", None))
    while True:
        try:
            name, args = conn.recv()
        except EOFError:  # the parent is gone
            road.close()
            return
        try:
            conn.send(("ok", getattr(road, name)(*args)))
        except BaseException as error:  # noqa: BLE001
            conn.send(("error", error))
        if name == "close":
            return


class RoadSimProcess:
    """A :class:`RoadSim` in a spawned worker process (never forked: a fork would copy this process's SUMO)."""

    def __init__(self, cfg: HighwayConfig, seed: int, gui: bool = False):
        require_main_guard("a second SUMO env in one process (its simulation runs in a worker process)")
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._process = ctx.Process(
            target=_serve, args=(child, cfg, int(seed), bool(gui)), daemon=True, name="kddrl_trl-road"
        )
        self._process.start()
        child.close()
        self._answer()

    def _answer(self) -> Any:
        try:
            status, value = self._conn.recv()
        except EOFError:
            self._process.join(timeout=5)
            raise RuntimeError(
                f"the SUMO worker process ended unexpectedly (exit code {self._process.exitcode})"
            ) from None
        if status == "error":
            raise value
        return value

    def _call(self, name: str, *args) -> Any:
        if self._conn.closed:
            raise RuntimeError("this road's simulation is closed")
        self._conn.send((name, args))
        return self._answer()

    def reset(self, seed: int | None = None) -> dict:
        return self._call("reset", seed)

    def step(self, lc: int, cf: float) -> dict:
        return self._call("step", lc, cf)

    def close(self) -> None:
        if self._conn.closed:
            return
        try:
            self._call("close")
        except (RuntimeError, OSError):
            pass
        self._conn.close()
        self._process.join(timeout=10)
        if self._process.is_alive():
            self._process.kill()


def check_process(process: str) -> str:
    """``process`` if it is ``"auto"`` (here, unless a simulation already runs in this process: then in a worker),
    ``"here"`` or ``"worker"``; a ``ValueError`` naming it otherwise."""
    if process not in ("auto", "here", "worker"):
        raise ValueError(f"process must be 'auto', 'here' or 'worker', got {process!r}")
    return process


def open_road_sim(cfg: HighwayConfig, seed: int, process: str = "auto", gui: bool = False) -> RoadSim | RoadSimProcess:
    """One road's simulation, where ``process`` says (:func:`check_process`); ``gui``: in ``sumo-gui``."""
    if check_process(process) == "worker" or (process == "auto" and simulation_open()):
        return RoadSimProcess(cfg, seed, gui)
    return RoadSim(cfg, seed, gui)
