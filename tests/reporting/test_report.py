"""Evidence: the evaluation protocol, a tiny sweep as typed, the report on it, determinism, traces and videos."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from testkit import TINY_BUDGET, fake_run, run_module

from kddrl_trl.protocol import TEST_OFFSET, VALIDATION_OFFSET, check_disjoint, protocol
from kddrl_trl.reporting.records import find_runs
from kddrl_trl.reporting.stats import difference_ci, mean_ci, ratio_ci

#: a tiny KDDRL budget that still trains, validates and evaluates
TINY = [
    "episodes=4",
    "eval_episodes=4",
    *TINY_BUDGET,
    "train.eval_every=2",
    "train.eval_episodes=2",
    "env.max_steps=120",
]


# ------------------------------------------------------------------------------------------ protocol
def test_evaluation_seeds_never_repeat_training_traffic():
    p = protocol(seed=3, episodes=1000, eval_seed=None, eval_episodes=1000)
    assert p == {
        "train_seeds": [3, 1002],
        "validation_seed": 3 + VALIDATION_OFFSET,
        "eval_seed": 3 + TEST_OFFSET,
        "eval_episodes": 1000,
    }
    with pytest.raises(ValueError, match=r"eval_seed=500 lies in the training seeds \[0, 1000\)"):
        protocol(seed=0, episodes=1000, eval_seed=500, eval_episodes=10)
    check_disjoint("eval_seed", 1000, 0, 1000)  # just past the last training seed: allowed


def test_an_overlapping_eval_seed_is_refused_before_any_simulator_starts():
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=["eval_seed=10", "seed=5"])
    with pytest.raises(ValueError, match="eval_seed=10 lies in the training seeds"):
        OmegaConf.to_object(cfg)


# ---------------------------------------------------------------------------------------------- stats
def test_intervals_over_seeds():
    ci = mean_ci([1.0, 2.0, 3.0, 4.0, 5.0])  # t(0.975, 4) = 2.776, se = 0.707
    assert ci["mean"] == 3.0 and (ci["ci_low"], ci["ci_high"]) == pytest.approx((3 - 1.963, 3 + 1.963), abs=1e-3)
    assert mean_ci([2.0]) == {"mean": 2.0, "ci_low": None, "ci_high": None, "n": 1}
    assert mean_ci([0.0, 0.0, 0.0])["ci_low"] == 0.0
    with pytest.raises(ValueError, match="finite"):
        mean_ci([1.0, float("nan")])
    lower = difference_ci([1.0, 1.1, 0.9], [5.0, 5.2, 4.9])
    assert lower["ci_high"] < 0 and lower["p_greater"] == 0.0
    same = difference_ci([1.0, 2.0, 3.0], [1.5, 2.5, 2.0])
    assert same["ci_low"] < 0 < same["ci_high"]
    faster = ratio_ci([110.0, 112.0, 108.0], [100.0, 101.0, 99.0])
    assert faster["mean"] == pytest.approx(1.1) and 1.0 < faster["ci_low"] < 1.1 < faster["ci_high"]
    with pytest.raises(ValueError, match="means must be > 0"):
        ratio_ci([1.0], [0.0])


def test_records_refuse_bad_files_naming_file_and_column(tmp_path):
    from kddrl_trl.reporting.records import find_runs, load_run

    run = fake_run(tmp_path / "a")
    assert load_run(run).metrics()["collision_rate"] == 0.5
    frame = pd.read_csv(run / "eval_episodes.csv")
    frame.drop(columns=["lane_changes"]).to_csv(run / "eval_episodes.csv", index=False)
    with pytest.raises(ValueError, match=r"eval_episodes.csv: missing column\(s\) lane_changes"):
        load_run(run)
    frame.assign(mean_speed_kmh=["fast"] * len(frame)).to_csv(run / "eval_episodes.csv", index=False)
    with pytest.raises(ValueError, match="mean_speed_kmh"):
        load_run(run)
    with pytest.raises(FileNotFoundError, match="no such run"):
        find_runs([tmp_path / "missing"])
    fake_run(tmp_path / "b")
    fake_run(tmp_path / "c")
    with pytest.raises(ValueError, match="two runs of kddrl on baseline with seed 0"):
        find_runs([tmp_path / "b", tmp_path / "c"])


def test_a_record_cut_short_is_refused_in_one_line_leaving_no_report_folder(tmp_path):
    """An ``eval_episodes.csv`` cut at a row boundary parses; its row count against ``summary.json`` 's gives it
    away. The report command ends with one line naming the file, and makes no report folder."""
    import os
    import sys

    run = fake_run(tmp_path / "runs" / "a", speeds=(100.0, 110.0, 120.0), collisions=(False, True, False))
    lines = (run / "eval_episodes.csv").read_text().splitlines(keepends=True)
    (run / "eval_episodes.csv").write_text("".join(lines[:-1]))
    env = {k: v for k, v in os.environ.items() if k != "HYDRA_FULL_ERROR"}
    cmd = [sys.executable, "-m", "kddrl_trl.report", "runs/a", "out=out"]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    message = f"error: {Path('runs/a/eval_episodes.csv')}: 2 episode rows, but {Path('runs/a/summary.json')} counts 3"
    assert done.returncode != 0 and done.stderr.strip().startswith(message), done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and not (tmp_path / "out").exists()


def test_a_report_of_one_system_has_no_empty_comparison_and_one_shape(tmp_path):
    from kddrl_trl.reporting.builder import build_report

    build_report(find_runs([fake_run(tmp_path / "runs" / "a")]), tmp_path / "out", title="A study: report")
    md = (tmp_path / "out" / "report.md").read_text()
    assert "Comparison with KDDRL" not in md and md.startswith("# A study: report\n")
    report = json.loads((tmp_path / "out" / "report.json").read_text())  # one shape, with or without the verdict
    assert set(report) == {"rows", "claims", "commits", "plan_commit"} and report["claims"] == []
    build_report(find_runs([fake_run(tmp_path / "runs" / "b", algo="ni"), tmp_path / "runs" / "a"]), tmp_path / "o2")
    assert "## Comparison with KDDRL" in (tmp_path / "o2" / "report.md").read_text()


@pytest.mark.parametrize("suffix", [".xz", ".gz"])
def test_compressed_records_read_as_plain_ones(tmp_path, suffix):
    """A study committed with compressed CSVs (eval_episodes.csv.xz, ...) reads exactly as its plain form."""
    import gzip
    import lzma
    import shutil

    from kddrl_trl.reporting.records import load_run

    plain = fake_run(tmp_path / "plain", speeds=(100.0, 120.0, 90.0), collisions=(False, True, False))
    pd.DataFrame({"return_lc": [1.0, 2.0], "return_cf": [3.0, 4.0]}).to_csv(plain / "train_episodes.csv", index=False)
    packed = tmp_path / "packed"
    shutil.copytree(plain, packed)
    for csv in packed.glob("*.csv"):
        with open(csv, "rb") as src, {".xz": lzma.open, ".gz": gzip.open}[suffix](f"{csv}{suffix}", "wb") as dst:
            shutil.copyfileobj(src, dst)
        csv.unlink()
    a, b = load_run(plain), load_run(packed)
    assert (packed / f"eval_episodes.csv{suffix}").is_file() and not (packed / "eval_episodes.csv").exists()
    pd.testing.assert_frame_equal(a.episodes, b.episodes)
    pd.testing.assert_frame_equal(a.training, b.training)
    assert a.metrics() == b.metrics() and b.metrics()["collision_rate"] == pytest.approx(1 / 3)
    from kddrl_trl.reporting.records import record_bytes

    assert record_bytes(packed, "train_episodes.csv") == record_bytes(plain, "train_episodes.csv")
    assert record_bytes(packed, "train_episodes.csv") != record_bytes(packed, "eval_episodes.csv")


def test_report_of_hand_made_runs_holds_their_numbers(tmp_path):
    from kddrl_trl.reporting.builder import build_report
    from kddrl_trl.reporting.records import find_runs

    for seed, speed in enumerate((115.0, 120.0, 125.0)):
        fake_run(tmp_path / "runs" / f"k{seed}", "kddrl", seed, speeds=(speed, speed + 10), collisions=(False, False))
        fake_run(tmp_path / "runs" / f"i{seed}", "idm_mobil", seed, speeds=(90.0, 90.0), collisions=(False, False))
    out = build_report(find_runs([tmp_path / "runs"]), tmp_path / "rep")
    rows = {r["algo"]: r for r in json.loads((tmp_path / "rep" / "report.json").read_text())["rows"]}
    speed = rows["kddrl"]["metrics"]["mean_speed_kmh"]
    assert speed["mean"] == pytest.approx(125.0) and speed["ci_low"] < 125.0 < speed["ci_high"]
    assert rows["kddrl"]["seeds"] == [0, 1, 2] and rows["kddrl"]["episodes"] == 6
    assert rows["idm_mobil"]["metrics"]["collision_rate"] == {"mean": 0.0, "ci_low": 0.0, "ci_high": 0.0}
    assert rows["kddrl"]["paper"]["mean_speed_kmh"] == [159.4, 22.5]
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "idm_mobil is lower" in md and "125.0 [" in md and "paper: 159.4 ± 22.5" in md
    # against the rule baseline: 125 / 90 km/h, no collisions on either side; no shield column without a shield
    assert "| kddrl | 3 | 1.389 | [" in md and "| 0.0% | +0.0 | [+0.0, +0.0] |" in md
    assert "shield interventions" not in md
    two = build_report(
        find_runs(
            [tmp_path / "runs" / "k0", tmp_path / "runs" / "k1", tmp_path / "runs" / "i0", tmp_path / "runs" / "i1"]
        ),
        tmp_path / "rep2",
    )
    assert two["rows"] and "too few seeds for a reading (2 vs 2" in (tmp_path / "rep2" / "report.md").read_text()
    assert out["figures"]["Figs. 9 / 15: evaluation returns"]


def test_shield_interventions_and_collisions_are_read_against_the_rules(tmp_path):
    """Issue 14: a shielded row shows how often its shield acted (fraction of frames), and every row's speed ratio
    and collision difference to IDM+MOBIL come with their intervals."""
    from kddrl_trl.reporting.builder import build_report
    from kddrl_trl.reporting.records import find_runs

    for seed in range(3):
        run = fake_run(
            tmp_path / "runs" / f"k{seed}", "kddrl", seed, speeds=(110.0, 110.0 + seed), collisions=(seed == 0, False)
        )
        frame = pd.read_csv(run / "eval_episodes.csv")
        frame.assign(shield_interventions=[50, 25]).to_csv(run / "eval_episodes.csv", index=False)
        fake_run(tmp_path / "runs" / f"i{seed}", "idm_mobil", seed, speeds=(100.0, 100.0), collisions=(False, False))
    build_report(find_runs([tmp_path / "runs"]), tmp_path / "rep")
    md = (tmp_path / "rep" / "report.md").read_text()
    table = next(line for line in md.splitlines() if line.startswith("| **kddrl**"))
    assert table.endswith("| 37.50% [37.50%, 37.50%] |")  # 75 of 200 frames in every seed
    against = next(line for line in md.splitlines() if line.startswith("| kddrl | 3 |"))
    # speed 110.5 / 100 (seeds 110, 110.5, 111); collisions 50 %, 0, 0: +16.7 points
    assert against.startswith(
        "| kddrl | 3 | 1.105 | [1.093, 1.117] | 16.7% | +16.7 | [-55.0, +88.4] | 37.50% |"
    )  # by hand: Welch, t(2)


def test_policies_trained_on_another_scenario_are_their_own_rows(tmp_path):
    """A run trained on ``mixed`` (its ``final__*`` evaluations) and a ``kddrl_trl.evaluate`` folder named on the
    command line are reported as "<algo> (trained on <scenario>)", beside, not inside, the runs trained there."""
    from kddrl_trl.reporting.builder import build_report
    from kddrl_trl.reporting.records import find_runs

    for seed in range(3):
        fake_run(tmp_path / "runs" / f"b{seed}", seed=seed, scenario="braking", speeds=(100.0, 100.0))
        mixed = tmp_path / "runs" / f"m{seed}"
        mixed.mkdir(parents=True)
        (mixed / "summary.json").write_text(
            json.dumps(
                {
                    "algo": "kddrl",
                    "scenario": "mixed",
                    "seed": seed,
                    "final_evaluations": ["final__baseline", "final__braking"],
                    "wall_s": 4000.0,
                    "training": {"elapsed_s": 3600.0},
                }
            )
        )
        for scenario in ("baseline", "braking"):
            fake_run(
                mixed / f"final__{scenario}",
                seed=seed,
                scenario=scenario,
                speeds=(130.0, 130.0),
                collisions=(False, False),
                trained_on="mixed",
                final=True,
            )
    evaluated = fake_run(tmp_path / "runs" / "b0" / "eval__baseline__0__t", scenario="baseline", trained_on="braking")
    runs = find_runs([tmp_path / "runs"])  # evaluate's eval__ folders are left out of a sweep's search
    assert sorted((r.scenario, r.algo) for r in runs) == sorted(
        [("braking", "kddrl")] * 3
        + [("braking", "kddrl (trained on mixed)")] * 3
        + [("baseline", "kddrl (trained on mixed)")] * 3
    )
    build_report(runs, tmp_path / "rep")
    rows = {(r["scenario"], r["algo"]): r for r in json.loads((tmp_path / "rep" / "report.json").read_text())["rows"]}
    assert rows[("braking", "kddrl")]["metrics"]["collision_rate"]["mean"] == 0.5
    assert rows[("braking", "kddrl (trained on mixed)")]["metrics"]["collision_rate"]["mean"] == 0.0
    assert rows[("braking", "kddrl (trained on mixed)")]["trained_on"] == "mixed"
    assert rows[("braking", "kddrl (trained on mixed)")]["paper"] == {}  # the paper published nothing for it
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "kddrl (trained on mixed) is higher" in md  # vs kddrl
    # the runs table names a final evaluation with its run's folder, and a wall time it lacks as missing, not nan
    runs_table = md.split("## Runs")[1].split("\n---\n")[0]
    assert "| `m1/final__braking` |" in runs_table and "nan" not in runs_table
    # the footer's wall time counts each mixed run once, from its own summary.json (its final evaluations have none)
    assert "training 3.00 h over all runs" in md and "3.33 h (`wall_s`); 3 runs did not record it" in md
    named = find_runs([evaluated])
    assert [(r.scenario, r.algo) for r in named] == [("baseline", "kddrl (trained on braking)")]


def test_provenance_names_the_commit_and_a_changed_tree(tmp_path):
    from kddrl_trl.provenance import commit, cpu_model, provenance

    assert commit(tmp_path) == "unknown"  # not a checkout
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path)]
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "a.py").write_text("x = 1\n")
    for args in (["init", "-q"], ["add", "."], ["commit", "-qm", "a"]):
        subprocess.run(git + args, check=True)
    head = subprocess.run(git + ["rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    assert commit(tmp_path) == head
    (tmp_path / "src" / "a.py").write_text("x = 2\n")
    assert commit(tmp_path) == head + "+dirty"
    p = provenance()
    assert set(p) == {"commit", "machine", "packages"} and "CPUs" in p["machine"]
    assert cpu_model() in p["machine"] and cpu_model()  # the CPU model: other models give other float arithmetic


def test_the_cpu_is_named_down_to_its_generation():
    """One model name covers CPU generations whose float arithmetic differs: a run records family, model and
    stepping and whether the CPU has AVX-512, from the first processor's entry, with no comma."""
    from kddrl_trl.provenance import cpu_model

    entry = (
        "processor\t: {n}\ncpu family\t: {f}\nmodel\t\t: {m}\nmodel name\t: AMD EPYC\nstepping\t: 1\nflags\t\t: {x}\n\n"
    )
    zen4 = entry.format(n=0, f=25, m=17, x="fpu sse2 avx2 avx512f avx512bw") + entry.format(n=1, f=23, m=1, x="avx2")
    assert cpu_model(zen4) == "AMD EPYC [cpu family 25 model 17 stepping 1; AVX-512]"
    assert cpu_model(entry.format(n=0, f=23, m=1, x="fpu avx2 avx512_bf16x")) == (
        "AMD EPYC [cpu family 23 model 1 stepping 1; no AVX-512]"
    )
    assert "," not in cpu_model(zen4) and cpu_model("") != ""


