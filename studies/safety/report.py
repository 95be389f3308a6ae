"""The safety study's report (studies/safety/plan.md): the four goals per arm and scenario, what the layer costs, what
the predictions buy, and the learner's sanity check, from the landed records.

    python studies/safety/report.py [--out studies/safety]

Reads ``studies/safety/runs`` (the arms and IDM+MOBIL), ``studies/safety/runs_unshielded`` (the learning runs' final
policies without the layer), ``studies/safety/sanity/<reward>`` (the sanity check) and ``studies/paper/runs_5-14`` (the
paper's method without the layer, its records restored), each where present, and writes
``report.md`` and ``report.json``. Only runs of the plan's pinned commit (the last commit that changed ``plan.md``)
are read; another commit is refused, naming the run.
"""

from __future__ import annotations

import argparse
import math
import subprocess
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy.stats import binomtest

from kddrl_trl.atomic_files import write_json_atomic, write_text_atomic
from kddrl_trl.reporting.markdown import estimate, percent
from kddrl_trl.reporting.records import RunRecord, find_runs
from kddrl_trl.reporting.stats import clopper_pearson, difference_ci, mean_ci, ratio_ci

HERE = Path(__file__).resolve().parent
SCENARIOS = ("baseline", "congested", "braking")
ARMS = {"kddrl": "KDDRL safe", "d3qn_td3": "D3QN+TD3 safe"}
REFERENCE = "idm_mobil"
#: the goals' thresholds (plan, "The goals")
SPEED_RATIO, INTERVENTION_RATE, ALPHA = 1.10, 0.10, 0.05
#: the sanity check's reading: running collision rate over this many training episodes, below this level
SANITY_WINDOW, SANITY_LEVEL = 50, 0.05


def pinned_commit(root: Path = HERE) -> str:
    """The short hash of the last commit that changed ``plan.md`` (the plan, "The safety study's plan")."""
    out = subprocess.run(["git", "log", "-1", "--format=%h", "--", "plan.md"], cwd=root, capture_output=True, text=True)
    hashes = out.stdout.split()
    if out.returncode != 0 or not hashes:
        raise SystemExit(f"{root / 'plan.md'}: not committed (the study reads only runs of the plan's commit)")
    return hashes[0]


def read(folder: Path, commit: str | None) -> list[RunRecord]:
    """The runs under ``folder`` ([] where it does not exist); each must be of ``commit`` when one is given."""
    if not folder.is_dir():
        return []
    runs = find_runs([folder])
    if commit is not None:
        other = [r for r in runs if not commit.startswith(r.commit[: len(commit)]) and not r.commit.startswith(commit)]
        if other:
            raise SystemExit(
                f"{other[0].path}: commit {other[0].commit}, not the plan's pinned {commit} "
                f"({len(other)} such run(s)); the study reads only the pinned commit's runs"
            )
    return runs


def per_seed(run: RunRecord) -> dict:
    """One seed's figures from its test episodes (and the end of its training)."""
    ep = run.episodes
    crashes = ep[ep["collision"]]
    faults = crashes["collision_fault"] if "collision_fault" in ep.columns else None
    frames = float(ep["frames"].sum())
    out = {
        "seed": run.seed,
        "episodes": len(ep),
        "mean_speed_kmh": float(ep["mean_speed_kmh"].mean()),
        "collisions": len(crashes),
        "collision_rate": len(crashes) / len(ep),
        "ego_fault": None if faults is None else int((faults == "ego").sum()),
        "other_fault": None if faults is None else int((faults == "other").sum()),
        "unknown_fault": None if faults is None else int((faults == "unknown").sum()),
        "intervention_rate": float(ep["shield_interventions"].sum()) / frames if "shield_interventions" in ep else 0.0,
    }
    train = run.training
    if train is not None and "shield_interventions" in train.columns:
        last = train.tail(100)
        out["train_intervention_rate_last100"] = float(last["shield_interventions"].sum() / last["frames"].sum())
    return out


