"""The Hydra entry point: config composition, and the command a user types, as a subprocess."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf
from testkit import SMALL_NETS, TINY, TINY_BUDGET, compose_job, fake_trainer, kill_when


def test_scenario_is_appended_not_required():
    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        base = compose(config_name="config")
        braking = compose(config_name="config", overrides=["+scenario=braking"])
        congested = compose(config_name="config", overrides=["+scenario=congested", "env.flow_vph=2658"])
    assert base.env.scenario == "baseline" and not base.env.braking.enabled and base.env.flow_scale == 1.0
    assert braking.env.scenario == "braking" and braking.env.braking.enabled
    assert congested.env.flow_scale == 1.5 and congested.env.flow_vph == 2658


def test_rule_based_algo_runs_as_typed_from_any_directory(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "kddrl_trl.train",
        "+scenario=braking",
        "algo=idm_mobil",
        "eval_episodes=4",
        "env.num_roads=2",
        "progress=false",
    ]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    runs = list((tmp_path / "runs").glob("braking__idm_mobil__0__*"))
    assert len(runs) == 1
    summary = json.loads((runs[0] / "summary.json").read_text())
    assert summary["episodes"] == 4 and summary["scenario"] == "braking"
    assert summary["compile"] in (True, False)  # compile=auto, resolved on this machine
    assert (runs[0] / "eval_episodes.csv").read_text().count("\n") == 5
    # wall_s is the run's whole time, its evaluation included: at least from config.yaml (written after the
    # start) to eval_episodes.csv (written after the evaluation)
    span = (runs[0] / "eval_episodes.csv").stat().st_mtime - (runs[0] / "config.yaml").stat().st_mtime
    assert summary["wall_s"] >= span - 0.01 and span > 0.1
    assert "mean speed (km/h)" in done.stdout


def test_kddrl_trains_end_to_end_as_typed(tmp_path):
    cmd = [sys.executable, "-m", "kddrl_trl.train", "+scenario=braking", "episodes=3", "eval_episodes=2", *TINY]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    (run,) = list((tmp_path / "runs").glob("braking__kddrl__0__*"))
    summary = json.loads((run / "summary.json").read_text())
    assert summary["algo"] == "kddrl" and summary["episodes"] == 2 and summary["compile"] is False
    assert summary["compile_s"] == 0.0  # compile=false: nothing compiled in the job's process
    assert summary["compile_counts"]["graphs"] == 0
    training = summary["training"]
    assert training["episodes"] == 3 and training["cf_updates"] > 0 and training["frames"] > 50
    assert (run / "train_episodes.csv").read_text().count("\n") == 4
    assert (run / "training_curves.png").read_bytes()[:4] == b"\x89PNG"
    assert (run / "checkpoints" / "latest").read_text().strip() == "ep000003.pt"
    assert "wiring check, not a result" in done.stdout and f"python -m kddrl_trl.evaluate run={run}" in done.stdout
    assert f"training curves: {run / 'training_curves.png'}" in done.stdout  # the run says what it made
    for name in ("train/return_lc", "train/return_cf", "train/loss_qvalue", "time/frames_per_s", "test/mean_speed_kmh"):
        assert (run / "logs" / "scalars" / f"{name}.csv").is_file(), name

    # the trained policy, evaluated on another scenario from its checkpoint (paper §IV.D)
    cmd = [
        sys.executable,
        "-m",
        "kddrl_trl.evaluate",
        f"run={run}",
        "+scenario=congested",
        "eval_episodes=2",
        "env.num_roads=2",
        "progress=false",
        "video=true",
        "video_episodes=1",
    ]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    (ev,) = list(run.glob("eval__congested__0__*"))
    (video,) = list((ev / "videos").glob("*.mp4"))
    assert f"video: {video}" in done.stdout and "trace: " in done.stdout  # it names what it made
    summary = json.loads((ev / "summary.json").read_text())
    assert summary["episodes"] == 2 and summary["trained_on"] == "braking" and summary["scenario"] == "congested"
    assert summary["compile"] is False and summary["compile_s"] == 0.0  # compile=auto: 2 episodes do not pay for it
    assert summary["checkpoint"].endswith("ep000003.pt")
    # evaluate shield=<kind>: the trained policy under another shield (the run's own otherwise)
    from kddrl_trl.factories import make_trained_learner, make_transforms
    from kddrl_trl.transforms import SafetyShield

    assert make_trained_learner(run)[0].shield == "none"
    algo = make_trained_learner(run, shield="rss")[0]
    shields = [
        t for t in make_transforms(algo, 0, compose_job().env.highway()).transforms if isinstance(t, SafetyShield)
    ]
    assert algo.shield == "rss" and [s.kind for s in shields] == ["rss"]
    # a shipped policy (kddrl_trl.policies): the run's networks, no optimiser or buffer, read as a run folder
    import torch

    from kddrl_trl.devtools.ship_policy import ship
    from kddrl_trl.policies import output_folder, shipped_policy

    shipped = ship(run, "tiny", why="a test", dest=tmp_path / "policies")
    assert sorted(p.name for p in shipped.iterdir()) == ["card.json", "config.yaml", "policy.pt"]
    assert shipped.joinpath("policy.pt").stat().st_size < (run / "checkpoints" / "ep000003.pt").stat().st_size / 4
    mine, theirs = make_trained_learner(shipped)[1].state_dict(), make_trained_learner(run)[1].state_dict()
    assert mine.keys() == theirs.keys() and all(torch.equal(mine[k], theirs[k]) for k in mine)
    assert json.loads((shipped / "card.json").read_text())["checkpoint"] == "ep000003.pt"
    assert output_folder("shipped:tiny") == "runs/shipped__tiny" and output_folder(run) == str(run)
    with pytest.raises(FileNotFoundError, match="run=shipped:nope: no such shipped policy"):
        shipped_policy("shipped:nope")


@pytest.mark.slow
@pytest.mark.parametrize(
    "algo, small",
    [
        ("peng", "algo.learner.ddpg.hidden=[32,32]"),
        ("d3qn_unified", "algo.learner.d3qn.hidden=[32,32]"),
        ("pasac_unified", "algo.learner.pasac.hidden=[32,32]"),
    ],
)
def test_the_new_systems_train_and_evaluate_on_sumo_as_typed(algo, small, tmp_path):
    """``python -m kddrl_trl.train algo=<new system> +scenario=braking``, a few episodes with updates: every frame
    is a decision (lc_period 1), the summary and the evaluation records are the same as for every algo."""
    cmd = [
        sys.executable,
        "-m",
        "kddrl_trl.train",
        f"algo={algo}",
        "+scenario=braking",
        "episodes=3",
        "eval_episodes=2",
        "train.eval_every=0",
        *TINY_BUDGET,
        small,
    ]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    (run,) = list((tmp_path / "runs").glob(f"braking__{algo}__0__*"))
    summary = json.loads((run / "summary.json").read_text())
    training = summary["training"]
    assert summary["algo"] == algo and summary["episodes"] == 2 and training["episodes"] == 3
    assert training["decisions"] == training["frames"] > 50 and training["cf_updates"] > 0
    assert (training["lc_updates"] > 0) == (algo == "peng")
    assert (run / "eval_episodes.csv").read_text().count("\n") == 3
    assert (run / "checkpoints" / "latest").read_text().strip() == "ep000003.pt"
    assert "wiring check, not a result" in done.stdout and f"python -m kddrl_trl.evaluate run={run}" in done.stdout
    assert f"training curves: {run / 'training_curves.png'}" in done.stdout  # the run says what it made


@pytest.mark.parametrize(
    "args, message",
    [
        (["run=runs/nope"], "error: run=runs/nope: no config.yaml there"),
        (["run=elsewhere/deep/nope"], "error: run=elsewhere/deep/nope: no config.yaml there"),
        (["run=runs/r", "eval_episodes=-3"], "error: eval_episodes must be >= 1, got -3"),
        (["run=runs/r", "+eval_episods=3"], "error: unknown config key(s) eval_episods"),
        (["run=runs/r", "shield=wall"], "error: shield='wall': known shields are none, idm, ttc, rss"),
        (["run=runs/r"], "error: no checkpoint in runs/r/checkpoints"),  # fails after Hydra made the eval folder
    ],
)
def test_a_refused_or_failed_evaluation_is_one_line_and_leaves_nothing_behind(tmp_path, args, message):
    """A missing run, a bad value, a ``+`` typo or a run without checkpoints: one line naming it, no traceback, and
    no folder left (neither the ``eval__*`` folder nor the folders Hydra made for a run that does not exist)."""
    (tmp_path / "runs" / "r").mkdir(parents=True)
    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        config = compose(config_name="config", overrides=["algo=kddrl"])
    (tmp_path / "runs" / "r" / "config.yaml").write_text(OmegaConf.to_yaml(config))
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    env = {k: v for k, v in os.environ.items() if k != "HYDRA_FULL_ERROR"}
    cmd = [sys.executable, "-m", "kddrl_trl.evaluate", *args, "progress=false", "compile=false"]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode != 0 and done.stderr.strip().startswith(message), done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def _latest_episodes(run) -> int:
    pointer = run / "checkpoints" / "latest"
    return int(pointer.read_text().strip()[2:8]) if pointer.is_file() else 0


@pytest.mark.slow
def test_killed_run_resumes_from_its_last_checkpoint(tmp_path):
    args = ["episodes=8", "eval_episodes=1", "train.checkpoint_every=2", *TINY]

    def checkpointed():
        runs = list((tmp_path / "runs").glob("baseline__kddrl__0__*"))
        return runs[0] if runs and 2 <= _latest_episodes(runs[0]) < 8 else None

    run, stderr = kill_when(["kddrl_trl.train", *args], tmp_path, checkpointed, timeout=400)
    assert run is not None, "no checkpoint appeared before the run ended: " + stderr
    killed_at = _latest_episodes(run)
    assert not (run / "summary.json").exists()

    done = subprocess.run(
        [sys.executable, "-m", "kddrl_trl.train", *args, "resume=true"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads((run / "summary.json").read_text())  # written into the resumed run's directory
    assert list((tmp_path / "runs").iterdir()) == [run]  # the resumed invocation made no folder of its own
    assert summary["training"]["episodes"] == 8 and summary["run_dir"] == str(run)
    history = (run / "train_episodes.csv").read_text().strip().splitlines()
    assert len(history) == 1 + 8
    steps = [int(float(line.split(",")[0])) for line in (run / "logs/scalars/train/return_cf.csv").read_text().split()]
    assert steps == list(range(8)), steps  # no episode logged twice, none missing
    assert _latest_episodes(run) == 8 and killed_at >= 2


@pytest.mark.parametrize("override", ["env.flow_vph=-5", "env.flow_vph=lots", "env.flow_vhp=5"])
def test_train_rejects_a_bad_override(tmp_path, override):
    cmd = [sys.executable, "-m", "kddrl_trl.train", override, "episodes=1", "progress=false"]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and ("flow_vph" in done.stderr or "flow_vhp" in done.stderr), done.stderr


def test_summary_statistics_by_hand():
    from kddrl_trl.eval.metrics import summarize

    eps = [
        {
            "mean_speed_kmh": 36.0,
            "mean_speed": 10.0,
            "mean_sq_speed": 100.0,
            "mean_accel": 0.0,
            "mean_sq_accel": 1.0,
            "mean_abs_accel": 1.0,
            "lane_changes": 1,
            "frames": 10,
            "return_lc": 1.0,
            "return_cf": 2.0,
            "collision": False,
            "outcome": "left_section",
        },
        {
            "mean_speed_kmh": 72.0,
            "mean_speed": 20.0,
            "mean_sq_speed": 400.0,
            "mean_accel": 0.0,
            "mean_sq_accel": 1.0,
            "mean_abs_accel": 1.0,
            "lane_changes": 0,
            "frames": 30,
            "return_lc": 1.0,
            "return_cf": 2.0,
            "collision": True,
            "outcome": "collision",
        },
    ]
    s = summarize(eps)
    assert s["mean_speed_kmh"] == 54.0 and s["mean_speed_kmh_sd"] == 18.0
    # frames: 10 at 10 m/s and 30 at 20 m/s -> mean 17.5, sd sqrt(325 - 306.25) = 4.33 m/s
    assert abs(s["frame_speed_kmh_sd"] - 3.6 * 18.75**0.5) < 1e-9
    assert s["frame_accel_sd"] == 1.0 and s["collision_rate"] == 0.5 and s["lane_changes_total"] == 1
    assert s["outcomes"] == {"left_section": 1, "collision": 1}


KINDS = {"d3qn_unified": "joint_d3qn", "pasac_unified": "pasac"}


@pytest.mark.parametrize(
    "algo", ["kddrl", "d3qn_td3", "d3qn_td3_lg", "kddrl_same_clock", "ni", "peng", "d3qn_unified", "pasac_unified"]
)
def test_every_learning_algo_config_builds_and_learns_on_the_fake_env(algo, tmp_path):
    """Each comparison system is a configuration of the same pipeline: compose it, build env + learner, train
    a few episodes on the fake env (fast; the SUMO path is covered by the subprocess tests)."""
    nets = SMALL_NETS.get(algo, ["algo.learner.d3qn.hidden=[16]", "algo.learner.td3.hidden=[16]"])
    job = compose_job(f"algo={algo}", "env.num_roads=2", "compile=false", *nets)
    assert job.algo.name == algo and job.algo.kind == KINDS.get(algo, "hierarchical")
    env, learner, trainer, collector = fake_trainer(
        job, tmp_path, warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10
    )
    if job.algo.kind == "hierarchical":
        assert (learner.embedding is None) == (algo in ("d3qn_td3", "ni", "peng"))
        assert learner.d3qn.actor.module[0].module.dueling == (algo != "ni")
    history = trainer.run(collector)
    env.close()
    assert len(history) == 3 and trainer.counters["cf_updates"] > 0
    period = job.algo.lc_period
    # every episode decides on its first frame and then every lc_period frames: ceil(n / period) per stretch
    assert trainer.counters["frames"] / period <= trainer.counters["decisions"] <= trainer.counters["frames"]
    if period == 1:
        assert trainer.counters["decisions"] == trainer.counters["frames"]


def test_every_issue14_option_trains_on_the_fake_env(tmp_path):
    """The safety and learning-signal options together (README "Safety and learning-signal options"): the pipeline
    builds and learns; the shield's interventions reach the episode records."""
    job = compose_job(
        "algo=d3qn_td3",
        "env.num_roads=2",
        "compile=false",
        "algo.learner.d3qn.hidden=[16]",
        "algo.learner.td3.hidden=[16]",
        "algo.mobil_safety_mask=true",
        "algo.lc_reward=decision",
        "algo.shield=idm",
        "algo.learner.d3qn.semi_mdp=true",
        "env.reward=safe",
        "env.ego_start=window",
    )
    env, learner, trainer, collector = fake_trainer(
        job, tmp_path, warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10
    )
    history = trainer.run(collector)
    env.close()
    assert len(history) == 3 and trainer.counters["cf_updates"] > 0 and trainer.counters["lc_updates"] > 0
    assert all("shield_rate" in ep for ep in history)