def test_a_run_records_the_commit_its_code_was_loaded_from(monkeypatch):
    from kddrl_trl import provenance as prov

    monkeypatch.setattr(prov, "_LOADED", {})
    checked_out = iter(["aaaaaaa", "bbbbbbb"])  # a commit lands in the checkout while the run trains
    monkeypatch.setattr(prov, "commit", lambda where=None: next(checked_out))
    assert prov.code_commit() == "aaaaaaa"  # the entry point's call as it starts
    assert prov.provenance()["commit"] == "aaaaaaa" and prov.code_commit() == "aaaaaaa"


def test_the_code_commit_is_the_packages_checkout_not_the_working_directorys(tmp_path, monkeypatch):
    """A job run from one checkout with another's ``src`` first on ``PYTHONPATH`` records the commit of the code it
    loaded."""
    from pathlib import Path

    from kddrl_trl import provenance as prov

    other = tmp_path / "other"
    other.mkdir()
    git = ["git", "-C", str(other), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "commit", "-q", "--allow-empty", "-m", "another checkout"], check=True)
    monkeypatch.chdir(other)
    monkeypatch.setattr(prov, "_LOADED", {})
    package_checkout = prov.commit(Path(prov.__file__).parent)
    assert prov.code_commit() == package_checkout != prov.commit(other)


