"""Driving metrics of the paper's Tables II-V from per-episode records (:class:`~kddrl_trl.eval.EpisodeTracker`)."""

from __future__ import annotations

import numpy as np

from .paper import paper_value


def paper_reference(scenario: str, algo: str) -> dict | None:
    """The paper's values for ``algo`` on ``scenario`` (:mod:`kddrl_trl.eval.paper`) in the keys of
    :func:`summarize`, for :func:`format_summary`; None where the paper has none."""
    ref = {}
    for key in ("mean_speed_kmh", "mean_accel", "collision_rate"):
        value = paper_value(scenario, algo, key)
        if value is not None:
            ref[key] = value[0]
            if value[1] is not None:
                ref[f"{key}_sd"] = value[1]
    return ref or None


def summarize(episodes: list[dict]) -> dict:
    """Mean ± sd over episodes of speed (km/h) and acceleration (signed and absolute, m/s²), the sd of speed
    and acceleration over all frames (``frame_*_sd``), lane changes (total and per episode), collision
    rate (fraction of episodes), outcome counts and, for episodes of the tracker, the shield intervention rate
    (``shield_rate``: fraction of all frames; ``shield_episode_rate``: of episodes with at least one). The paper
    does not say which sd its tables give."""
    if not episodes:
        raise ValueError("summarize: no finished episodes to summarize")

    def col(key):
        return np.asarray([e[key] for e in episodes], dtype=float)

    out = {"episodes": len(episodes)}
    for key in ("mean_speed_kmh", "mean_accel", "mean_abs_accel", "lane_changes", "frames", "return_lc", "return_cf"):
        values = col(key)
        out[key] = float(values.mean())
        out[f"{key}_sd"] = float(values.std())
    # frame-level spread (pooled over every frame of every episode), as in the paper's distributions
    frames = col("frames")
    for key, mean_key, sq_key, scale in (
        ("speed_kmh", "mean_speed", "mean_sq_speed", 3.6),
        ("accel", "mean_accel", "mean_sq_accel", 1.0),
    ):
        if sq_key in episodes[0]:
            mean = np.average(col(mean_key), weights=frames)
            second = np.average(col(sq_key), weights=frames)
            out[f"frame_{key}_sd"] = float(scale * np.sqrt(max(second - mean * mean, 0.0)))
    out["lane_changes_total"] = int(col("lane_changes").sum())
    out["collision_rate"] = float(col("collision").mean())
    if "shield_interventions" in episodes[0]:  # the car-following shield (algo.shield): frames it acted in
        out["shield_rate"] = float(col("shield_interventions").sum() / max(frames.sum(), 1.0))
        out["shield_episode_rate"] = float((col("shield_interventions") > 0).mean())
    outcomes: dict[str, int] = {}
    for e in episodes:
        outcomes[e["outcome"]] = outcomes.get(e["outcome"], 0) + 1
    out["outcomes"] = outcomes
    return out


def format_summary(summary: dict, reference: dict | None = None) -> str:
    """A small text table of ``summary`` (and the paper's values beside it where given)."""
    rows = [("episodes", f"{summary['episodes']}", "")]
    ref = reference or {}

    def pm(key):
        return f"{summary[key]:.2f} ± {summary[key + '_sd']:.2f}"

    def ref_pm(key):
        return f"{ref[key]:.2f} ± {ref[key + '_sd']:.2f}" if key + "_sd" in ref else ""

    rows += [
        ("mean speed (km/h), sd over episodes", pm("mean_speed_kmh"), ref_pm("mean_speed_kmh")),
        ("  sd over all frames", f"{summary.get('frame_speed_kmh_sd', float('nan')):.2f}", ""),
        ("mean acceleration (m/s²)", pm("mean_accel"), ref_pm("mean_accel")),
        ("  sd over all frames", f"{summary.get('frame_accel_sd', float('nan')):.2f}", ""),
        ("mean |acceleration| (m/s²)", pm("mean_abs_accel"), ""),
        ("lane changes per episode", pm("lane_changes"), ""),
        ("lane changes, total", f"{summary['lane_changes_total']}", ""),
        (
            "collision rate",
            f"{100 * summary['collision_rate']:.2f} %",
            f"{100 * ref['collision_rate']:.2f} %" if "collision_rate" in ref else "",
        ),
    ]
    width = max(len(r[0]) for r in rows)
    head = f"{'metric':<{width}}  {'measured':>18}  {'paper':>16}"
    return "\n".join([head, "-" * len(head)] + [f"{a:<{width}}  {b:>18}  {c:>16}" for a, b, c in rows])
