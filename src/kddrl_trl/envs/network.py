"""Build the SUMO files of K disconnected copies of the study road, with the PyPI wheel's ``netconvert``.

Road r (0-based) runs along +x at network y = ``-r * ROAD_SPACING`` and has three edges:
``r{r}_in`` (entry stretch, where traffic settles and the ego is designated), ``r{r}_main`` (the 420 m study
section) and ``r{r}_out`` (exit stretch). Roads share no node, so vehicles of different roads never meet:
K roads in one simulation are K independent environments (libsumo allows one simulation per process).

Files are cached under ``$KDDRL_TRL_CACHE`` (default ``~/.cache/kddrl_trl``) by a hash of what shapes
them, and written atomically, so parallel workers can share the cache.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

from ..atomic_files import cache_dir, write_text_atomic
from ..highway_config import HighwayConfig

ROAD_SPACING = 50.0  # m between the centre lines of neighbouring roads
#: SUMO's default speed and lane-change modes, given back to a vehicle released from external control
SPEED_MODE_DEFAULT, LC_MODE_DEFAULT = 31, 1621


@dataclass(frozen=True)
class RoadFiles:
    net: Path
    routes: Path


def sumo_binary(name: str) -> str:
    """Path of a SUMO executable from the ``eclipse-sumo`` wheel (no system SUMO is used)."""
    import sumo  # the eclipse-sumo wheel

    path = Path(sumo.SUMO_HOME) / "bin" / name
    if not path.exists():
        raise FileNotFoundError(f"{path} not found: is the 'eclipse-sumo' wheel installed?")
    return str(path)


def edge_ids(road: int) -> tuple[str, str, str]:
    return f"r{road}_in", f"r{road}_main", f"r{road}_out"


def road_y(road: int) -> float:
    """Network y of road ``road``'s left edge line (lanes extend to the right, toward -y)."""
    return -road * ROAD_SPACING


def _nodes_xml(cfg: HighwayConfig, num_roads: int) -> str:
    xs = (0.0, cfg.entry_length, cfg.entry_length + cfg.section_length, cfg.road_length)
    rows = [
        f'  <node id="r{r}_n{i}" x="{x:.2f}" y="{road_y(r):.2f}" type="priority"/>'
        for r in range(num_roads)
        for i, x in enumerate(xs)
    ]
    return "<nodes>\n" + "\n".join(rows) + "\n</nodes>\n"


def _edges_xml(cfg: HighwayConfig, num_roads: int) -> str:
    rows = []
    for r in range(num_roads):
        for i, eid in enumerate(edge_ids(r)):
            rows.append(
                f'  <edge id="{eid}" from="r{r}_n{i}" to="r{r}_n{i + 1}" numLanes="{cfg.num_lanes}" '
                f'speed="{cfg.v_max:.4f}" width="{cfg.lane_width:.2f}" spreadType="right"/>'
            )
    return "<edges>\n" + "\n".join(rows) + "\n</edges>\n"


def _routes_xml(cfg: HighwayConfig, num_roads: int) -> str:
    """Driver classes as IDM vTypes and the routes of each road. No flows: vehicles are inserted by
    ``HighwaySim`` from per-road random streams, so roads stay independent of each other."""
    types = []
    for d in cfg.drivers:
        types.append(
            f'  <vType id="{d.name}" carFollowModel="IDM" laneChangeModel="LC2013" length="{cfg.vehicle_length}" '
            f'accel="{d.a}" decel="{d.b}" emergencyDecel="9.0" tau="{d.T}" minGap="{d.s0}" delta="4" '
            f'maxSpeed="{d.v0:.4f}" speedFactor="1" speedDev="0" sigma="0" '
            f'lcSpeedGain="{d.lc_speed_gain}" lcKeepRight="{d.lc_keep_right}" lcStrategic="1" lcCooperative="1"/>'
        )
    rows = ["<routes>", *types]
    for r in range(num_roads):
        e_in, e_main, e_out = edge_ids(r)
        rows.append(f'  <route id="route_r{r}" edges="{e_in} {e_main} {e_out}"/>')
        rows.append(f'  <route id="route_r{r}_main" edges="{e_main} {e_out}"/>')
        rows.append(f'  <route id="route_r{r}_out" edges="{e_out}"/>')
    rows.append("</routes>")
    return "\n".join(rows) + "\n"


