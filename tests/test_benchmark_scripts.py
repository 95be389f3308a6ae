"""``benchmarks/equivalence.py`` (the paired differences of a float-only change, on copies of committed runs) and
``benchmarks/gpu_update_gap.py`` (its arms, in its CPU trial mode)."""

from __future__ import annotations

import json
import lzma
import shutil
from pathlib import Path

import pandas as pd
import pytest
from testkit import load_benchmark

ROOT = Path(__file__).resolve().parents[1]
RUNS = [ROOT / "docs" / "paper" / "runs" / f"baseline__kddrl__{s}" for s in (0, 1, 2)]


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("equivalence")


def copy_runs(root: Path) -> Path:
    for run in RUNS:
        shutil.copytree(run, root / run.name)
    return root


def shift_speed(run: Path, kmh: float) -> None:
    """Adds ``kmh`` to every evaluation episode's mean speed of ``run`` (as a faster policy would)."""
    path = run / "eval_episodes.csv.xz"
    df = pd.read_csv(path)
    df["mean_speed_kmh"] += kmh
    path.write_bytes(lzma.compress(df.to_csv(index=False).encode()))


def test_equivalence_pairs_runs_and_measures_the_difference(bench, tmp_path):
    before, after = copy_runs(tmp_path / "before"), copy_runs(tmp_path / "after")
    out = tmp_path / "eq.json"
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0
    same = json.loads(out.read_text())
    speed = same["by_group"]["pooled"]["mean speed"]
    assert speed["pairs"] == 3 and speed["difference"] == 0 and speed["ci"] == [0, 0]
    assert same["training_identical"] == 3 and same["counts_equal"]
    for run, kmh in zip(sorted(after.iterdir()), (1.0, 2.0, 3.0)):
        shift_speed(run, kmh)
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0
    moved = json.loads(out.read_text())["by_group"]["kddrl on baseline"]["mean speed"]
    assert moved["difference"] == pytest.approx(2.0) and moved["ci"][0] < 2.0 < moved["ci"][1]
    collisions = json.loads(out.read_text())["by_group"]["pooled"]["collision rate"]
    assert collisions["difference"] == 0


def test_equivalence_refuses_a_run_without_partner_and_other_configs(bench, tmp_path):
    before, after = copy_runs(tmp_path / "before"), copy_runs(tmp_path / "after")
    shutil.rmtree(after / RUNS[2].name)
    with pytest.raises(ValueError, match="without a partner.*baseline.*2"):
        bench.pairs(before, after)
    shutil.copytree(RUNS[2], after / RUNS[2].name)
    config = after / RUNS[1].name / "config.yaml"
    config.write_text(config.read_text().replace("episodes: 1000", "episodes: 999", 1))
    with pytest.raises(ValueError, match="other configs.*episodes"):
        bench.pairs(before, after)


@pytest.mark.slow
def test_gpu_update_gap_script_runs_its_arms_and_writes_the_ratios(tmp_path):
    """``benchmarks/gpu_update_gap.py`` on the CPU (its ``--device cpu`` trial mode): every arm gives a rate and
    the JSON holds the ratios between them."""
    gap = load_benchmark("gpu_update_gap")
    out = tmp_path / "gap.json"
    args = ["--device", "cpu", "--batches", "16", "--updates", "4", "--repeats", "1", "--out", str(out)]
    assert gap.main(args) == 0
    row = json.loads(out.read_text())["by_batch"]["16"]
    assert all(row[a]["td3_updates_per_s"] > 0 for a in gap.ARMS)
    assert set(row["ratios"]) == {
        "ours_vs_torchrl_mujoco",
        "ours_vs_torchrl_our_shapes",
        "ours_no_embedding_vs_torchrl_our_shapes",
        "ours_vs_ours_no_embedding",
    }