def compute(runs: list[RunRecord]) -> list[dict]:
    """Per algo, the runs and the hours of wall clock they recorded (``wall_s``: training, validations and the final
    evaluation, each job on one torch thread beside one other; a seed of a batch its share of the batch's:
    :attr:`RunRecord.seed_share`), and the CPUs that ran them (``machine``). The evaluations without the layer
    record no wall clock and are not in it."""
    out = defaultdict(lambda: {"runs": 0, "wall_h": 0.0, "cpus": set()})
    for r in runs:
        row = out[str(r.summary["algo"])]
        row["runs"] += 1
        row["wall_h"] += float(r.summary.get("wall_s", 0.0)) * r.seed_share / 3600
        machine = str(r.summary.get("machine", "not recorded")).split(", ")
        row["cpus"].add(machine[1] if len(machine) > 1 else machine[0])
    return [{"algo": a, **v, "cpus": sorted(v["cpus"])} for a, v in sorted(out.items())]


def cells(runs: list[RunRecord]) -> dict[tuple[str, str], list[dict]]:
    """(algo, scenario) -> the per-seed figures, by seed."""
    out = defaultdict(list)
    for r in runs:
        out[(str(r.summary["algo"]), r.scenario)].append(per_seed(r))
    return {k: sorted(v, key=lambda s: s["seed"]) for k, v in out.items()}


def _values(seeds: list[dict], key: str) -> np.ndarray:
    return np.array([s[key] for s in seeds], dtype=float)


def goals(arm: list[dict], ref: list[dict] | None) -> dict:
    """G1-G4 of one arm and scenario (plan, "The goals")."""
    n = sum(s["episodes"] for s in arm)
    ego = None if any(s["ego_fault"] is None for s in arm) else sum(s["ego_fault"] for s in arm)
    out = {
        "seeds": [s["seed"] for s in arm],
        "episodes": n,
        "G1": {
            "ego_fault": ego,
            "upper95": None if ego is None else clopper_pearson(ego, n, confidence=1 - 2 * ALPHA)[1],
            "holds": ego == 0,
        },
    }
    rates = _values(arm, "intervention_rate")
    g4 = mean_ci(rates, within=(0.0, 1.0))
    out["G4"] = {
        **g4,
        "holds": g4["mean"] <= INTERVENTION_RATE,
        "decided": g4["ci_high"] is not None and g4["ci_high"] <= INTERVENTION_RATE,
    }
    if all("train_intervention_rate_last100" in s for s in arm):
        out["G4"]["train_last100"] = float(_values(arm, "train_intervention_rate_last100").mean())
    if ref:
        k_a, k_r = sum(s["collisions"] for s in arm), sum(s["collisions"] for s in ref)
        n_r = sum(s["episodes"] for s in ref)
        p_worse = binomtest(k_a, k_a + k_r, n / (n + n_r), alternative="greater").pvalue if k_a + k_r else 1.0
        out["G2"] = {
            "collisions": k_a,
            "rate": k_a / n,
            "reference_collisions": k_r,
            "reference_rate": k_r / n_r,
            "p_worse": float(p_worse),
            "holds": k_a / n <= k_r / n_r,
            "contradicted": bool(p_worse < ALPHA),
        }
        ratio = ratio_ci(_values(arm, "mean_speed_kmh"), _values(ref, "mean_speed_kmh"))
        out["G3"] = {
            **ratio,
            "speed_kmh": float(_values(arm, "mean_speed_kmh").mean()),
            "reference_speed_kmh": float(_values(ref, "mean_speed_kmh").mean()),
            "holds": ratio["mean"] >= SPEED_RATIO,
            "decided": ratio["ci_low"] is not None and ratio["ci_low"] >= SPEED_RATIO,
        }
    return out


def layer_cost(shielded: list[dict], bare: list[dict]) -> dict | None:
    """With the layer minus without, paired by seed: mean speed and collision rate."""
    common = sorted({s["seed"] for s in shielded} & {s["seed"] for s in bare})
    if not common:
        return None
    by = {s["seed"]: s for s in shielded}, {s["seed"]: s for s in bare}
    out = {"seeds": common}
    for key in ("mean_speed_kmh", "collision_rate"):
        out[key] = mean_ci([by[0][s][key] - by[1][s][key] for s in common])
        out[f"{key}_without"] = float(np.mean([by[1][s][key] for s in common]))
    return out