# ------------------------------------------------------------------------------ the sweep, as typed
@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweep")
    cmd = [
        "kddrl_trl.train",
        "-m",
        "algo=idm_mobil,kddrl",
        "+scenario=braking",
        "seed=0,1",
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
        f"hydra.sweep.dir={root / 'sweep'}",
        "video=true",
        "video_episodes=1",
        *TINY,
    ]
    run_module(cmd, root)
    return root, cmd


def test_sweep_runs_every_job_and_resumes_job_by_job(sweep):
    root, cmd = sweep
    jobs = sorted(p.name for p in (root / "sweep").iterdir() if p.is_dir())
    assert jobs == ["braking__idm_mobil__0", "braking__idm_mobil__1", "braking__kddrl__0", "braking__kddrl__1"]
    for job in jobs:
        summary = json.loads((root / "sweep" / job / "summary.json").read_text())
        seed = summary["seed"]
        assert summary["protocol"] == {
            "train_seeds": [seed, seed + 3],
            "validation_seed": seed + VALIDATION_OFFSET,
            "eval_seed": seed + TEST_OFFSET,
            "eval_episodes": 4,
        }
        records = pd.read_csv(root / "sweep" / job / "eval_episodes.csv", keep_default_na=False)
        assert len(records) == 4 and {"outcome", "collision_kind", "collision_with", "ended_changing_lane"} <= set(
            records
        )
        assert {"commit", "machine", "packages"} <= set(summary) and summary["packages"]["torchrl"].startswith("0.14")
        assert list((root / "sweep" / job / "videos").glob("*.mp4")) and list(
            (root / "sweep" / job / "traces").glob("*.json")
        )
    kddrl = root / "sweep" / "braking__kddrl__0"
    validation = pd.read_csv(kddrl / "validation.csv")
    assert list(validation["episodes_trained"]) == [2, 4] and (validation["episodes"] == 2).all()
    assert (kddrl / "checkpoints" / "best.pt").is_file() and (
        kddrl / "logs" / "scalars" / "eval" / "score.csv"
    ).is_file()

    # the sweep again with resume=true after one job's folder was lost: the finished jobs are skipped, the lost one
    # is computed again, and the same config and seed give identical records (determinism on one machine)
    lost = root / "sweep" / "braking__kddrl__1"
    first = {
        name: pd.read_csv(lost / name, keep_default_na=False) for name in ("eval_episodes.csv", "train_episodes.csv")
    }
    shutil.rmtree(lost)
    before = (kddrl / "eval_episodes.csv").stat().st_mtime_ns
    done = run_module(cmd + ["resume=true"], root)
    assert (done.stdout + done.stderr).count("is finished (summary.json): skipped") == 3
    assert (kddrl / "eval_episodes.csv").stat().st_mtime_ns == before
    for name, frame in first.items():
        pd.testing.assert_frame_equal(pd.read_csv(lost / name, keep_default_na=False), frame)


