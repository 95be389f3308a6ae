"""``kddrl_trl.devtools.equivalence`` (the paired differences of a float-only change, on copies of committed runs),
``benchmarks/gpu_update_gap.py`` (its arms, in its CPU trial mode), ``benchmarks/gpu_determinism.py`` (its hashes
and their comparison, on the CPU) and ``kddrl_trl.devtools.ab_records`` (two run folders of one job compared)."""

from __future__ import annotations

import json
import lzma
import shutil
import subprocess
from pathlib import Path

import pandas as pd
import pytest
from testkit import TINY_BUDGET, fake_run, load_benchmark, study_records

ROOT = Path(__file__).resolve().parents[1]

NAMES = [f"baseline__kddrl__{s}" for s in (0, 1, 2)]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> list[Path]:
    """Three committed runs of the verdict study, from main's history."""
    studies = study_records(tmp_path_factory.mktemp("records"), *(f"studies/paper/runs/{n}" for n in NAMES))
    return [studies / "paper" / "runs" / n for n in NAMES]


@pytest.fixture(scope="module")
def bench():
    from kddrl_trl.devtools import equivalence

    return equivalence


def copy_runs(runs: list[Path], root: Path) -> Path:
    for run in runs:
        shutil.copytree(run, root / run.name)
    return root


def shift_speed(run: Path, kmh: float) -> None:
    """Adds ``kmh`` to every evaluation episode's mean speed of ``run`` (as a faster policy would)."""
    path = run / "eval_episodes.csv.xz"
    df = pd.read_csv(path)
    df["mean_speed_kmh"] += kmh
    path.write_bytes(lzma.compress(df.to_csv(index=False).encode()))


def test_equivalence_pairs_runs_and_measures_the_difference(bench, runs, tmp_path):
    before, after = copy_runs(runs, tmp_path / "before"), copy_runs(runs, tmp_path / "after")
    out = tmp_path / "eq.json"
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0
    same = json.loads(out.read_text())
    speed = same["by_group"]["pooled"]["mean speed"]
    assert speed["pairs"] == 3 and speed["difference"] == 0 and speed["ci"] == [0, 0]
    assert same["training_identical"] == 3 and same["counts_equal"]
    packed = after / runs[0].name / "train_episodes.csv.xz"  # one record kept plain: the same content
    packed.with_suffix("").write_bytes(lzma.decompress(packed.read_bytes()))
    packed.unlink()
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0
    assert json.loads(out.read_text())["training_identical"] == 3
    for run, kmh in zip(sorted(after.iterdir()), (1.0, 2.0, 3.0)):
        shift_speed(run, kmh)
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0
    moved = json.loads(out.read_text())["by_group"]["kddrl on baseline"]["mean speed"]
    assert moved["difference"] == pytest.approx(2.0) and moved["ci"][0] < 2.0 < moved["ci"][1]
    collisions = json.loads(out.read_text())["by_group"]["pooled"]["collision rate"]
    assert collisions["difference"] == 0
    welch = moved["welch"]["ci"]  # the same difference as two independent samples: the seeds' spread widens it
    assert welch[0] < 2.0 < welch[1] and welch[1] - welch[0] > moved["ci"][1] - moved["ci"][0]


def test_equivalence_decides_against_margins_stated_before(bench, runs, tmp_path):
    """``--margins``: a measure is equivalent when both intervals contain 0 and lie inside ±margin. Unchanged runs
    are at a margin wider than Welch's interval of three seeds, not at one narrower (the paired interval is 0
    there); a constant shift (a paired interval that excludes 0) is not; a margin that is not positive is refused."""
    before, after = copy_runs(runs, tmp_path / "before"), copy_runs(runs, tmp_path / "after")
    out = tmp_path / "eq.json"
    assert bench.main([str(before), str(after), "--out", str(out), "--margins", "50", "50"]) == 0
    same = json.loads(out.read_text())["by_group"]["kddrl on baseline"]
    assert same["mean speed"]["equivalent"] and same["collision rate"]["equivalent"]
    assert (same["mean speed"]["margin"], same["collision rate"]["margin"]) == (50.0, 50.0)
    assert bench.main([str(before), str(after), "--out", str(out), "--margins", "0.01", "50"]) == 0
    narrow = json.loads(out.read_text())["by_group"]["kddrl on baseline"]["mean speed"]
    assert narrow["ci"] == [0, 0] and narrow["welch"]["ci"][1] > 0.01 and not narrow["equivalent"]
    for run in after.iterdir():
        shift_speed(run, 1.0)
    assert bench.main([str(before), str(after), "--out", str(out), "--margins", "50", "50"]) == 0
    shifted = json.loads(out.read_text())["by_group"]["kddrl on baseline"]
    assert not shifted["mean speed"]["equivalent"] and shifted["collision rate"]["equivalent"]
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0  # no margins: no decision
    assert "equivalent" not in json.loads(out.read_text())["by_group"]["pooled"]["mean speed"]
    with pytest.raises(SystemExit):
        bench.main([str(before), str(after), "--out", str(out), "--margins", "4", "0"])