def first_safe_episode(run: RunRecord) -> int | None:
    """The first training episode (counted from 1) at which the running collision rate over the last
    :data:`SANITY_WINDOW` episodes is below :data:`SANITY_LEVEL` and stays below to the end (None: it never does)."""
    if run.training is None or "collision" not in run.training.columns:
        return None
    hits = run.training["collision"].astype(str).str.lower().isin(("true", "1")).to_numpy(float)
    running = np.convolve(hits, np.ones(SANITY_WINDOW) / SANITY_WINDOW, mode="valid")
    above = np.nonzero(running >= SANITY_LEVEL)[0]
    if above.size == 0:
        return SANITY_WINDOW
    last = int(above[-1])
    return None if last + 1 >= running.size else last + 1 + SANITY_WINDOW


def sanity(runs: list[RunRecord]) -> list[dict]:
    out = []
    for r in sorted(runs, key=lambda r: (r.path.parent.name, r.seed)):
        reward = r.path.parent.name  # sanity/<reward>/<run>
        out.append(
            {
                "reward": reward,
                "seed": r.seed,
                "commit": r.commit,
                "test_collision_rate": float(r.episodes["collision"].mean()),
                "test_mean_speed_kmh": float(r.episodes["mean_speed_kmh"].mean()),
                "first_safe_episode": first_safe_episode(r),
                "training_episodes": None if r.training is None else len(r.training),
            }
        )
    return out