def test_report_of_the_sweep_as_typed(sweep, tmp_path):
    root, _ = sweep
    run_module(["kddrl_trl.report", str(root / "sweep"), f"out={tmp_path / 'rep'}"], tmp_path)
    rows = json.loads((tmp_path / "rep" / "report.json").read_text())["rows"]
    assert sorted((r["algo"], r["scenario"]) for r in rows) == [("idm_mobil", "braking"), ("kddrl", "braking")]
    for row in rows:
        runs = [
            json.loads((root / "sweep" / f"braking__{row['algo']}__{s}" / "summary.json").read_text()) for s in (0, 1)
        ]
        assert row["seeds"] == [0, 1] and row["episodes"] == 8
        for name, key in (
            ("mean_speed_kmh", "mean_speed_kmh"),
            ("mean_accel", "mean_accel"),
            ("collision_rate", "collision_rate"),
            ("lane_changes_per_episode", "lane_changes"),
        ):
            m = row["metrics"][name]
            assert m["mean"] == pytest.approx(np.mean([r[key] for r in runs]))
            assert m["ci_low"] <= m["mean"] + 1e-12 and m["mean"] <= m["ci_high"] + 1e-12
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## Tables II-V" in md and "## Comparison with KDDRL" in md and "## Collisions by kind" in md
    assert "Report made at commit" in md and "Evaluation protocol" in md
    assert "Runs made at commits:" in md and "not recorded" not in md.split("Runs made at commits:")[1].split("\n")[0]
    for fig in (
        "fig08_training_curves.png",
        "fig09_returns.png",
        "fig13_distributions_braking.png",
        "fig14_space_time_braking.png",
    ):
        assert (tmp_path / "rep" / fig).read_bytes()[:4] == b"\x89PNG", fig
    # the same runs with Fig. 14 left to that report: said why, and no PNG written
    run_module(
        ["kddrl_trl.report", str(root / "sweep"), f"out={tmp_path / 'no14'}", "space_time_figures=false"], tmp_path
    )
    md = (tmp_path / "no14" / "report.md").read_text()
    assert "space_time_figures=false" in md.split("### Fig. 14: braking, space-time diagrams")[1].split("\n###")[0]
    assert not (tmp_path / "no14" / "fig14_space_time_braking.png").exists()
    assert "* **Command:** `python -m kddrl_trl.report" in md and "space_time_figures=false`" in md