def set_training(run: Path, **delta: int) -> None:
    """Adds ``delta`` to the counts of ``run`` 's training summary."""
    path = run / "summary.json"
    summary = json.loads(path.read_text())
    for key, d in delta.items():
        summary["training"][key] += d
    path.write_text(json.dumps(summary))


def test_equivalence_checks_the_update_rule_where_the_counts_part(bench, runs, tmp_path):
    """Runs whose episodes ended at other frames (a float change) part in their counts but keep the update rule
    (frames and decisions less updates: the warm-up's); an update more per frame breaks the rule."""
    before, after = copy_runs(runs, tmp_path / "before"), copy_runs(runs, tmp_path / "after")
    out = tmp_path / "eq.json"
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0
    assert json.loads(out.read_text())["update_rule_equal"]
    run = after / runs[0].name
    set_training(run, frames=960, cf_updates=960, decisions=48, lc_updates=48)
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert not result["counts_equal"] and result["update_rule_equal"]
    set_training(run, cf_updates=1)
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0
    assert not json.loads(out.read_text())["update_rule_equal"]


def test_equivalence_refuses_a_run_without_partner_and_other_configs(bench, runs, tmp_path):
    before, after = copy_runs(runs, tmp_path / "before"), copy_runs(runs, tmp_path / "after")
    shutil.rmtree(after / runs[2].name)
    with pytest.raises(ValueError, match="without a partner.*baseline.*2"):
        bench.pairs(before, after)
    shutil.copytree(runs[2], after / runs[2].name)
    config = after / runs[1].name / "config.yaml"
    config.write_text(config.read_text().replace("episodes: 1000", "episodes: 999", 1))
    with pytest.raises(ValueError, match="other configs.*episodes"):
        bench.pairs(before, after)


def test_equivalence_compares_one_scenario_where_asked(bench, runs, tmp_path):
    """``--scenario``: only that scenario's runs are paired, so a run of another scenario without its partner
    (a study whose second scenario is still running) is left out there and refused without it; a scenario with no
    run is refused, naming it."""
    before, after = copy_runs(runs, tmp_path / "before"), copy_runs(runs, tmp_path / "after")
    other = before / "braking__kddrl__0"
    shutil.copytree(runs[0], other)
    summary = json.loads((other / "summary.json").read_text())
    (other / "summary.json").write_text(json.dumps({**summary, "scenario": "braking"}))
    with pytest.raises(ValueError, match="without a partner.*braking"):
        bench.pairs(before, after)
    assert [r["seed"] for r in bench.pairs(before, after, "baseline")] == [0, 1, 2]
    out = tmp_path / "eq.json"
    assert bench.main([str(before), str(after), "--out", str(out), "--scenario", "baseline"]) == 0
    assert set(json.loads(out.read_text())["by_group"]) == {"pooled", "kddrl on baseline"}
    with pytest.raises(ValueError, match="no run of scenario 'highway'"):
        bench.pairs(before, after, "highway")


def test_equivalence_divides_a_batch_time_among_its_seeds(bench, runs, tmp_path):
    """A run trained in a seed batch (``seed_batch`` in its summary) shares the batch's clock: its training time is
    the batch's divided among the batch's seeds, so three batched seeds that took the time of one each alone read
    as a third of it."""
    before, after = copy_runs(runs, tmp_path / "before"), copy_runs(runs, tmp_path / "after")
    out = tmp_path / "eq.json"
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0
    assert json.loads(out.read_text())["training_time_ratio"] == [1.0, 1.0, 1.0]
    for run in after.iterdir():
        path = run / "summary.json"
        summary = json.loads(path.read_text())
        path.write_text(json.dumps({**summary, "seed_batch": {"index": 0, "seeds": [0, 1, 2]}}))
    assert bench.main([str(before), str(after), "--out", str(out)]) == 0
    assert json.loads(out.read_text())["training_time_ratio"] == pytest.approx([1 / 3] * 3)


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