def fault_figure(result: dict, path: Path) -> Path | None:
    """Collisions per 10,000 test episodes by fault class, per system and scenario (stacked bars): the crash figure
    of the study. None where no collision was classed."""
    rows = result["faults"]
    if not rows:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    episodes = {(r["algo"], r["scenario"]): sum(s["episodes"] for s in result["per_seed"][f"{r['algo']} {r['scenario']}"])
                for r in rows}  # fmt: skip
    labels = [f"{r['algo']}\n{r['scenario']}" for r in rows]
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(rows)), 4.0))
    bottom = np.zeros(len(rows))
    for fault, color in (("ego", "tab:red"), ("other", "tab:blue"), ("unknown", "tab:gray")):
        per = np.array([1e4 * r[fault] / episodes[(r["algo"], r["scenario"])] for r in rows])
        ax.bar(labels, per, bottom=bottom, color=color, label=f"fault: {fault}")
        bottom += per
    ax.set_ylabel("collisions per 10,000 test episodes")
    ax.set_title("Who is at fault (RSS's proper response, envs/fault.py)", fontsize=10)
    ax.legend(fontsize=8)
    ax.tick_params(axis="x", labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def markdown(result: dict) -> str:
    lines = [
        "# The safety study's report",
        "",
        f"Regenerated by `python studies/safety/report.py` from the runs of the pinned commit {result['commit']} "
        "(studies/safety/plan.md). Intervals are 95 %; the goals' readings are the plan's.",
        "",
        "## The goals",
        "",
        "| arm | scenario | seeds | G1 ego-fault collisions [95 % upper bound] | G2 collisions: arm / IDM+MOBIL "
        "(p worse) | G3 speed / IDM+MOBIL's (km/h) | G4 intervention rate, test (end of training) |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in result["goals"]:
        g1, g2, g3, g4 = (row.get(k) for k in ("G1", "G2", "G3", "G4"))
        c1 = (
            "n/a" if g1["ego_fault"] is None else f"{g1['ego_fault']} / {row['episodes']} [{percent(g1['upper95'], 3)}]"
        )
        c2 = (
            f"{g2['collisions']} / {g2['reference_collisions']} ({percent(g2['rate'])} vs {percent(g2['reference_rate'])}, "
            f"p {g2['p_worse']:.3f})"
            if g2
            else "no reference yet"
        )
        c3 = (
            f"{estimate(g3, '.3f')} ({g3['speed_kmh']:.1f} / {g3['reference_speed_kmh']:.1f})" if g3 else "no reference"
        )
        c4 = estimate(g4, ".1f", 100, " %") + (f" ({100 * g4['train_last100']:.1f} %)" if "train_last100" in g4 else "")
        seeds = f"{len(row['seeds'])} ({min(row['seeds'])}-{max(row['seeds'])})"
        lines.append(f"| {row['arm']} | {row['scenario']} | {seeds} | {c1} | {c2} | {c3} | {c4} |")
    lines += ["", "Pooled over the three scenarios (G1):", ""]
    for arm, pooled in result["pooled_G1"].items():
        lines.append(
            f"- {arm}: {pooled['ego_fault']} ego-fault collisions in {pooled['episodes']} test episodes "
            f"(95 % upper bound {percent(pooled['upper95'], 3)})"
        )
    lines += ["", "Fault classes of every arm's collisions (and IDM+MOBIL's; `fig_faults.png`):", ""]
    lines += ["| algo | scenario | collisions | ego | other | unknown |", "|---|---|---|---|---|---|"]
    for row in result["faults"]:
        lines.append(
            f"| {row['algo']} | {row['scenario']} | {row['collisions']} | {row['ego']} | {row['other']} | "
            f"{row['unknown']} |"
        )
    lines += ["", "## What the layer costs (the same final policies without it; paired by seed)", ""]
    lines += [
        "| arm | scenario | seeds | speed with - without (km/h) | without (km/h) | collision rate with - without | "
        "without |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in result["layer_cost"]:
        lines.append(
            f"| {row['arm']} | {row['scenario']} | {len(row['seeds'])} | {estimate(row['mean_speed_kmh'], '.1f')} | "
            f"{row['mean_speed_kmh_without']:.1f} | {estimate(row['collision_rate'], '.2f', 100, ' pts')} | "
            f"{percent(row['collision_rate_without'])} |"
        )
    if not result["layer_cost"]:
        lines.append("| (no unshielded evaluation landed yet) | | | | | | |")
    lines += [
        "",
        "## Against the paper's method without the layer (studies/paper, seeds 5-14 at b88a84a; Welch; exploratory)",
        "",
        "| arm | scenario | seeds | speed, arm - the paper's method (km/h) | collision rate, arm - the paper's method |",
        "|---|---|---|---|---|",
    ]
    for row in result.get("against_paper", []):
        lines.append(
            f"| {row['arm']} | {row['scenario']} | {row['n']} | {estimate(row['speed'], '.1f')} | "
            f"{estimate(row['collision_rate'], '.2f', 100, ' pts')} |"
        )
    if not result.get("against_paper"):
        lines.append(
            "| (the paper study's records not restored: python -m kddrl_trl.devtools.records restore paper) | | | | |"
        )
    lines += ["", "## Do the predictions buy speed? KDDRL safe - D3QN+TD3 safe (Welch; exploratory)", ""]
    lines += ["| scenario | seeds | speed difference (km/h) | p |", "|---|---|---|---|"]
    for row in result["predictions"]:
        d = row["difference"]
        lines.append(f"| {row['scenario']} | {row['n']} | {estimate(d, '.1f')} | {d.get('p', float('nan')):.3f} |")
    lines += ["", "## The learner's sanity check (one lane, a leader braking to a stop, no layer)", ""]
    lines += [
        "| reward | seed | test collisions | test speed (km/h) | first training episode after which the running "
        f"{SANITY_WINDOW}-episode collision rate stays below {percent(SANITY_LEVEL, 0)} |",
        "|---|---|---|---|---|",
    ]
    for row in result["sanity"]:
        first = row["first_safe_episode"]
        lines.append(
            f"| {row['reward']} | {row['seed']} | {percent(row['test_collision_rate'], 1)} | "
            f"{row['test_mean_speed_kmh']:.1f} | {'never' if first is None else first} of "
            f"{row['training_episodes']} |"
        )
    lines += ["", "## Compute (wall clock the runs recorded; two jobs at a time on a 2-core machine)", ""]
    lines += ["| algo | runs | wall clock (h) | CPU |", "|---|---|---|---|"]
    for row in result.get("compute", []):
        lines.append(f"| {row['algo']} | {row['runs']} | {row['wall_h']:.1f} | {', '.join(row['cpus'])} |")
    return "\n".join(lines) + "\n"


def build(root: Path = HERE, commit: str | None = None) -> dict:
    commit = commit or pinned_commit(root)
    runs = read(root / "runs", commit)
    study = cells(runs)
    bare = cells(read(root / "runs_unshielded", commit))
    result = {"commit": commit, "goals": [], "pooled_G1": {}, "faults": [], "layer_cost": [], "predictions": []}
    for algo, arm in ARMS.items():
        pooled = [s for sc in SCENARIOS for s in study.get((algo, sc), [])]
        if pooled and all(s["ego_fault"] is not None for s in pooled):
            ego, n = sum(s["ego_fault"] for s in pooled), sum(s["episodes"] for s in pooled)
            result["pooled_G1"][arm] = {
                "ego_fault": ego,
                "episodes": n,
                "upper95": clopper_pearson(ego, n, confidence=1 - 2 * ALPHA)[1],
            }
        for sc in SCENARIOS:
            seeds = study.get((algo, sc))
            if not seeds:
                continue
            result["goals"].append({"arm": arm, "scenario": sc, **goals(seeds, study.get((REFERENCE, sc)))})
            cost = layer_cost(seeds, bare.get((algo, sc), []))
            if cost:
                result["layer_cost"].append({"arm": arm, "scenario": sc, **cost})
    for (algo, sc), seeds in sorted(study.items()):
        if all(s["ego_fault"] is not None for s in seeds):
            result["faults"].append(
                {
                    "algo": algo,
                    "scenario": sc,
                    "collisions": sum(s["collisions"] for s in seeds),
                    **{k: sum(s[f"{k}_fault"] for s in seeds) for k in ("ego", "other", "unknown")},
                }
            )
    paper = cells(read(root.parent / "paper" / "runs_5-14", None))  # the paper's method, another commit (b88a84a)
    result["against_paper"] = []
    for algo, arm in ARMS.items():
        for sc in SCENARIOS:
            mine, theirs = study.get((algo, sc)), paper.get((algo, sc))
            if mine and theirs and min(len(mine), len(theirs)) >= 2:
                result["against_paper"].append(
                    {
                        "arm": arm,
                        "scenario": sc,
                        "n": f"{len(mine)} / {len(theirs)}",
                        "speed": difference_ci(_values(mine, "mean_speed_kmh"), _values(theirs, "mean_speed_kmh")),
                        "collision_rate": difference_ci(
                            _values(mine, "collision_rate"), _values(theirs, "collision_rate")
                        ),
                    }
                )
    for sc in SCENARIOS:
        a, b = study.get(("kddrl", sc)), study.get(("d3qn_td3", sc))
        if a and b and min(len(a), len(b)) >= 2:
            d = difference_ci(_values(a, "mean_speed_kmh"), _values(b, "mean_speed_kmh"))
            result["predictions"].append({"scenario": sc, "n": f"{len(a)} / {len(b)}", "difference": d})
    result["sanity"] = sanity(read(root / "sanity", None))  # before the study, at the plan's first commit
    result["compute"] = compute(runs)
    result["seeds"] = {f"{algo} {sc}": [s["seed"] for s in v] for (algo, sc), v in sorted(study.items())}
    result["per_seed"] = {f"{algo} {sc}": v for (algo, sc), v in sorted(study.items())}
    return result


def _clean(x):
    """JSON-safe: NaN and infinities as None."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, np.generic):
        return _clean(x.item())
    return x


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=HERE, help="the study folder (runs/, runs_unshielded/, sanity/)")
    parser.add_argument("--out", type=Path, default=None, help="where report.md and report.json go (default: --root)")
    parser.add_argument("--commit", default=None, help="the pinned commit (default: the one that added plan.md)")
    args = parser.parse_args(argv)
    out = args.out or args.root
    result = _clean(build(args.root, args.commit))
    write_json_atomic(out / "report.json", result)
    write_text_atomic(out / "report.md", markdown(result))
    fault_figure(result, out / "fig_faults.png")
    print(markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