# ------------------------------------------------------------------------------------ traces, video
def test_traces_follow_the_tracked_episodes_and_make_videos(tmp_path):
    from kddrl_trl.baselines import IDMMobilPolicy
    from kddrl_trl.envs.fake import FakeHighwayEnv
    from kddrl_trl.eval import evaluate_policy
    from kddrl_trl.eval.render import plot_space_time, write_video
    from kddrl_trl.eval.trace import TraceRecorder

    env = FakeHighwayEnv(num_roads=3, seed=0)
    recorder = TraceRecorder(2, scenario="baseline", algo="idm_mobil", lane_width=3.2, num_lanes=3)
    episodes = evaluate_policy(env, IDMMobilPolicy(), 6, seed=4, progress=False, trace=recorder)
    by_key = {(e["road"], e["frames"], e["lane_changes"]) for e in episodes}
    assert recorder.traces
    for trace in recorder.traces:
        frames = trace["frames"]
        assert [f["t"] for f in frames] == list(range(len(frames)))
        assert trace["lane_changes"] == sum(f["lc_started"] for f in frames)
        assert all(0.0 <= f["x"] <= 3 * 3.2 for f in frames)
        # a trace is one whole episode the tracker counted (first frame = the reset observation)
        assert (trace["row"], len(frames) - 1, trace["lane_changes"]) in by_key
    video = write_video(recorder.traces[0], tmp_path / "v" / "ep.mp4")
    assert video.read_bytes()[4:8] == b"ftyp" and not list((tmp_path / "v").glob(".*tmp*"))
    png = plot_space_time([("ep", t) for t in recorder.chosen()], tmp_path / "st.png")
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_gym_env_renders_rgb_frames():
    import gymnasium as gym

    import kddrl_trl  # noqa: F401  (registers the env)

    env = gym.make("kddrl_trl/SumoHighway-v0", render_mode="rgb_array")
    try:
        env.reset(seed=0)
        first = env.render()
        for _ in range(5):
            env.step({"lc": 1, "cf": np.array([1.0], np.float32)})
        frame = env.render()
    finally:
        env.close()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3 and frame.shape == first.shape
    assert frame.std() > 0  # something is drawn


