"""Drawing recorded episodes (:class:`~kddrl_trl.eval.trace.TraceRecorder` traces) with matplotlib: a top view of
one frame (:func:`draw_frame`, also the Gymnasium env's ``rgb_array``), an mp4 of a whole episode
(:func:`write_video`, ffmpeg from the ``imageio-ffmpeg`` wheel) and the space-time diagram of paper Fig. 14
(:func:`plot_space_time`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import keys as K

EGO_COLOR, NEIGHBOUR_COLOR, LEADER_COLOR, BRAKING_COLOR = "tab:red", "tab:gray", "tab:blue", "tab:orange"
#: what each colour is, in the frame's legend
LEGEND = (
    (EGO_COLOR, "ego"),
    (LEADER_COLOR, "leaders a, b, c"),
    (NEIGHBOUR_COLOR, "followers d, e, f"),
    (BRAKING_COLOR, "the braking event's car"),
)
VEHICLE_LENGTH, VEHICLE_WIDTH = 4.5, 1.8
#: metres shown behind and ahead of the ego in a frame
BEHIND, AHEAD = 60.0, 140.0
#: frame size (inches) and resolution: 1200 x 330 pixels, ~2-3 MB per 1000-frame episode in H.264
FIGSIZE, DPI = (12, 3.3), 100


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw_frame(ax, frame: dict, trace: dict) -> None:
    """One frame seen from above: lanes, the ego (red), leaders a-c (blue), followers d-f (grey), the braking event's
    car (orange, with the event's phase), a colour legend, and on the collision frame a red cross and the collision's
    kind; the view follows the ego (``BEHIND`` / ``AHEAD`` metres)."""
    from matplotlib.patches import Patch, Rectangle

    lanes, width = int(trace.get("num_lanes", 3)), float(trace.get("lane_width", 3.2))
    y0 = frame["y"] - BEHIND
    ax.clear()
    ax.add_patch(Rectangle((y0, 0), BEHIND + AHEAD, lanes * width, color="0.85", zorder=0))
    for lane in range(1, lanes):
        ax.axhline(lane * width, color="white", lw=1.0, ls=(0, (6, 6)), zorder=1)
    section = float(trace.get("section_length", 420.0))
    for edge in (0.0, section):
        if y0 <= edge <= y0 + BEHIND + AHEAD:
            ax.axvline(edge, color="k", lw=0.8, zorder=1)
    phase, braking = frame.get("braking_phase", "none"), frame.get("braking_slot", "")
    cars = [(frame["y"], frame["x"], EGO_COLOR, "ego")]
    for slot, (y, x) in frame["neighbours"].items():
        color = BRAKING_COLOR if slot == braking else LEADER_COLOR if slot in K.LEADER_SLOTS else NEIGHBOUR_COLOR
        cars.append((y, x, color, slot))
    for y, x, color, label in cars:
        ax.add_patch(
            Rectangle((y - VEHICLE_LENGTH, x - VEHICLE_WIDTH / 2), VEHICLE_LENGTH, VEHICLE_WIDTH, color=color, zorder=3)
        )
        ax.text(y - VEHICLE_LENGTH / 2, x, label, ha="center", va="center", fontsize=8, color="white", zorder=4)
        if label == braking and phase != "none":
            ax.text(y - VEHICLE_LENGTH / 2, x + VEHICLE_WIDTH, phase, ha="center", va="bottom", fontsize=9,
                    color=BRAKING_COLOR, fontweight="bold", zorder=4)  # fmt: skip
    hit = frame.get("collision")
    if hit:
        ax.plot([frame["y"] - VEHICLE_LENGTH / 2], [frame["x"]], marker="x", color="red", ms=22, mew=4, zorder=5)
        other = frame.get("collision_with", "")
        ax.text(0.99, 0.93, f"COLLISION: {hit.replace('_', ' ')}" + (f" with {other}" if other else ""),
                transform=ax.transAxes, ha="right", va="top", fontsize=16, color="red", fontweight="bold",
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "red"}, zorder=6)  # fmt: skip
    ax.set_xlim(y0, y0 + BEHIND + AHEAD)
    ax.set_ylim(-0.5, lanes * width + 0.5)
    ax.set_yticks([])  # lateral scale stretched (about 2.5x) so that three lanes stay readable
    ax.set_xlabel("longitudinal position y (m from the study section's start)", fontsize=9)
    ax.tick_params(labelsize=8)
    ax.legend(handles=[Patch(color=c, label=t) for c, t in LEGEND], loc="upper center", bbox_to_anchor=(0.5, -0.3),
              ncol=len(LEGEND), fontsize=8, frameon=False)  # fmt: skip
    ax.set_title(
        f"{trace.get('algo', '')} on {trace.get('scenario', '')}  t = {frame['t'] * trace.get('step_length', 0.1):.1f} s"
        f"  v = {3.6 * frame['v']:.0f} km/h  a = {frame['accel']:+.1f} m/s²"
        + ("  lane change" if frame.get("lc_active") else "")
        + ("" if phase == "none" else f"  braking event: {phase}"),
        fontsize=11,
    )


def frame_rgb(frame: dict, trace: dict, fig=None) -> np.ndarray:
    """``draw_frame`` as an ``uint8`` array ``[H, W, 3]``."""
    plt = _plt()
    own = fig is None
    fig = fig or plt.figure(figsize=FIGSIZE, dpi=DPI)
    ax = fig.axes[0] if fig.axes else fig.add_subplot(1, 1, 1)
    draw_frame(ax, frame, trace)
    fig.subplots_adjust(left=0.02, right=0.98, bottom=0.33, top=0.88)
    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    if own:
        plt.close(fig)
    return rgb


def write_video(trace: dict, path: str | Path, fps: int = 10) -> Path:
    """The whole episode as an H.264 mp4 at ``fps`` frames per second (real time at 10 Hz)."""
    import os

    import imageio.v2 as imageio

    plt = _plt()
    fig = plt.figure(figsize=FIGSIZE, dpi=DPI)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.mp4")  # complete before it takes the final name
    try:
        with imageio.get_writer(
            tmp, fps=fps, codec="libx264", quality=5, macro_block_size=8, ffmpeg_log_level="error"
        ) as writer:
            for frame in trace["frames"]:
                writer.append_data(frame_rgb(frame, trace, fig))
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
        plt.close(fig)
    return path


def plot_space_time(traces: list[tuple[str, dict]], path: str | Path) -> Path:
    """Fig. 14: per trace, lateral position x, longitudinal position y and time step as a 3-D line for the ego
    (red; lane-change starts marked) and its neighbours (leaders blue, followers grey; points while seen)."""
    plt = _plt()
    fig = plt.figure(figsize=(5.2 * len(traces), 4.8))
    for i, (title, trace) in enumerate(traces):
        ax = fig.add_subplot(1, len(traces), i + 1, projection="3d")
        frames = trace["frames"]
        t = np.array([f["t"] for f in frames])
        ax.plot([f["x"] for f in frames], [f["y"] for f in frames], t, color=EGO_COLOR, lw=2, label="ego")
        starts = [f for f in frames if f["lc_started"]]
        if starts:
            ax.scatter(
                [f["x"] for f in starts],
                [f["y"] for f in starts],
                [f["t"] for f in starts],
                color="k",
                marker="^",
                s=30,
                label="lane change starts",
            )
        braking = [f for f in frames if f.get("braking_phase") in ("braking", "standing")]
        if braking:
            ax.scatter(
                [f["x"] for f in braking],
                [f["y"] for f in braking],
                [f["t"] for f in braking],
                color="gold",
                s=4,
                label="braking event under way",
            )
        for slot in K.NEIGHBOR_SLOTS:
            pts = [
                (f["neighbours"][slot][1], f["neighbours"][slot][0], f["t"]) for f in frames if slot in f["neighbours"]
            ]
            if pts:
                x, y, tt = zip(*pts)
                ax.scatter(x, y, tt, s=1, color=LEADER_COLOR if slot in K.LEADER_SLOTS else NEIGHBOUR_COLOR)
        width, lanes = float(trace.get("lane_width", 3.2)), int(trace.get("num_lanes", 3))
        ax.set_xlim(0, lanes * width)
        ax.set_xlabel("lateral x (m)")
        ax.set_ylabel("longitudinal y (m)")
        ax.set_zlabel("time step")
        ax.set_title(f"{title}\n{trace.get('lane_changes', 0)} lane changes, {trace.get('outcome', '')}", fontsize=9)
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
