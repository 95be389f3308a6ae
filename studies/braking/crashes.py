"""Where and how the learners crash on braking, from the onset and crash fields of their evaluation records
(section 1 of studies/braking/README.md).

    python studies/braking/crashes.py <evaluation folder>... [--out studies/braking/crashes.json]

Each folder is an evaluation on braking's test traffic whose ``eval_episodes.csv`` has the onset and crash fields
(:data:`kddrl_trl.envs.episode_metrics.ONSET_FIELDS`, ``CRASH_FIELDS``; ``studies/braking/evaluate_fields.sh`` makes
them). Folders are grouped by system (``summary.json`` 's algo); each folder is one seed. Per system, with the mean
and the 95 % t interval over seeds:

* the crash rate, and each crash's phase of the event (before it, while the car brakes, while it stands, after it
  drives on), its kind, whether the ego hit the event's car, and whether its lane change was under way;
* the onset of crash and clean episodes (gap, ego speed, time headway, time to collision: medians and quartiles,
  all episodes of the system pooled);
* **whether each crash was avoidable from the state at the onset.** By braking: the ego, reacting one frame later,
  brakes at its bound (``env.accel_low``, -5 m/s²) while the car brakes at ``env.braking.decel`` (8 m/s²) to a stop;
  avoidable when the ego stops behind the car's stopping point (stopping distances only: the car stands 3 s, and the
  ego, once stopped, waits). By a lane change: the ego, keeping its speed, would reach the stopped car later than
  one frame plus a lane change of ``env.lc_duration`` (2 s) after the onset, so a manoeuvre begun at the onset ends
  before it (the neighbouring lanes' traffic left aside: an upper bound on what a lane change could avoid).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from kddrl_trl.reporting.records import record_file
from kddrl_trl.reporting.stats import mean_ci

PHASES = ("before", "braking", "standing", "resumed")


def _env(folder: Path) -> dict:
    """The env node the evaluation ran with (its Hydra config)."""
    path = folder / ".hydra" / "config.yaml"
    return yaml.safe_load((path if path.is_file() else folder / "config.yaml").read_text())["env"]


def _phase(row) -> str:
    """The event's phase at the crash frame (``frames``), from the frame counts at which each phase began."""
    start, stop, resume = (row.get(f"braking_{p}_frame", math.nan) for p in ("start", "stop", "resume"))
    if not row["frames"] >= start:  # no event, or the crash before it
        return "before"
    if not row["frames"] >= stop:
        return "braking"
    return "standing" if not row["frames"] >= resume else "resumed"


def _avoidable(ep: pd.DataFrame, env: dict) -> tuple[pd.Series, pd.Series]:
    """(by braking, by a lane change) from the onset of each episode (NaN where it had no onset)."""
    dt, brake, decel = float(env["step_length"]), -float(env["accel_low"]), float(env["braking"]["decel"])
    gap, v, v_lead = ep["onset_gap"], ep["onset_speed"], ep["onset_leader_speed"]
    ego_stop = v * dt + v**2 / (2 * brake)
    lead_stop = v_lead**2 / (2 * decel)
    by_braking = (gap + lead_stop > ego_stop).where(gap.notna())
    reach = (gap + lead_stop) / v.where(v > 0)  # s until the ego, at its speed, reaches the car's stopping point
    by_lane_change = (reach > dt + float(env["lc_duration"])).where(gap.notna())
    return by_braking, by_lane_change


def load(folder: Path) -> tuple[str, pd.DataFrame]:
    summary = json.loads((folder / "summary.json").read_text())
    ep = pd.read_csv(record_file(folder, "eval_episodes.csv"))  # plain or compressed
    missing = [c for c in ("onset_gap", "crash_speed", "crash_with_event_car") if c not in ep.columns]
    if missing:
        raise ValueError(
            f"{record_file(folder, 'eval_episodes.csv')}: no {', '.join(missing)} column (evaluate_fields.sh)"
        )
    env = _env(folder)
    ep["phase"] = ep.apply(_phase, axis=1)
    ep["avoidable_braking"], ep["avoidable_lane_change"] = _avoidable(ep, env)
    ep["hit_event_car"] = ep["crash_with_event_car"].astype(str).str.lower() == "true"
    ep["dt"] = float(env["step_length"])
    return str(summary["algo"]), ep


def _share(values) -> dict:
    return {k: v for k, v in mean_ci(values, within=(0.0, 1.0)).items()}