def test_runs_with_options_are_rows_of_their_own(tmp_path):
    """Issue 14's ablation: a run whose ``config.yaml`` sets an option otherwise than its algo's defaults (e.g.
    ``train.n_steps=3``) is the row ``"kddrl [train.n_steps=3]"``, beside the runs at the defaults; a config
    without the option keys (saved before they existed) is the algo's own row."""
    import yaml
    from omegaconf import OmegaConf

    from kddrl_trl.reporting.records import default_config, find_runs

    defaults = default_config("kddrl", "braking")
    options = OmegaConf.to_container(
        OmegaConf.merge(
            defaults,
            {
                "train": {"n_steps": 3},
                "algo": {"shield": "idm", "state_extras": ["thw", "ttc"]},
                "collector": {"sync": False},
            },
        )
    )
    for seed in range(2):
        for name, cfg in (("paper", defaults), ("options", options), ("old", {"seed": seed, "episodes": 1000})):
            run = fake_run(tmp_path / "runs" / f"{name}{seed}", seed=seed, scenario="braking")
            (run / "config.yaml").write_text(yaml.safe_dump(cfg))
    runs = find_runs([tmp_path / "runs" / "paper0", tmp_path / "runs" / "options0", tmp_path / "runs" / "old1"])
    assert sorted(r.algo for r in runs) == sorted(
        [
            "kddrl",
            "kddrl",
            "kddrl [algo.shield=idm, algo.state_extras=[thw,ttc], train.n_steps=3, collector.sync=False]",
        ]
    )