@pytest.mark.parametrize("algo", ["peng", "d3qn_unified", "pasac_unified"])
def test_new_systems_checkpoint_and_resume_on_the_fake_env(algo, tmp_path):
    """A run of each new system stops at its checkpoint; a fresh process's learner loads it (networks, targets,
    optimisers, exploration state, buffers) and training continues to the new episode count."""
    import torch

    job = compose_job(f"algo={algo}", "env.num_roads=2", "compile=false", *SMALL_NETS[algo])
    env, learner, trainer, collector = fake_trainer(
        job, tmp_path, warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10
    )
    trainer.run(collector)
    env.close()
    unified = not learner.learns_from_decisions
    assert (trainer.counters["lc_updates"] == 0) == unified and (len(trainer.buffer_lc) == 0) == unified
    torch.manual_seed(99)
    env, fresh, resumed, collector = fake_trainer(
        job, tmp_path, warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10
    )
    assert resumed.load(tmp_path) == 3
    assert {k: v for k, v in resumed.counters.items() if k != "elapsed_s"} == {
        k: v for k, v in trainer.counters.items() if k != "elapsed_s"
    }
    for (name, a), (_, b) in zip(learner.state_dict().items(), fresh.state_dict().items()):
        torch.testing.assert_close(a, b, msg=name)
    assert fresh.exploration() == learner.exploration()
    assert len(resumed.buffer_cf) == len(trainer.buffer_cf) and len(resumed.buffer_lc) == len(trainer.buffer_lc)
    resumed.episodes = 5
    assert len(resumed.run(collector)) == 5 and resumed.counters["cf_updates"] > trainer.counters["cf_updates"]
    env.close()