def _quartiles(series: pd.Series) -> list[float]:
    finite = series[np.isfinite(series)]
    return [float(q) for q in finite.quantile([0.25, 0.5, 0.75])] if len(finite) else [math.nan] * 3


def summarise(seeds: list[pd.DataFrame]) -> dict:
    """One system's readings: per-seed shares with their interval over seeds, pooled onset quartiles."""
    per_seed: dict[str, list[float]] = {}

    def add(name: str, value: float) -> None:
        per_seed.setdefault(name, []).append(float(value))

    for ep in seeds:
        crash = ep[ep["collision"]]
        add("crash_rate", len(crash) / len(ep))
        n = max(len(crash), 1)
        for phase in PHASES:
            add(f"crashes_{phase}", (crash["phase"] == phase).sum() / n)
        for kind in ("rear_end", "side", "hit_from_behind"):
            add(f"crashes_{kind}", (crash["collision_kind"] == kind).sum() / n)
        add("crashes_with_event_car", crash["hit_event_car"].sum() / n)
        add("crashes_changing_lane", crash["ended_changing_lane"].astype(bool).sum() / n)
        add("crashes_avoidable_braking", (crash["avoidable_braking"] == True).sum() / n)  # noqa: E712
        add("crashes_avoidable_lane_change", (crash["avoidable_lane_change"] == True).sum() / n)  # noqa: E712
        add("episodes_avoidable_braking", (ep["avoidable_braking"] == True).sum() / ep["onset_gap"].notna().sum())  # noqa: E712
    pooled = pd.concat(seeds)
    crash, clean = pooled[pooled["collision"]], pooled[~pooled["collision"]]
    onset = {
        name: {"crash": _quartiles(crash[name]), "clean": _quartiles(clean[name])}
        for name in ("onset_gap", "onset_speed", "onset_leader_speed", "onset_headway", "onset_ttc")
    }
    dt = crash["dt"]  # s a frame
    after = crash.assign(
        since_command=(crash["frames"] - crash["crash_lc_command_frame"]) * dt,
        since_lane_change=(crash["frames"] - crash["crash_lane_change_frame"]) * dt,
        after_release=(crash["frames"] - crash["braking_resume_frame"]) * dt,
    )
    at_crash = {
        name: _quartiles(after[name])
        for name in (
            "crash_speed",
            "crash_accel",
            "crash_cf_command",
            "crash_other_speed",
            "crash_event_gap",
            "since_command",
            "since_lane_change",
            "after_release",
        )
    }
    hit, other = after[after["hit_event_car"]], after[~after["hit_event_car"]]
    by_target = {
        "event_car": {name: _quartiles(hit[name]) for name in ("crash_speed", "crash_cf_command", "crash_other_speed")},
        "other_vehicle": {
            name: _quartiles(other[name])
            for name in ("crash_speed", "crash_cf_command", "crash_other_speed", "crash_event_gap")
        },
    }
    commands = crash["crash_lc_command"].value_counts().to_dict()
    return {
        "seeds": len(seeds),
        "episodes": int(len(pooled)),
        "crashes": int(len(crash)),
        "per_seed": {name: {"values": v, **_share(v)} for name, v in per_seed.items()},
        "onset_quartiles": onset,
        "crash_quartiles": at_crash,
        "crash_quartiles_by_target": by_target,
        "crash_lc_commands": {str(k): int(v) for k, v in commands.items()},
    }


def _pct(entry: dict) -> str:
    lo, hi = entry["ci_low"], entry["ci_high"]
    ci = f" [{100 * lo:.0f}, {100 * hi:.0f}]" if lo is not None else ""
    return f"{100 * entry['mean']:.0f} %{ci}"


