"""What a report measures: each metric of a run's evaluation (:meth:`~kddrl_trl.reporting.records.RunRecord.metrics`)
with its column title, unit and format, the paper's table columns among them, and the ranges intervals are cut to."""

from __future__ import annotations

#: metric name -> (column title, unit, format); the first four are the paper's table columns
METRICS = {
    "mean_speed_kmh": ("mean speed", "km/h", "{:.1f}"),
    "mean_accel": ("mean acceleration", "m/s²", "{:.2f}"),
    "lane_changes_per_episode": ("lane changes per episode", "", "{:.2f}"),
    "lane_changes_per_1000_episodes": ("lane changes per 1000 episodes", "", "{:.0f}"),
    "collision_rate": ("collision rate", "", "{:.1%}"),
    "mean_abs_accel": ("mean |acceleration|", "m/s²", "{:.2f}"),
    "frame_speed_kmh_sd": ("sd of speed over frames", "km/h", "{:.1f}"),
    "frame_accel_sd": ("sd of acceleration over frames", "m/s²", "{:.2f}"),
    "return_lc": ("lane-change return", "", "{:.1f}"),
    "return_cf": ("car-following return", "", "{:.1f}"),
    "shield_rate": ("shield interventions (fraction of frames)", "", "{:.2%}"),  # algo.shield; 0 without one
}
TABLE_METRICS = (
    "mean_speed_kmh",
    "mean_accel",
    "lane_changes_per_episode",
    "lane_changes_per_1000_episodes",
    "collision_rate",
)
#: the metrics' possible ranges: their intervals are cut to them
RANGES = {"collision_rate": (0.0, 1.0), "shield_rate": (0.0, 1.0)}


def fmt(metric: str, value) -> str:
    """``value`` in ``metric``'s format; ``"n/a"`` for None."""
    return "n/a" if value is None else METRICS[metric][2].format(value)