def build_road_files(cfg: HighwayConfig, num_roads: int) -> RoadFiles:
    """Generate (or reuse from the cache) the network and route files for ``num_roads`` roads."""
    nodes, edges, routes = _nodes_xml(cfg, num_roads), _edges_xml(cfg, num_roads), _routes_xml(cfg, num_roads)
    key = hashlib.sha1(json.dumps([nodes, edges, routes]).encode()).hexdigest()[:16]
    folder = cache_dir() / "roads" / key
    folder.mkdir(parents=True, exist_ok=True)
    net, rou = folder / "highway.net.xml", folder / "highway.rou.xml"
    if not net.exists():
        write_text_atomic(folder / "highway.nod.xml", nodes)
        write_text_atomic(folder / "highway.edg.xml", edges)
        tmp_net = folder / f"highway.{os.getpid()}.net.xml"
        cmd = [
            sumo_binary("netconvert"),
            "--node-files",
            str(folder / "highway.nod.xml"),
            "--edge-files",
            str(folder / "highway.edg.xml"),
            "--output-file",
            str(tmp_net),
            "--no-internal-links",
            "true",
            "--no-turnarounds",
            "true",
            "--offset.disable-normalization",
            "true",
            "--no-warnings",
            "true",
        ]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"netconvert failed ({' '.join(cmd)}):\n{done.stderr}")
        os.replace(tmp_net, net)
    if not rou.exists():
        write_text_atomic(rou, routes)
    return RoadFiles(net=net, routes=rou)


def sumo_args(cfg: HighwayConfig, files: RoadFiles, seed: int) -> list[str]:
    """Command line of the simulation (libsumo takes the same arguments as the ``sumo`` binary)."""
    return [
        sumo_binary("sumo"),
        "--net-file",
        str(files.net),
        "--route-files",
        str(files.routes),
        "--step-length",
        f"{cfg.step_length}",
        "--lanechange.duration",
        f"{cfg.lc_duration}",
        "--seed",
        str(int(seed)),
        "--collision.action",
        "remove",
        "--collision.mingap-factor",
        "0",
        "--collision.check-junctions",
        "false",
        "--time-to-teleport",
        "-1",
        "--max-depart-delay",
        "10",
        "--no-step-log",
        "true",
        "--no-warnings",
        "true",
        "--duration-log.disable",
        "true",
        "--default.speeddev",
        "0",
        "--xml-validation",
        "never",
    ]


#: the view sumo-gui opens, which the live view follows
GUI_VIEW = "View #0"


def gui_args(args: list[str], cfg: HighwayConfig) -> list[str]:
    """:func:`sumo_args` for ``sumo-gui``: the simulation starts at once, without the GUI's own delay (the warm-up
    runs at full speed; :class:`~kddrl_trl.envs.sim.HighwaySim` paces the episodes' frames to real time), and the
    window closes with the simulation. sumo-gui needs a display: where ``DISPLAY`` is unset (a headless machine) it
    is refused here, naming ``xvfb-run``."""
    import os

    if not os.environ.get("DISPLAY"):
        raise RuntimeError(
            "gui=true: sumo-gui needs a display and DISPLAY is not set; on a machine without one, run the command "
            "under a virtual display: xvfb-run -a python -m ... (Debian's xvfb package)"
        )
    return [
        sumo_binary("sumo-gui"), *args[1:], "--start", "--quit-on-end", "--delay", "0", "--window-size", "1200,500",
    ]  # fmt: skip


#: the live view's zoom (percent of the whole network's fit): about 170 m of road around the ego across the window
GUI_ZOOM = 500.0