def test_gpu_determinism_hashes_tell_tensors_apart():
    """``tensor_hashes`` hashes every tensor of a nested state (dtype, shape and bytes: a changed bit, a changed
    dtype or a changed shape changes the hash) and ``compare`` names the tensors that differ."""
    import torch

    det = load_benchmark("gpu_determinism")
    state = {"modules": {"w": torch.ones(2, 3), "flag": torch.tensor(True)}, "optimizers": {"s": [torch.zeros(())]}}
    a = det.tensor_hashes(state)
    assert set(a) == {"modules.w", "modules.flag", "optimizers.s.0"}
    assert det.tensor_hashes(state) == a
    bit = torch.ones(2, 3)
    bit.view(torch.int32)[0, 0] ^= 1  # one bit of one float
    for other in (bit, torch.ones(3, 2), torch.ones(2, 3, dtype=torch.float64)):
        b = det.tensor_hashes({**state, "modules": {**state["modules"], "w": other}})
        assert b["modules.w"] != a["modules.w"] and b["modules.flag"] == a["modules.flag"]
    run = {"tensors": a, "losses_sha256": "x"}
    assert det.compare(run, run)["identical"]
    changed = det.compare(run, {"tensors": {**a, "modules.w": "y"}, "losses_sha256": "x"})
    assert not changed["identical"] and changed["tensors_differing"] == ["modules.w"]


@pytest.mark.slow
def test_gpu_determinism_script_repeats_itself_on_the_cpu(tmp_path):
    """Two runs of ``benchmarks/gpu_determinism.py`` with one seed write the same hashes (the CPU learner
    repeats itself bit for bit); another seed's differ."""
    det = load_benchmark("gpu_determinism")
    outs = [tmp_path / f"{name}.json" for name in ("a", "b", "c")]
    for out, seed in zip(outs, ("0", "0", "1")):
        assert det.main(["--device", "cpu", "--updates", "6", "--seed", seed, "--out", str(out)]) == 0
    a, b, c = (json.loads(o.read_text()) for o in outs)
    assert det.compare(a, b)["identical"] and len(a["tensors"]) > 100
    assert not det.compare(a, c)["identical"] and not det.compare(a, c)["losses_identical"]


def ab_run(folder: Path, weight: float = 1.0, loss: str = "0.5", seconds: str = "1.0") -> Path:
    """A finished run folder (:func:`testkit.fake_run`) with what ``ab_records.py`` reads beyond it: training
    counts, a scalar log, a wall-clock log and a checkpoint."""
    import torch

    fake_run(folder, training={"cf_updates": 4, "frames": 8, "episodes": 2})
    (folder / "logs" / "scalars" / "train").mkdir(parents=True)
    (folder / "logs" / "scalars" / "time").mkdir(parents=True)
    (folder / "checkpoints").mkdir()
    (folder / "logs" / "scalars" / "train" / "loss.csv").write_text(f"0,{loss}\n")
    (folder / "logs" / "scalars" / "time" / "elapsed_s.csv").write_text(f"0,{seconds}\n")
    state = {"modules": {"w": torch.tensor([weight, 2.0])}, "optimizers": {"cf": {"state": {0: torch.zeros(2)}}}}
    torch.save({"learner": state}, folder / "checkpoints" / "ep000002.pt")
    return folder


