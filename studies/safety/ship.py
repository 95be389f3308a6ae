"""The safety study's shipped policies (studies/safety/plan.md, "Shipped policies"): per learning arm, the seed whose
three runs' last periodic validation has no collision and the highest mean speed, pooled over the three scenarios,
chosen on validation traffic only (``validation.csv``, seed + 500,000 traffic); that seed's three final policies
ship with the package (:mod:`kddrl_trl.policies`, as ``<algo>_safe_<scenario>``).

    python -m studies.safety.ship                    # the choice, from the landed records (studies/safety/runs)
    python -m studies.safety.ship --from SWEEP [--from SWEEP2]   # ... then ship the chosen runs (their checkpoints)

A checkpoint does not outlive the machine that wrote it, so the chosen runs are shipped from a sweep folder that
holds them: the study's own (its last seeds), or a rerun of the chosen seed at the pinned commit
(``SEEDS=<seed> ALGOS=<algo> bash studies/safety/study.sh <SWEEP>``). A run of SWEEP ships only if it is the study's
run: its training, validation and test records are byte-identical to the landed ones (the training record on the
columns a study keeps). A rerun on another CPU, whose float arithmetic differs, is refused, naming the first record
that differs; ``--rerun`` ships it all the same, its card saying that it is a rerun and not the study's run. Where no
seed of an arm has a validation without collision, the plan's rule chooses none; this script then takes the fewest
pooled validation collisions, then the highest speed, and says so on the policies' cards and in its output.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from kddrl_trl.devtools.ab_records import RECORDS
from kddrl_trl.devtools.records import compact_record
from kddrl_trl.devtools.ship_policy import ship
from kddrl_trl.policies import SHIPPED_DIR
from kddrl_trl.reporting.records import RunRecord, record_bytes
from kddrl_trl.run_folder import RunFolder
from studies.safety.report import ARMS, HERE, SCENARIOS, pinned_commit, read

#: the repository root, where the landed runs' paths on a card start
ROOT = HERE.parent.parent


def last_validation(run: RunRecord) -> dict:
    """The last periodic validation of ``run`` (the row with the most episodes trained); a run without one raises,
    naming its folder."""
    frame = run.validation
    if frame is None or frame.empty:
        raise SystemExit(f"{run.path}: no validation.csv (the choice reads each run's last periodic validation)")
    missing = [c for c in ("episodes_trained", "episodes", "mean_speed_kmh", "collision_rate") if c not in frame]
    if missing:
        raise SystemExit(f"{run.path}: validation.csv lacks column(s) {', '.join(missing)}")
    row = frame.loc[frame["episodes_trained"].idxmax()]
    episodes = int(row["episodes"])
    return {
        "scenario": run.scenario,
        "episodes_trained": int(row["episodes_trained"]),
        "episodes": episodes,
        "collisions": round(float(row["collision_rate"]) * episodes),
        "mean_speed_kmh": float(row["mean_speed_kmh"]),
    }


def candidates(runs: list[RunRecord], algo: str) -> list[dict]:
    """Each seed of ``algo`` with a run in every scenario: its last validations pooled (collisions summed, speed
    the episode-weighted mean), best first (no collision, then the fastest; ties to the lower seed)."""
    by_seed: dict[int, dict[str, RunRecord]] = {}
    for run in runs:
        if str(run.summary["algo"]) == algo:  # its label (run.algo) names the options too
            by_seed.setdefault(run.seed, {})[run.scenario] = run
    rows = []
    for seed, scenarios in sorted(by_seed.items()):
        if set(scenarios) != set(SCENARIOS):
            continue
        last = [last_validation(scenarios[sc]) for sc in SCENARIOS]
        episodes = sum(v["episodes"] for v in last)
        rows.append(
            {
                "seed": seed,
                "collisions": sum(v["collisions"] for v in last),
                "episodes": episodes,
                "mean_speed_kmh": sum(v["mean_speed_kmh"] * v["episodes"] for v in last) / episodes,
                "runs": {sc: str(scenarios[sc].path) for sc in SCENARIOS},
                "validations": last,
            }
        )
    return sorted(rows, key=lambda r: (r["collisions"], -r["mean_speed_kmh"], r["seed"]))


def choose(root: Path = HERE, commit: str | None = None) -> dict[str, dict]:
    """Per learning arm (its algo), the chosen seed's row of :func:`candidates`, with ``by_plan`` false where no seed
    had a validation without collision (the fallback of the module docstring) and ``ranking`` the other seeds."""
    runs = read(root / "runs", commit or pinned_commit(root))
    chosen = {}
    for algo in ARMS:
        rows = candidates(runs, algo)
        if not rows:
            raise SystemExit(f"{root / 'runs'}: no seed of {algo} has a run in each of {', '.join(SCENARIOS)}")
        chosen[algo] = {
            **rows[0],
            "by_plan": rows[0]["collisions"] == 0,
            "ranking": [(r["seed"], r["collisions"], round(r["mean_speed_kmh"], 2)) for r in rows],
        }
    return chosen


def same_run(landed: Path, rerun: Path) -> str | None:
    """None where ``rerun`` holds the records of ``landed`` byte for byte (its training record on the columns a
    study keeps, :func:`~kddrl_trl.devtools.records.compact_record`; a record absent from both is no difference);
    else the first record that differs."""

    def content(folder: Path, name: str) -> bytes | None:
        try:
            raw = record_bytes(folder, name)
        except FileNotFoundError:
            return None
        return compact_record(raw, folder / name)[0] if name == RunFolder.TRAIN_EPISODES else raw

    return next((name for name in RECORDS if content(landed, name) != content(rerun, name)), None)


def ship_chosen(
    chosen: dict[str, dict], sweeps: list[Path], dest: Path = SHIPPED_DIR, rerun: bool = False
) -> list[Path]:
    """Ships each chosen seed's three runs, each from the first of ``sweeps`` that holds it finished with the landed
    run's records (module docstring); refuses a run that no sweep holds so, naming it. With ``rerun``, a run whose
    records differ ships too, its card saying that it is a rerun of the chosen seed, not the study's run, and from
    which record on they differ (its final evaluation on the card is its own)."""
    plans = []
    for algo, row in chosen.items():
        for sc in SCENARIOS:
            name = f"{sc}__{algo}__{row['seed']}"
            held = [s / name for s in sweeps if (s / name / "summary.json").is_file()]
            if not held:
                raise SystemExit(
                    f"{name}: not a finished run in {', '.join(map(str, sweeps))}; rerun it with "
                    f"SEEDS={row['seed']} ALGOS={algo} study.sh"
                )
            compared = [(same_run(Path(row["runs"][sc]), run), run) for run in held]
            differs, run = next((c for c in compared if c[0] is None), compared[0])
            if differs and not rerun:
                raise SystemExit(
                    f"{run}: {differs} differs from the landed {row['runs'][sc]}: not the study's run (--rerun ships "
                    f"it as a rerun)"
                )
            plans.append((algo, sc, row, run, differs))
    shipped = []
    for algo, sc, row, run, differs in plans:
        landed = Path(row["runs"][sc]).resolve()
        landed = landed.relative_to(ROOT) if landed.is_relative_to(ROOT) else landed
        rule = (
            "by the plan's rule: no collision and"
            if row["by_plan"]
            else "the plan's rule choosing none (every seed collided in validation): the fewest collisions, then"
        )
        why = (
            f"studies/safety (plan.md, 'Shipped policies'): seed {row['seed']} of {ARMS[algo]}, {rule} the highest "
            f"mean speed of its last validations pooled over {', '.join(SCENARIOS)} ({row['mean_speed_kmh']:.2f} "
            f"km/h, {row['collisions']} collisions in {row['episodes']} validation episodes); chosen on validation "
            f"traffic only"
        )
        if differs:
            why += (
                f". This policy is a rerun of that seed at the study's pinned commit on another machine, not the "
                f"study's run: its records differ from {landed} from {differs} on (the float arithmetic of "
                f"the two CPUs differs, and a run amplifies it); its final evaluation here is its own"
            )
        shipped.append(ship(run, f"{algo}_safe_{sc}", why=why, dest=dest))
    return shipped


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=HERE, help="the study folder (its runs/)")
    parser.add_argument("--commit", default=None, help="the pinned commit (default: the last that changed plan.md)")
    parser.add_argument(
        "--from", dest="sweeps", type=Path, action="append", default=[], help="a sweep folder holding chosen runs"
    )
    parser.add_argument("--dest", type=Path, default=SHIPPED_DIR, help="where the shipped policies go")
    parser.add_argument("--rerun", action="store_true", help="ship a rerun whose records differ, its card saying so")
    args = parser.parse_args(argv)
    chosen = choose(args.root, args.commit)
    for algo, row in chosen.items():
        note = "" if row["by_plan"] else " (no seed without a validation collision: the fewest taken)"
        print(
            f"{ARMS[algo]}: seed {row['seed']}, {row['mean_speed_kmh']:.2f} km/h, {row['collisions']} collisions in "
            f"{row['episodes']} validation episodes{note}; ranking (seed, collisions, km/h): {row['ranking']}"
        )
    if args.sweeps:
        for out in ship_chosen(chosen, args.sweeps, args.dest, args.rerun):
            print(f"shipped {out}: python -m kddrl_trl.evaluate run=shipped:{out.name}")
    print(json.dumps({algo: row["seed"] for algo, row in chosen.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