def test_a_diverging_loss_stops_training_with_a_clear_error(tmp_path):
    job = compose_job("env.num_roads=2", "compile=false")
    env, learner, trainer, collector = fake_trainer(job, tmp_path, warmup_frames=10, batch_size_cf=8, frames_per_env=10)
    learner.update_cf = lambda batch: {"loss_qvalue": float("nan")}
    with pytest.raises(FloatingPointError, match="loss_qvalue = nan.*diverged"):
        trainer.run(collector)
    env.close()


@pytest.mark.parametrize(
    "override, key",
    [
        ("train.batch_size_cf=abc", "train.batch_size_cf"),
        ("train.batch_sise_cf=1", "train.batch_sise_cf"),
        ("algo.learner.d3qn.lrr=1", "algo.learner.d3qn.lrr"),
        ("algo.learner.td3.policy_delay=2.5", "algo.learner.td3.policy_delay"),
        ("algo.lc_period=often", "algo.lc_period"),
        ("algo.idm.T=slow", "algo.idm.T"),
    ],
)
def test_a_typo_or_wrong_type_in_algo_or_train_is_refused_naming_the_key(override, key):
    from hydra.errors import ConfigCompositionException

    algo = ["algo=idm_mobil"] if key.startswith("algo.idm") else []
    with pytest.raises(ConfigCompositionException) as err:
        compose_job(*algo, override)
    message = f"{err.value}\n{err.value.__cause__}"
    assert key in message, message