def test_ab_records_says_identical_only_when_every_record_log_and_bit_is(tmp_path):
    """Wall-clock logs may differ; a record, a scalar log or one bit of a parameter may not, and each is named."""
    from kddrl_trl.devtools import ab_records as ab

    before = ab_run(tmp_path / "before")
    out = tmp_path / "ab.json"
    assert ab.main([str(before), str(ab_run(tmp_path / "same", seconds="9.0")), "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["identical"] and result["checkpoint"] == "ep000002.pt"
    assert result["records_sha256_16"]["before"]["validation.csv"] is None  # absent from both: no difference

    nudged = torch_nextafter_one()
    assert ab.main([str(before), str(ab_run(tmp_path / "bit", weight=nudged)), "--out", str(out)]) == 1
    result = json.loads(out.read_text())
    assert result["records_identical"] and not result["checkpoint_parameters_identical"]
    assert result["checkpoint_optimizer_states_identical"]

    assert ab.main([str(before), str(ab_run(tmp_path / "log", loss="0.6")), "--out", str(out)]) == 1
    assert json.loads(out.read_text())["scalar_logs_differing"] == ["train/loss.csv"]


def test_ab_records_cuts_out_a_declared_new_column_and_nothing_else(tmp_path):
    """A record with one more column matches only through ``--new-columns`` naming it, and only when the rest of
    each line is the same text; the before side may not hold the column already."""
    import pandas as pd

    from kddrl_trl.devtools import ab_records as ab

    before, after = ab_run(tmp_path / "before"), ab_run(tmp_path / "after")
    episodes = pd.read_csv(before / "eval_episodes.csv")
    added = episodes.assign(collision_fault=["ego" if c else "" for c in episodes["collision"]])
    (after / "eval_episodes.csv").write_text(added.to_csv(index=False))
    out = tmp_path / "ab.json"
    assert ab.main([str(before), str(after), "--out", str(out)]) == 1
    assert ab.main([str(before), str(after), "--out", str(out), "--new-columns", "collision_fault"]) == 0
    assert json.loads(out.read_text())["new_columns"] == ["collision_fault"]
    changed = added.copy()
    changed.loc[0, "mean_speed_kmh"] += 0.001
    (after / "eval_episodes.csv").write_text(changed.to_csv(index=False))
    assert ab.main([str(before), str(after), "--out", str(out), "--new-columns", "collision_fault"]) == 1
    with pytest.raises(SystemExit, match="already has collision_fault"):
        ab.main([str(after), str(after), "--out", str(out), "--new-columns", "collision_fault"])


def torch_nextafter_one() -> float:
    """The float32 just above 1.0: one bit off."""
    import torch

    return float(torch.nextafter(torch.tensor(1.0), torch.tensor(2.0)))


def test_default_job_alternates_the_commits_and_gives_the_ratio(tmp_path, monkeypatch):
    """``benchmarks/default_job.py``: A B A B, one worktree a commit, the ratio of the means (the job itself
    stands in: a real default job takes minutes)."""
    bench = load_benchmark("default_job")
    order, times = [], {"A": iter([100.0, 110.0]), "B": iter([80.0, 90.0])}

    def fake_run(tree, out, overrides):
        label = out.name[0]
        order.append(label)
        t = next(times[label])
        return {
            "process_s": t,
            "training_s": t / 2,
            "wall_s": t,
            "compile_s": 1.0,
            "collision_rate": 0.0,
            "mean_speed_kmh": 100.0,
        }

    monkeypatch.setattr(bench, "run_job", fake_run)
    out, work = tmp_path / "default_job.json", tmp_path / "work"
    try:
        result = bench.main(["--a", "HEAD", "--b", "HEAD", "--work", str(work), "--out", str(out), "episodes=2"])
    finally:
        for tree in work.glob("*/"):
            if (tree / ".git").exists():
                subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=bench.ROOT, check=False)
    assert order == ["A", "B", "A", "B"]
    assert result["ratio_b_over_a"]["process_s"] == pytest.approx(85.0 / 105.0)
    assert (
        result["job"] == "python -m kddrl_trl.train episodes=2" and json.loads(out.read_text())["runs"][3]["round"] == 1
    )
    assert result["commits"]["A"] == result["commits"]["B"] and len(result["commits"]["A"]) == 40


def test_compile_cost_runs_eager_cold_and_warm_with_the_cache_emptied_once(tmp_path, monkeypatch):
    """``benchmarks/compile_cost.py``: the cold run starts from an empty cache folder, the warm one reuses it (the
    job itself stands in); over several lengths the cold arm runs once, and the crossover is where the compiled
    job's line meets the eager one's."""
    bench = load_benchmark("compile_cost")
    seen = []

    def fake_run(out, cache, compile_, overrides):
        seen.append((out.name, compile_, sorted(p.name for p in cache.iterdir())))
        (cache / "entry").write_text("compiled")  # what a compiled run leaves in the cache
        episodes = int(next(o for o in overrides if o.startswith("episodes=")).split("=")[1])
        compile_s = {"eager": 0.0, "cold": 30.0, "warm": 10.0}[out.name.split("0_")[0]]
        per_episode = 1.0 if compile_ == "false" else 0.5  # the compiled job trains faster per episode
        process_s = 20.0 + compile_s + per_episode * episodes
        return {"process_s": process_s, "training_s": 15.0, "compile_s": compile_s, "compile_counts": {}}

    monkeypatch.setattr(bench, "run_job", fake_run)
    result = bench.main(["--out", str(tmp_path / "compile_cost.json"), "--episodes", "20", "100"])
    assert [s[:2] for s in seen] == [
        ("eager0_20", "false"),
        ("cold0_20", "true"),
        ("warm0_20", "true"),
        ("eager0_100", "false"),
        ("warm0_100", "true"),
    ]
    assert seen[1][2] == [] and seen[2][2] == ["entry"]  # cold: emptied; warm: what the cold run left
    assert result["ratios"]["compile_s_cold_over_warm"] == 3.0 and result["job"].endswith("episodes=20,100")
    # eager 20 + n, warm 30 + n / 2: equal at n = 20; cold 50 + n / 2: at n = 60
    assert result["crossover_episodes"]["warm"] is None  # already equal at the first length: not crossed within
    assert result["crossover_episodes"]["cold"] == 60.0


def test_compile_graphs_alternates_the_arms_each_cold_then_warm_on_a_cache_of_its_own(tmp_path, monkeypatch):
    """``benchmarks/compile_graphs.py``: the arms alternate round by round; each arm's warm run reads the cache its
    cold run filled, and no two arms or rounds share one; the ratios are one / three of the medians."""
    bench = load_benchmark("compile_graphs")
    seen = []

    def fake_arm(arm, cache):
        cache.mkdir(exist_ok=True)
        state = "warm" if (cache / "entry").exists() else "cold"
        (cache / "entry").write_text("compiled")
        seen.append((arm, cache.name, state))
        return {"compile_s": {"three": 40.0, "one": 30.0}[arm] / (3.0 if state == "warm" else 1.0)}

    monkeypatch.setattr(bench, "run_arm", fake_arm)
    result = bench.main(["--rounds", "2", "--out", str(tmp_path / "compile_graphs.json")])
    assert seen == [
        ("three", "three0", "cold"),
        ("three", "three0", "warm"),
        ("one", "one0", "cold"),
        ("one", "one0", "warm"),
        ("three", "three1", "cold"),
        ("three", "three1", "warm"),
        ("one", "one1", "cold"),
        ("one", "one1", "warm"),
    ]
    assert result["summary"]["one_over_three_cold"] == pytest.approx(0.75)
    assert result["summary"]["three_warm_s"] == pytest.approx(40.0 / 3)
    assert json.loads((tmp_path / "compile_graphs.json").read_text())["runs"][2]["arm"] == "one"


BENCHMARKS = sorted(
    p.stem for p in (Path(__file__).resolve().parents[1] / "benchmarks").glob("*.py") if p.stem != "__init__"
)


@pytest.mark.parametrize("name", BENCHMARKS)
def test_every_benchmark_imports_as_a_package_module_and_answers_help(name, capsys):
    """Each script runs as ``python -m benchmarks.<name>`` (no ``sys.path`` edits) and its ``--help`` parses; a script
    with a results file writes ``benchmarks/results/<name>.json`` by default."""
    module = load_benchmark(name)
    if not hasattr(module, "main"):  # a shared module (kddrl_parts, jobs)
        return
    with pytest.raises(SystemExit) as done:
        module.main(["--help"])
    assert done.value.code == 0 and "usage" in capsys.readouterr().out
    src = Path(module.__file__).read_text()
    assert "sys.path" not in src


@pytest.mark.benchmarks
def test_threads_runs_the_job_alone_and_beside_a_copy_of_itself_at_its_smallest_size(tmp_path):
    """``benchmarks/threads.py`` for real at its smallest size (two episodes, tiny networks): each arm's job alone,
    then two copies at once, without ``OMP_NUM_THREADS``; the ratios and the threads each job chose are recorded."""
    from testkit import TINY

    bench = load_benchmark("threads")
    out = tmp_path / "threads.json"
    result = bench.main(["--out", str(out), "--episodes", "2", "--eval-episodes", "1", *TINY])
    assert json.loads(out.read_text())["ratios"] == result["ratios"] and len(result["runs"]) == 2
    auto, fixed = result["runs"]
    assert auto["torch_threads"] == "auto" and auto["threads_chosen"]["alone"]["reason"] == "free cores"
    assert fixed["threads_chosen"]["alone"]["reason"] == "torch_threads" and len(fixed["beside_s"]) == 2
    assert all(r["slowdown"] > 0 for r in result["runs"])


@pytest.mark.benchmarks
def test_seed_batch_runs_at_its_smallest_size(tmp_path):
    """``benchmarks/seed_batch.py`` for real at its smallest size: a single learner and a batch of 2 seeds, eager
    and compiled, their per-seed ratios and the floor, and the batch's compiled update split in its parts."""
    bench = load_benchmark("seed_batch")
    out = tmp_path / "seed_batch.json"
    args = ["--seeds", "2", "--updates", "2", "--repeats", "1", "--threads", "1", "--split", "2", "--out", str(out)]
    assert bench.main(args) == 0
    result = json.loads(out.read_text())
    arms, split = result["arms"], result["split"]["2"]
    assert split["gemm"] > 0 and split["gradients"] > 0 and split["optimizer"] > 0
    assert split["total"] >= split["gradients"] + split["optimizer"] and split["total_over_floor"] > 0
    assert set(arms) == {"eager/single", "eager/seeds_2", "compiled/single", "compiled/seeds_2"}
    assert arms["eager/single"]["td3_per_seed_over_single"] == 1.0
    assert all(r["td3_per_seed_over_floor"] > 0 for r in arms.values())


def test_seed_batch_refuses_a_split_off_the_cpu(capsys):
    """The split's ratios are over the CPU's GEMM floor: on another device it says so, not skips it."""
    with pytest.raises(SystemExit):
        load_benchmark("seed_batch").main(["--device", "cuda", "--split", "2"])
    assert "--split measures against the CPU's GEMM floor" in capsys.readouterr().err


@pytest.mark.benchmarks
def test_seed_batch_job_on_c_cores_sets_c_single_runs_against_a_batch_of_c_threads(tmp_path, monkeypatch):
    """``--cores 2``: the single arm is two copies at once on one thread each, a batch gets two threads, and the
    per-seed ratio is (batch time / N) over (the copies' time / 2)."""
    bench = load_benchmark("seed_batch_job")
    calls = []

    def jobs(outs, overrides, env):
        calls.append((len(outs), env["OMP_NUM_THREADS"], overrides[0]))
        n = 1 if overrides[0] == "seed=0" else 4
        summary = lambda s, t: {"seed": s, "training": {"elapsed_s": t}, "mean_speed_kmh": 1.0, "collision_rate": 0.0}
        train = 100.0 if n == 1 else 160.0
        return [
            {"process_s": train + 10 * i, "summaries": [summary(s, train + 2 * i) for s in range(n)]}
            for i in range(len(outs))
        ]

    monkeypatch.setattr(bench, "started_train_jobs", jobs)
    result = bench.main(
        ["--seeds", "1", "4", "--cores", "2", "--work", str(tmp_path), "--out", str(tmp_path / "o.json")]
    )
    assert calls == [(2, "1", "seed=0"), (1, "2", "seeds=[0,1,2,3]")]
    assert result["mean"]["1"] == {"process_s": 110.0, "training_s": 101.0}  # the last copy's end, their mean training
    assert result["per_seed_over_alone"]["4"]["process_s"] == pytest.approx((160 / 4) / (110 / 2))
    assert result["per_seed_over_alone"]["4"]["training_s"] == pytest.approx((160 / 4) / (101 / 2))


def test_update_floor_runs_at_its_smallest_size(tmp_path):
    """``benchmarks/update_floor.py`` for real at its smallest size: the update eager and compiled, the floor and the
    update's parts (whose import of the learner's module once broke with a rename, unseen by ``--help``)."""
    bench = load_benchmark("update_floor")
    out = tmp_path / "update_floor.json"
    assert bench.main(["--updates", "2", "--repeats", "1", "--floor-threads", "1", "--update-threads", "1",
                       "--out", str(out)]) == 0  # fmt: skip
    result = json.loads(out.read_text())
    assert result["floor"] and result["update"]["torch_threads"] == 1


#: the smallest size of benchmarks that had only their ``--help`` tested: a broken import or call fails here
SMALLEST = {
    "replay_sampling": [
        "--capacity",
        "1000",
        "--batch-size",
        "8",
        "--calls",
        "4",
        "--per-batch",
        "2",
        "--seeds",
        "2",
        "--repeats",
        "1",
    ],
    "gan_inference": ["--envs", "1", "--calls", "2"],
    "transform_overhead": ["--roads", "1", "--frames", "20", "--segment", "10"],
    "env_throughput": ["--roads", "1", "--scenarios", "baseline", "--frames", "20", "--warmup", "2"],
    "update_speed": ["--updates", "4", "--repeats", "1"],
    "gpu_update": ["--device", "cpu", "--updates", "2", "--repeats", "1"],  # the device's code path, on the CPU
}
#: benchmarks that open SUMO, each run in a process of its own (libsumo runs one simulation per process): their
#: smallest size
SMALLEST_SUMO = {
    "collect_speed": ["--roads", "1", "--frames", "20"],
    "collector_overhead": ["--roads", "1", "--frames", "20"],
    "data_throughput": ["--duration", "5", "--roads", "1"],
    "soak": ["--eval-episodes", "2", "--train-episodes", "2", "--every", "1", "--roads", "1"],
    "seed_batch_job": [
        "--seeds",
        "1",
        "2",
        "--cores",
        "2",
        "episodes=2",
        "eval_episodes=1",
        "env.max_steps=60",
        *TINY_BUDGET,
    ],
}


@pytest.mark.benchmarks
@pytest.mark.parametrize("name", sorted(SMALLEST))
def test_a_benchmark_runs_at_its_smallest_size_and_writes_its_json(name, tmp_path):
    """Each of :data:`SMALLEST` for real at its smallest size: it ends without an error and writes a JSON object."""
    bench = load_benchmark(name)
    out = tmp_path / f"{name}.json"
    assert bench.main([*SMALLEST[name], "--out", str(out)]) in (0, None)
    assert isinstance(json.loads(out.read_text()), dict)


@pytest.mark.benchmarks
@pytest.mark.parametrize("name", sorted(SMALLEST_SUMO))
def test_a_sumo_benchmark_runs_at_its_smallest_size_in_a_process_of_its_own(name, tmp_path):
    """Each of :data:`SMALLEST_SUMO` as a user runs it (``python -m benchmarks.<name>``), at its smallest size: it
    ends without an error and writes a JSON object."""
    import os
    import sys

    out = tmp_path / f"{name}.json"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", f"benchmarks.{name}", *SMALLEST_SUMO[name], "--out", str(out)]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    assert isinstance(json.loads(out.read_text()), dict)


@pytest.mark.benchmarks
def test_lcgan_ablation_runs_at_its_smallest_size_on_a_dataset_just_prepared(tmp_path):
    """``benchmarks/lcgan_ablation.py`` as a user runs it, on a minute of traffic that ``python -m kddrl_trl.prepare``
    records and splits here, one seed and one epoch per variant: it ends without an error and writes both variants."""
    import os
    import sys

    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    prepare = [sys.executable, "-m", "kddrl_trl.prepare", "progress=false", "record.duration_s=60"]
    prepare += ["record.num_roads=1", "calibrate=false"]
    done = subprocess.run(prepare, cwd=tmp_path, capture_output=True, text=True, timeout=900, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    out, data = tmp_path / "lcgan_ablation.json", tmp_path / "data" / "datasets" / "synthetic_baseline_seed0"
    cmd = [sys.executable, "-m", "benchmarks.lcgan_ablation", "--seeds", "0", "--epochs", "1", "--data-dir", str(data)]
    done = subprocess.run([*cmd, "--out", str(out)], cwd=tmp_path, capture_output=True, text=True, timeout=900, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(out.read_text())
    assert {k: len(v) for k, v in result["runs"].items()} == {"adversarial": 1, "plain": 1}
    assert result["ratio_balanced_accuracy_adversarial_over_plain"] > 0