def table(result: dict) -> str:
    """The markdown tables of the README's section 1."""
    systems = list(result)
    rows = [
        ("crash rate", "crash_rate"),
        ("crashes before the event", "crashes_before"),
        ("… while the car brakes", "crashes_braking"),
        ("… while it stands", "crashes_standing"),
        ("… after it drives on", "crashes_resumed"),
        ("crashes into the event's car", "crashes_with_event_car"),
        ("crashes with a lane change under way", "crashes_changing_lane"),
        ("crashes avoidable by braking from the onset", "crashes_avoidable_braking"),
        ("crashes avoidable by a lane change from the onset", "crashes_avoidable_lane_change"),
        ("episodes avoidable by braking from the onset", "episodes_avoidable_braking"),
    ]
    out = ["| share (mean over seeds, 95 % CI) | " + " | ".join(systems) + " |", "|---|" + "---|" * len(systems)]
    for label, key in rows:
        out.append(f"| {label} | " + " | ".join(_pct(result[s]["per_seed"][key]) for s in systems) + " |")
    out += ["", "| median [quartiles], crash / clean episodes | " + " | ".join(systems) + " |"]
    out.append("|---|" + "---|" * len(systems))
    for name, unit in (("onset_gap", "m"), ("onset_speed", "m/s"), ("onset_headway", "s"), ("onset_ttc", "s")):
        cells = []
        for s in systems:
            c, k = result[s]["onset_quartiles"][name]["crash"], result[s]["onset_quartiles"][name]["clean"]
            cells.append(f"{c[1]:.1f} [{c[0]:.1f}, {c[2]:.1f}] / {k[1]:.1f} [{k[0]:.1f}, {k[2]:.1f}]")
        out.append(f"| {name} ({unit}) | " + " | ".join(cells) + " |")
    out += ["", "| at the crash, median [quartiles] | " + " | ".join(systems) + " |", "|---|" + "---|" * len(systems)]
    for name, unit in (
        ("crash_speed", "m/s"),
        ("crash_cf_command", "m/s²"),
        ("crash_other_speed", "m/s"),
        ("crash_event_gap", "m"),
        ("since_command", "s"),
        ("since_lane_change", "s"),
        ("after_release", "s"),
    ):
        q = [result[s]["crash_quartiles"][name] for s in systems]
        out.append(f"| {name} ({unit}) | " + " | ".join(f"{x[1]:.1f} [{x[0]:.1f}, {x[2]:.1f}]" for x in q) + " |")
    return "\n".join(out)


PHASE_COLOURS = {"braking": "#f4a582", "standing": "#d6604d", "resumed": "#92c5de"}


def space_time(traces: list[dict], path: Path) -> None:
    """Paper Fig. 14's form for crash episodes: position along the road against time, the ego and its leader in its
    lane (slot b), the event's phases shaded, the crash marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = min(len(traces), 2)
    rows = math.ceil(len(traces) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 3.6 * rows), squeeze=False)
    for ax, trace in zip(axes.flat, traces):
        dt = float(trace.get("step_length", 0.1))
        frames = trace["frames"]
        t = np.array([f["t"] for f in frames]) * dt
        ax.plot(t, [f["y"] for f in frames], color="black", label="ego")
        lead = [f["neighbours"].get("b", [math.nan])[0] for f in frames]
        ax.plot(t, lead, color="tab:orange", label="its leader (slot b)")
        for phase, colour in PHASE_COLOURS.items():
            on = np.array([f["braking_phase"] == phase for f in frames])
            if on.any():
                ax.axvspan(t[on].min(), t[on].max() + dt, color=colour, alpha=0.35, lw=0, label=f"event: {phase}")
        changes = [f["t"] * dt for f in frames if f["lc_started"]]
        for i, x in enumerate(changes):
            ax.axvline(x, color="tab:green", ls="--", lw=1, label="lane change starts" if i == 0 else None)
        ax.plot(t[-1], frames[-1]["y"], "rx", ms=10, mew=2, label=f"crash ({trace.get('collision_kind', '')})")
        ax.set(
            xlabel="time (s)",
            ylabel="position along the section (m)",
            title=f"{trace.get('algo', '')} seed {trace.get('seed', '')}, episode row {trace.get('row', '')}",
        )
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(traces) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="evaluation folders (summary.json, eval_episodes.csv)")
    parser.add_argument("--out", type=Path, help="write the readings as JSON")
    parser.add_argument(
        "--traces",
        nargs="*",
        type=Path,
        default=[],
        help="crash traces (evaluate video=true video_select=collisions: <folder>/traces/*.json) for --figure",
    )
    parser.add_argument("--figure", type=Path, help="write the crashes' space-time figure here")
    args = parser.parse_args(argv)
    if args.figure:
        traces = [json.loads(p.read_text()) for p in args.traces]
        if not traces:
            parser.error("--figure needs --traces")
        space_time(traces, args.figure)
    by_system: dict[str, list[pd.DataFrame]] = {}
    for folder in args.folders:
        algo, ep = load(folder)
        by_system.setdefault(algo, []).append(ep)
    result = {algo: summarise(seeds) for algo, seeds in by_system.items()}
    print(table(result))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1, allow_nan=True) + "\n")
    return result


if __name__ == "__main__":
    main()