@pytest.mark.parametrize(
    "override, match",
    [
        ("train.batch_size_cf=0", "train.batch_size_cf must be >= 1, got 0"),
        ("train.checkpoint_every=-1", "train.checkpoint_every must be >= 1"),
        ("train.warmup_frames=-5", "train.warmup_frames must be >= 0"),
        ("episodes=0", "episodes must be >= 1"),
        ("algo.lc_period=0", "algo.lc_period must be >= 1"),
        ("compile=sometimes", "compile must be true, false or auto"),
        ("algo.shield_penalty=-1", "algo.shield_penalty must be >= 0"),
        ("algo.shield_penalty=0.1", "algo.shield_penalty > 0 needs a shield"),
    ],
)
def test_out_of_range_values_are_refused_by_the_schema(override, match):
    with pytest.raises(ValueError, match=match):
        compose_job(override)


@pytest.mark.parametrize(
    "algo, override, message",
    [
        ("peng", "algo.learner.ddpg.tauu=1", "algo.learner.ddpg.tauu"),
        ("peng", "algo.learner.ddpg.hidden=wide", "algo.learner.ddpg.hidden"),
        ("d3qn_unified", "algo.learner.num_levels=many", "algo.learner.num_levels"),
        ("pasac_unified", "algo.learner.pasac.alpha_lrr=1", "algo.learner.pasac.alpha_lrr"),
        ("pasac_unified", "algo.learner.td3.hidden=[8]", "algo.learner.td3"),
        ("d3qn_unified", "algo.lc_period=20", "algo.lc_period must be 1 for algo=d3qn_unified"),
        ("pasac_unified", "algo.lc_period=2", "algo.lc_period must be 1"),
        ("d3qn_unified", "algo.learner.num_levels=1", "algo.learner.num_levels must be >= 2"),
        ("peng", "algo.learner.cf_agent=ppo", "algo.learner.cf_agent='ppo': known agents are td3, ddpg"),
        ("kddrl", "algo.learner.cf_agent=ddpg", "the algo.learner.ddpg node is missing"),
    ],
)
def test_the_new_systems_configs_are_typed_and_range_checked(algo, override, message):
    """Typos and wrong types fail while Hydra composes (naming the key), ranges when the config becomes objects."""
    from hydra.errors import ConfigCompositionException

    with pytest.raises((ConfigCompositionException, ValueError)) as err:
        compose_job(f"algo={algo}", override)
    text = f"{err.value}\n{err.value.__cause__}"
    assert message in text, text


