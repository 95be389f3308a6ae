"""``studies/safety/report.py``: the plan's four goals, the layer's cost and the sanity check from run records, and
the refusal of a run of another commit."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from testkit import fake_run


def _report():
    from studies.safety import report

    return report


def run(folder: Path, algo: str, scenario: str, seed: int, speed: float, faults: list[str], shield: int = 0):
    """A run of 20 test episodes at ``speed``, one collision per entry of ``faults`` (its class), ``shield``
    interventions in each 100-frame episode, and a 200-episode training record."""
    n = 20
    collisions = [True] * len(faults) + [False] * (n - len(faults))
    fake_run(
        folder, algo=algo, seed=seed, scenario=scenario, speeds=[speed] * n, collisions=collisions, commit="abc1234",
        wall_s=360.0, machine="Linux-6.18-x86_64, AMD EPYC, Python 3.11.7, 2 CPUs",
    )  # fmt: skip
    ep = pd.read_csv(folder / "eval_episodes.csv")
    ep["collision_fault"] = faults + [""] * (n - len(faults))
    ep["shield_interventions"] = shield
    ep.to_csv(folder / "eval_episodes.csv", index=False)
    hits = [True] * 60 + [False] * 140
    pd.DataFrame(
        {
            "index": range(200),
            "return_lc": 0.0,
            "return_cf": 0.0,
            "mean_speed_kmh": speed,
            "collision": hits,
            "frames": 100,
            "shield_interventions": shield,
        }
    ).to_csv(folder / "train_episodes.csv", index=False)


def study(tmp_path: Path) -> Path:
    root = tmp_path / "safety"
    for seed in (100, 101, 102):
        for sc in ("baseline", "braking"):
            run(root / "runs" / f"{sc}__kddrl__{seed}", "kddrl", sc, seed, 130.0 + seed % 3, [], shield=5)
            run(root / "runs" / f"{sc}__idm_mobil__{seed}", "idm_mobil", sc, seed, 110.0 - seed % 2, ["other"])
            run(root / "runs_unshielded" / f"{sc}__kddrl__{seed}", "kddrl", sc, seed, 140.0, ["ego", "ego"])
    run(root / "sanity" / "paper" / "braking__d3qn_td3__0", "d3qn_td3", "braking", 0, 140.0, ["ego"] * 10)
    for seed in (5, 6):  # the paper's method without the layer, from the verdict study (another commit)
        run(tmp_path / "paper" / "runs_5-14" / f"braking__kddrl__{seed}", "kddrl", "braking", seed, 120.0, ["ego"] * 4)
    return root


def test_the_goals_the_cost_and_the_sanity_check(tmp_path):
    report = _report()
    result = report.build(study(tmp_path), commit="abc1234")
    rows = {(r["arm"], r["scenario"]): r for r in result["goals"]}
    braking = rows[("KDDRL safe", "braking")]
    assert braking["G1"] == {"ego_fault": 0, "upper95": pytest.approx(1 - 0.05 ** (1 / 60)), "holds": True}
    assert braking["G2"]["collisions"] == 0 and braking["G2"]["reference_collisions"] == 3 and braking["G2"]["holds"]
    assert braking["G3"]["mean"] == pytest.approx(131.0 / (110.0 - 1 / 3)) and braking["G3"]["holds"]
    assert braking["G4"]["mean"] == pytest.approx(0.05) and braking["G4"]["decided"]
    assert braking["G4"]["train_last100"] == pytest.approx(0.05)
    assert result["pooled_G1"]["KDDRL safe"]["episodes"] == 120
    (cost,) = [c for c in result["layer_cost"] if c["scenario"] == "braking"]
    assert cost["mean_speed_kmh"]["mean"] == pytest.approx(131.0 - 140.0)
    assert cost["collision_rate"]["mean"] == pytest.approx(-0.1)
    faults = {(f["algo"], f["scenario"]): f for f in result["faults"]}
    assert faults[("idm_mobil", "baseline")]["other"] == 3 and faults[("idm_mobil", "baseline")]["ego"] == 0
    (paper,) = result["against_paper"]
    assert paper["scenario"] == "braking" and paper["speed"]["mean"] == pytest.approx(131.0 - 120.0)
    assert paper["collision_rate"]["mean"] == pytest.approx(-0.2)
    compute = {c["algo"]: c for c in result["compute"]}  # the study's runs only, not those without the layer
    assert compute["kddrl"]["runs"] == 6 and compute["kddrl"]["wall_h"] == pytest.approx(0.6)
    assert compute["kddrl"]["cpus"] == ["AMD EPYC"] and "| idm_mobil | 6 | 0.6 | AMD EPYC |" in report.markdown(result)
    (sane,) = result["sanity"]
    assert sane["reward"] == "paper" and sane["test_collision_rate"] == pytest.approx(0.5)
    # crashes in episodes 1-60: the last 50-episode window with 3 of them (>= 5 %) ends at episode 107
    assert sane["first_safe_episode"] == 108
    text = report.markdown(report._clean(result))
    assert "| KDDRL safe | braking | 3 (100-102) | 0 / 60 [" in text
    json.dumps(report._clean(result))
    assert report.fault_figure(report._clean(result), tmp_path / "fig.png").read_bytes()[:4] == b"\x89PNG"


def test_a_run_of_another_commit_is_refused(tmp_path):
    report = _report()
    root = study(tmp_path)
    summary = root / "runs" / "baseline__kddrl__100" / "summary.json"
    summary.write_text(json.dumps({**json.loads(summary.read_text()), "commit": "fffffff"}))
    with pytest.raises(SystemExit, match="baseline__kddrl__100: commit fffffff, not the plan's pinned abc1234"):
        report.build(root, commit="abc1234")


def test_the_compute_counts_a_seed_batch_s_clock_once():
    """Seeds trained as one batch each record the batch's wall time; the study's compute counts it once."""
    from kddrl_trl.reporting.records import RunRecord

    def run(seed, batch=None):
        summary = {"algo": "kddrl", "wall_s": 3600.0, "machine": "x, AMD EPYC"}
        if batch:
            summary["seed_batch"] = {"index": batch.index(seed), "seeds": batch}
        return RunRecord(Path(f"r{seed}"), "kddrl", "braking", seed, summary, pd.DataFrame())

    (row,) = _report().compute(
        [run(0, [0, 1, 2, 3]), run(1, [0, 1, 2, 3]), run(2, [0, 1, 2, 3]), run(3, [0, 1, 2, 3]), run(9)]
    )
    assert row["runs"] == 5 and row["wall_h"] == pytest.approx(2.0)