def test_figures_keep_one_colour_per_system_and_few_series_per_axes():
    from kddrl_trl.reporting.figures import MAX_SERIES, series_panels, style, system_of

    labels = ["kddrl"] + [f"kddrl [opt{i}]" for i in range(13)] + ["d3qn_td3 [algo.shield=idm]", "idm_mobil", "ni"]
    panels = series_panels(labels)
    assert all(len(p) <= MAX_SERIES for p in panels)
    assert {lab for p in panels for lab in p} == set(labels)  # every series drawn...
    assert all("kddrl" in p for p in panels if any(system_of(lab) == "kddrl" for lab in p))  # ...beside its reference
    assert style("kddrl", labels)["color"] == style("kddrl", ["kddrl", "ni"])["color"]  # the same in every figure
    assert style("kddrl", labels)["color"] != style("ni", labels)["color"]
    assert system_of("kddrl [algo.shield=idm] @abc1234") == "kddrl" and system_of("ni (trained on mixed)") == "ni"
    assert series_panels(["peng", "kddrl", "ni"]) == [["kddrl", "ni", "peng"]]  # the paper's order


def test_an_evaluation_in_other_traffic_than_its_training_is_labelled_by_what_differs():
    from kddrl_trl.reporting.records import evaluation_label

    programmed = {"env": {"braking": {"release": "programmed", "resume_accel": 2.0, "stand_time": 3.0}}}
    assert evaluation_label(programmed, {"env": {"braking": {"stand_time": 3.0}}}) == "env.braking.release=programmed"
    assert evaluation_label(programmed, {"env": {"braking": {"release": "programmed"}}}) == ""  # as it was trained
    assert evaluation_label({"env": {"braking": {"stand_time": 5.0}}}, None) == "env.braking.stand_time=5.0"
    assert evaluation_label(None, programmed) == ""