def test_a_bad_algo_or_train_value_is_refused_before_any_simulator_starts(tmp_path):
    for override in ("train.batch_size_cf=abc", "algo.learner.d3qn.lrr=1", "train.batch_size_cf=0"):
        cmd = [sys.executable, "-m", "kddrl_trl.train", override, "episodes=1", "progress=false"]
        done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert done.returncode != 0 and override.split("=")[0] in done.stderr, done.stderr
        assert "SUMO" not in done.stdout + done.stderr and not list(tmp_path.glob("runs/*/checkpoints"))


@pytest.mark.parametrize(
    "override, message",
    [
        ("+episods=5", "error: unknown config key(s) episods: not in the schema"),
        ("+env.braking.relase=x", "error: unknown config key(s) env.braking.relase"),
        ("episodes=-3", "error: episodes must be >= 1, got -3"),
    ],
)
def test_a_refused_config_is_one_line_and_leaves_nothing_behind(tmp_path, override, message):
    """Our refusals end the command with one line naming the key (no traceback unless HYDRA_FULL_ERROR=1), and the
    folders Hydra made for the run (``runs/`` too) are gone; a key added with ``+`` is checked like any other."""
    cmd = [sys.executable, "-m", "kddrl_trl.train", override, "progress=false"]
    env = {k: v for k, v in os.environ.items() if k != "HYDRA_FULL_ERROR"}
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode != 0 and done.stderr.strip().startswith(message), done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_evaluate_does_not_import_the_training_entry_point():
    code = "import sys, kddrl_trl.evaluate; print('kddrl_trl.train' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "False", done.stderr


