"""The equivalence check of a change that alters only the float arithmetic: paired differences, after − before.

A speed change that keeps the algorithm (the same losses, the same update counts) but orders or fuses its float
arithmetic otherwise cannot keep the training records byte-identical. It lands on evidence that the results did
not move: the same runs (algo, scenario, seed) trained with the code before and after it, and, per algo and
scenario and pooled, the paired differences after − before of the final evaluation's mean speed and collision
rate with their Student-t 95 % intervals over the pairs (:func:`kddrl_trl.reporting.stats.mean_test`), beside how
many pairs kept byte-identical training records, the update counts of each pair (equal where the records are;
where the arithmetic changed, episodes end at other frames, so the counts part, but the update rule must hold in
both: frames and decisions less updates, the warm-up's, equal pair by pair) and the ratio of their training
times per seed (a seed batch's time divided among its seeds).

Running the two sides (each from a worktree pinned at its commit, with Hydra's multirun; the issue's check is
3 seeds on baseline and braking):

    git worktree add ../before <commit before>  &&  git worktree add ../after <commit after>
    (cd ../before && python -m kddrl_trl.train -m seed=0,1,2 +scenario=baseline,braking hydra.sweep.dir=runs/eq)
    (cd ../after && python -m kddrl_trl.train -m seed=0,1,2 +scenario=baseline,braking hydra.sweep.dir=runs/eq)
    python -m kddrl_trl.devtools.equivalence ../before/runs/eq ../after/runs/eq [--out PATH]

Every run must have its partner, with the same ``config.yaml`` (else the error names the run and the keys that
differ). Prints a table and writes ``benchmarks/results/equivalence.json`` (or ``--out``).

Beside the paired interval, each measure has Welch's (the two sides as independent samples: the pairs share a seed,
not a trajectory, where the arithmetic changed, so pairing may gain nothing). ``--margins SPEED COLLISION`` (km/h
and percentage points, stated before the runs) adds the decision of an equivalence study: a measure is equivalent
when both intervals contain 0 and lie inside ±its margin; ``--scenario`` keeps one scenario's runs, for margins
that differ by scenario. A seed batch against the same seeds alone is such a
change (``studies/performance/seed_batch_plan.md``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from kddrl_trl.atomic_files import write_json_atomic
from kddrl_trl.reporting.records import find_runs, record_bytes
from kddrl_trl.reporting.stats import difference_test, mean_test
from kddrl_trl.run_folder import config_differences

#: the measures compared, from each run's final evaluation: (name, summary key, scale to the unit, unit)
MEASURES = (("mean speed", "mean_speed_kmh", 1.0, "km/h"), ("collision rate", "collision_rate", 100.0, "points"))
#: update counts that match pair by pair where the arithmetic did not change (a byte-identical change)
COUNTS = ("cf_updates", "lc_updates", "frames", "episodes")
#: (count, updates): where the arithmetic changed, episodes end at other frames and the counts part, but the
#: update rule must not: one TD3 update per frame and one D3QN update per decision once the warm-up is over, so
#: ``count - updates`` (the frames and decisions of the warm-up, which no update has touched yet) match pair by pair
RULES = (("frames", "cf_updates"), ("decisions", "lc_updates"))


def _rule_offsets(training: dict) -> tuple:
    """``count - updates`` for each of :data:`RULES` (None where the summary lacks either)."""
    return tuple(
        training[c] - training[u] if training.get(c) is not None and training.get(u) is not None else None
        for c, u in RULES
    )


def _same_training(a: Path, b: Path) -> bool | None:
    """Whether two runs' ``train_episodes.csv`` are byte for byte the same, each decompressed where it is kept
    compressed; None where either has none (a rule-based algo trains nothing)."""
    try:
        return record_bytes(a, "train_episodes.csv") == record_bytes(b, "train_episodes.csv")
    except FileNotFoundError:
        return None


def pairs(before, after, scenario: str | None = None) -> list[dict]:
    """The runs of ``before`` and ``after`` matched by (algo, scenario, seed), only those of ``scenario`` where it
    is given; raises on a run without a partner, a pair whose configs differ, or a ``scenario`` with no run."""
    a, b = (
        {(r.algo, r.scenario, r.seed): r for r in find_runs([side]) if scenario in (None, r.scenario)}
        for side in (before, after)
    )
    if not a and not b:
        raise ValueError(f"no run of scenario {scenario!r} in {before} or {after}")
    lone = sorted(set(a) ^ set(b))
    if lone:
        where = ", ".join(f"{k} only in {before if k in a else after}" for k in lone[:6])
        raise ValueError(f"runs without a partner: {where}")
    out = []
    for key in sorted(a):
        ra, rb = a[key], b[key]
        ca, cb = (OmegaConf.to_container(OmegaConf.load(r.trained / "config.yaml")) for r in (ra, rb))
        different = config_differences(ca, cb)
        if different:
            raise ValueError(f"{ra.trained} and {rb.trained} ran other configs: {'; '.join(different[:5])}")
        ta, tb = ra.trained_summary.get("training", {}), rb.trained_summary.get("training", {})
        oa, ob = _rule_offsets(ta), _rule_offsets(tb)
        ma, mb = ra.metrics(), rb.metrics()  # from the evaluation episodes, as the report computes them
        out.append(
            {
                "algo": key[0],
                "scenario": key[1],
                "seed": key[2],
                "before": {"run": str(ra.path), "commit": ra.commit, **{m[1]: ma[m[1]] for m in MEASURES}},
                "after": {"run": str(rb.path), "commit": rb.commit, **{m[1]: mb[m[1]] for m in MEASURES}},
                "counts_equal": all(ta.get(c) == tb.get(c) for c in COUNTS),
                "warmup_offsets": [oa, ob],
                "update_rule_equal": None not in oa and oa == ob,
                "training_identical": _same_training(ra.trained, rb.trained),
                "training_time_ratio": (tb["elapsed_s"] * rb.seed_share) / (ta["elapsed_s"] * ra.seed_share)
                if ta.get("elapsed_s") and tb.get("elapsed_s")
                else None,
            }
        )
    return out


def differences(rows: list[dict], margins: tuple[float, float] | None = None) -> dict:
    """Per measure: the paired difference after − before, its 95 % interval and two-sided p (n >= 2), Welch's
    interval and p of the same difference (``welch``), and, given ``margins`` (one per measure, in its unit), the
    margin and whether the measure is equivalent: both intervals known, containing 0 and inside ±margin."""
    out = {}
    for i, (name, key, scale, unit) in enumerate(MEASURES):
        before = np.array([scale * r["before"][key] for r in rows])
        after = np.array([scale * r["after"][key] for r in rows])
        t = mean_test(after - before)
        w = difference_test(after, before)
        out[name] = {
            "unit": unit,
            "pairs": int(before.size),
            "difference": t["mean"],
            "ci": [t["ci_low"], t["ci_high"]],
            "p": t["p"],
            "welch": {"ci": [w["ci_low"], w["ci_high"]], "p": w["p"]},
        }
        if margins is not None:
            m = float(margins[i])
            cis = (out[name]["ci"], out[name]["welch"]["ci"])
            out[name]["margin"] = m
            out[name]["equivalent"] = all(lo is not None and -m <= lo <= 0 <= hi <= m for lo, hi in cis)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("before", type=Path, help="sweep (or run) folder of the code before the change")
    p.add_argument("after", type=Path, help="the same runs of the code after it")
    p.add_argument("--out", type=Path, default=Path("benchmarks") / "results" / "equivalence.json")
    p.add_argument("--note", default=None, help="free text stored in the JSON (where and how the runs ran)")
    p.add_argument(
        "--margins",
        type=float,
        nargs=2,
        metavar=("SPEED", "COLLISION"),
        default=None,
        help="equivalence margins stated before the runs, km/h and percentage points (module docstring)",
    )
    p.add_argument(
        "--scenario", default=None, help="compare only this scenario's runs (each scenario has margins of its own)"
    )
    args = p.parse_args(argv)
    if args.margins is not None and not all(m > 0 for m in args.margins):
        p.error(f"--margins: each margin must be > 0, got {args.margins}")
    rows = pairs(args.before, args.after, args.scenario)
    groups = {"pooled": rows}
    for r in rows:
        groups.setdefault(f"{r['algo']} on {r['scenario']}", []).append(r)
    result = {
        "before": sorted({r["before"]["commit"] for r in rows}),
        "after": sorted({r["after"]["commit"] for r in rows}),
        "pairs": rows,
        "by_group": {g: differences(rs, args.margins) for g, rs in groups.items()},
        "counts_equal": all(r["counts_equal"] for r in rows),
        "update_rule_equal": all(r["update_rule_equal"] for r in rows),
        "training_identical": sum(r["training_identical"] is True for r in rows),
        "training_time_ratio": [r["training_time_ratio"] for r in rows],
        **({"note": args.note} if args.note else {}),
    }
    print(
        f"{'group':32s} {'measure':16s} {'pairs':>5s}  after − before  paired [95 % CI]      p"
        f"     Welch [95 % CI]       p  margin  equivalent"
    )
    for g, ms in result["by_group"].items():
        for name, m in ms.items():
            cells = [f"{m['difference']:+7.2f} {m['unit']:6s}"]
            for ci, pv in ((m["ci"], m["p"]), (m["welch"]["ci"], m["welch"]["p"])):
                cells.append("" if ci[0] is None else f"[{ci[0]:+.2f}, {ci[1]:+.2f}]")
                cells.append("" if pv is None else f"{pv:.2f}")
            if "margin" in m:
                cells += [f"±{m['margin']:g}", "yes" if m["equivalent"] else "NO"]
            print(
                f"{g:32s} {name:16s} {m['pairs']:5d}  {cells[0]:15s} {cells[1]:18s} {cells[2]:5s} "
                f"{cells[3]:18s} {cells[4]:5s} {' '.join(cells[5:])}"
            )
    print(
        f"update counts equal in every pair: {result['counts_equal']}; update rule (frames and decisions less "
        f"updates) equal in every pair: {result['update_rule_equal']}; training records byte-identical in "
        f"{result['training_identical']} of {len(rows)} pairs"
    )
    ratios = [r for r in result["training_time_ratio"] if r is not None]
    if ratios:
        print(
            f"training time per seed, after / before: mean {np.mean(ratios):.3f} "
            f"(pairs {min(ratios):.3f}-{max(ratios):.3f})"
        )
    write_json_atomic(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