def test_the_lcgan_figures_are_drawn_from_its_metrics_and_left_out_when_not_asked_for(tmp_path):
    """Figs. 16 / 17 show the lcGAN's test metrics, not the runs: drawn from the shipped metrics by default, each
    figure's absence said with its reason (none shipped, or ``lcgan_figures=false``)."""
    from kddrl_trl.report import SHIPPED_LCGAN_METRICS, read_lcgan_metrics
    from kddrl_trl.reporting.builder import build_report

    runs = find_runs([fake_run(tmp_path / "runs" / "a")])
    metrics = read_lcgan_metrics(SHIPPED_LCGAN_METRICS)
    drawn = build_report(runs, tmp_path / "with", lcgan_metrics=metrics)["figures"]
    assert drawn["Fig. 16: lcGAN class shares"] and (tmp_path / "with" / "fig16_lcgan_shares.png").is_file()
    title = "Figs. 16 / 17: lcGAN class shares and confusion"
    for metrics, out, reason in ((None, "none", "carry no test metrics"), (False, "off", "`lcgan_figures=false`")):
        assert build_report(runs, tmp_path / out, lcgan_metrics=metrics)["figures"][title] is None
        md = (tmp_path / out / "report.md").read_text()
        assert f"### {title}\n\nNot drawn: " in md and reason in md.split(title)[1].split("\n###")[0]
        assert not (tmp_path / out / "fig16_lcgan_shares.png").exists()


def _timed_run(seed: int, elapsed: float, wall: float, batch: list[int] | None = None):
    from kddrl_trl.reporting.records import RunRecord

    summary = {"algo": "kddrl", "training": {"elapsed_s": elapsed}, "wall_s": wall}
    if batch is not None:
        summary["seed_batch"] = {"index": batch.index(seed), "seeds": batch}
    return RunRecord(Path(f"run{seed}"), "kddrl", "baseline", seed, summary, pd.DataFrame())


def test_a_seed_batch_s_shared_clock_is_counted_once_in_the_report_s_times():
    """The seeds of a batch each record the batch's wall time: the report's times give each its share
    (``RunRecord.seed_share``), so a batch of three counts once, beside a run alone counted whole."""
    from kddrl_trl.reporting.sections import _run_times

    batch = [_timed_run(s, 300.0, 360.0, [0, 1, 2]) for s in (0, 1, 2)]
    alone = _timed_run(7, 120.0, 150.0)
    assert [r.seed_share for r in batch] == pytest.approx([1 / 3] * 3) and alone.seed_share == 1.0
    times = _run_times([*batch, alone])
    assert sum(t for t, _ in times) == pytest.approx(300.0 + 120.0)
    assert sum(w for _, w in times) == pytest.approx(360.0 + 150.0)