def test_scenarios_are_the_same_presets_through_hydra_and_python():
    from dataclasses import asdict

    from kddrl_trl.envs import make_config, scenario_names

    for name in scenario_names():
        job = compose_job(f"+scenario={name}")
        assert asdict(job.env.highway()) == asdict(make_config(name))


@pytest.mark.slow
def test_a_mixed_traffic_run_is_evaluated_and_reported_per_scenario(tmp_path):
    """``+scenario=mixed eval_scenarios=[baseline,braking]``: one final evaluation per scenario, each its own folder,
    read by the report as its own row, never mixed with policies trained on the scenario evaluated."""
    cmd = [
        sys.executable,
        "-m",
        "kddrl_trl.train",
        "+scenario=mixed",
        "algo=idm_mobil",
        "eval_episodes=4",
        "env.num_roads=2",
        "progress=false",
        "eval_scenarios=[baseline,braking]",
    ]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    (run,) = list((tmp_path / "runs").glob("mixed__idm_mobil__0__*"))
    summary = json.loads((run / "summary.json").read_text())
    assert summary["final_evaluations"] == ["final__baseline", "final__braking"] and summary["scenario"] == "mixed"
    import pandas as pd

    for scenario, event in (("baseline", False), ("braking", True)):
        final = json.loads((run / f"final__{scenario}" / "summary.json").read_text())
        assert final["scenario"] == scenario and final["trained_on"] == "mixed" and final["episodes"] == 4
        distances = pd.read_csv(run / f"final__{scenario}" / "eval_episodes.csv")["braking_distance"]
        assert distances.notna().all() if event else distances.isna().all()  # every braking episode has the event
    done = subprocess.run(
        [sys.executable, "-m", "kddrl_trl.report", str(tmp_path / "runs"), f"out={tmp_path / 'rep'}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    rows = json.loads((tmp_path / "rep" / "report.json").read_text())["rows"]
    assert sorted((r["scenario"], r["algo"], r["trained_on"]) for r in rows) == [
        ("baseline", "idm_mobil (trained on mixed)", "mixed"),
        ("braking", "idm_mobil (trained on mixed)", "mixed"),
    ]


@pytest.mark.parametrize("entry", ["train", "evaluate", "report"])
def test_help_offers_only_configs_a_user_can_choose(entry):
    """The typed schemas are stored outside the config groups: Hydra's list of the groups (what its default
    ``--help`` printed; the help page is ours now, so the list is asked for by its template variable) holds algos,
    envs, loggers, not them."""
    groups_only = "hydra.help.template=$APP_CONFIG_GROUPS"
    done = subprocess.run(
        [sys.executable, "-m", f"kddrl_trl.{entry}", "--help", groups_only], capture_output=True, text=True, timeout=120
    )
    groups = done.stdout
    assert done.returncode == 0 and "algo: d3qn_td3," in groups and "kddrl" in groups, done.stdout[:2000]
    assert "_schema" not in groups and "_job" not in groups
