"""A seed batch as a job (``seeds=[...]``): each seed's run folder, the shared checkpoints and the resume, the
per-seed update counts, the config's refusals, on the fake env; and the command a user types, on SUMO."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace

import pandas as pd
import pytest
import torch
from testkit import TINY, compose_job, kill_when, run_module

from kddrl_trl.baselines import IDMMobilPolicy
from kddrl_trl.conf.resolvers import seed_label
from kddrl_trl.envs.fake import FakeHighwayEnv
from kddrl_trl.eval.rollout import evaluate_policy
from kddrl_trl.factories import make_env, make_seed_batch, make_seed_batch_collector, make_trained_learner
from kddrl_trl.modules.seed_batch import seed_slice
from kddrl_trl.reporting.records import find_runs
from kddrl_trl.training import load_training_checkpoint
from kddrl_trl.training.seed_batch_trainer import SeedBatchTrainer, read_seed_batch

SEEDS = [3, 5]


def _job(*overrides, **train):
    job = compose_job("seeds=[3,5]", *TINY, *overrides)
    job.train = replace(job.train, **train)
    job.torch_device, job.cudagraphs, job.threads = torch.device("cpu"), False, None
    return job


def _collector(job, batch, done=(0, 0)):
    roads = [s + n for s, n in zip(SEEDS, done) for _ in range(job.env.num_roads)]
    env = make_env(job.env, job.algo, seed=roads[0], compile=False, fake=True, road_seeds=roads)
    return make_seed_batch_collector(env, batch, job)


def _floats(td):
    return {k: td.get(k) for k in td.keys(True, True) if td.get(k).is_floating_point()}


def test_the_fake_env_carries_each_seeds_traffic_on_its_roads():
    batch = _floats(FakeHighwayEnv(num_roads=4, seed=3, road_seeds=[3, 3, 5, 5]).reset())
    for rows, seed in ((slice(0, 2), 3), (slice(2, 4), 5)):
        alone = _floats(FakeHighwayEnv(num_roads=2, seed=seed).reset())
        assert alone and all(torch.equal(batch[k][rows], v) for k, v in alone.items())
    other = _floats(FakeHighwayEnv(num_roads=2, seed=4).reset())
    assert not all(torch.equal(batch[k][2:4], v) for k, v in other.items())  # another seed: other traffic


def test_a_seeds_test_episodes_in_a_batch_are_its_episodes_alone():
    """The batched final evaluation counts each seed's episodes on its own rows, in start order, as an env of its
    own counts them: with a policy that acts row by row, seed by seed the same episodes (every field equal, the
    float sums over an episode's frames to rounding: they are reduced over a slice of the batch's rows)."""
    policy = IDMMobilPolicy()
    batch = evaluate_policy(
        FakeHighwayEnv("congested", num_roads=4, seed=3, road_seeds=[3, 3, 5, 5]), policy, 5, 3, False, groups=2
    )
    for seed, episodes in zip((3, 5), batch):
        alone = evaluate_policy(FakeHighwayEnv("congested", num_roads=2, seed=seed), policy, 5, seed, False)
        assert len(episodes) == len(alone) == 5
        for a, b in zip(episodes, alone):
            assert a.keys() == b.keys()
            for k in a:
                same = a[k] == b[k] or (a[k] != a[k] and b[k] != b[k])  # (NaN: a field an episode does not have)
                assert same or (isinstance(a[k], float) and math.isclose(a[k], b[k], rel_tol=1e-12)), (k, a[k], b[k])
    assert [e["mean_speed"] for e in batch[0]] != [e["mean_speed"] for e in batch[1]]


def test_a_seed_batch_trains_each_seed_into_its_folder_and_resumes_from_the_shared_cut(tmp_path, monkeypatch):
    job = _job("episodes=8", checkpoint_every=2, eval_every=0, warmup_frames=40)

    class Stop(Exception):
        pass

    first = SeedBatchTrainer._checkpoint

    def stop_after_the_first_cut(self, books):
        first(self, books)
        raise Stop

    monkeypatch.setattr(SeedBatchTrainer, "_checkpoint", stop_after_the_first_cut)
    batch = make_seed_batch(job, tmp_path, fake=True)
    batch.record(seeds=SEEDS, folders=[b.run_dir.name for b in batch.books])
    with pytest.raises(Stop):
        batch.run(_collector(job, batch))
    monkeypatch.undo()
    cut = read_seed_batch(tmp_path)["checkpoint"]
    names = [f"baseline__kddrl__{s}" for s in SEEDS]
    assert sorted(cut) == names and all(n >= 2 for n in cut.values())
    frames = {b.counters["frames"] for b in batch.books}
    assert len(frames) == 1  # one cut: every seed has collected the same frames

    resumed = make_seed_batch(job, tmp_path, fake=True)
    done = resumed.load()
    assert done == [cut[n] for n in names]
    for i, (book, name) in enumerate(zip(resumed.books, names)):
        saved = load_training_checkpoint(tmp_path / name / "checkpoints" / f"ep{cut[name]:06d}.pt")
        own = seed_slice(resumed.learner, i)
        for key, value in saved["learner"]["modules"].items():
            if key != "counters":
                assert torch.equal(own[key], value), key
    assert {b.counters["frames"] for b in resumed.books} == frames
    histories = resumed.run(_collector(job, resumed, done))
    assert [len(h) for h in histories] == [8, 8]
    for i, (book, name) in enumerate(zip(resumed.books, names)):
        latest = load_training_checkpoint(tmp_path / name / "checkpoints" / "ep000008.pt")
        lc, cf = book.counters["lc_updates"], book.counters["cf_updates"]
        assert latest["learner"]["modules"]["counters"].tolist() == [lc, cf, cf // 2]
        assert 0 < lc <= book.counters["decisions"] and 0 < cf <= book.counters["frames"]
        # each seed's D3QN optimiser stepped once per update of its own (its per-seed step count)
        steps = {int(s["step"][i]) for s in resumed.learner.opt_lc.state.values()}
        assert steps == {lc}
        assert len(latest["history"]) == 8 and latest["buffer_cf"] is not None
    lcs = [b.counters["lc_updates"] for b in resumed.books]
    assert lcs[0] != lcs[1]  # the seeds decide apart: each learns from its own decisions


@pytest.mark.parametrize(
    "override, message",
    [
        ("algo=idm_mobil", "hierarchical"),
        ("algo=d3qn_unified", "hierarchical"),
        ("collector.workers=2", "collector.workers=1"),
        ("train.prioritized=true", "train.prioritized=False"),
        ("eval_seed=7", "eval_seed=null"),
        ("video=true", "video=False"),
    ],
)
def test_a_seed_batch_refuses_what_it_does_not_run(override, message):
    with pytest.raises(Exception, match=message):
        compose_job("seeds=[3,5]", override)


def test_seeds_are_distinct_and_may_be_given_as_a_range():
    with pytest.raises(Exception, match="distinct"):
        compose_job("seeds=[3,3]")
    assert compose_job("seeds=${kddrl_seeds:200,203}").seeds == [200, 201, 202]
    assert compose_job().seeds is None
    assert (seed_label(0, None), seed_label(0, [200, 201, 202]), seed_label(0, [3, 7])) == (
        "0",
        "seeds200-202",
        "seeds3_7",
    )


def test_a_seed_batch_runs_as_typed_on_sumo_and_its_folders_read_as_runs(tmp_path):
    args = [
        "seeds=[3,5]",
        "episodes=3",
        "eval_episodes=2",
        "train.checkpoint_every=2",
        "train.eval_every=2",
        "train.eval_episodes=1",
        *TINY,
    ]
    cmd = [sys.executable, "-m", "kddrl_trl.train", *args]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-4000:]
    (batch,) = (tmp_path / "runs").glob("baseline__kddrl__seeds3_5__*")
    record = json.loads((batch / "seed_batch.json").read_text())
    assert record["seeds"] == SEEDS and record["finished"] is True
    for i, seed in enumerate(SEEDS):
        run = batch / f"baseline__kddrl__{seed}"
        summary = json.loads((run / "summary.json").read_text())
        assert summary["seed"] == seed and summary["seed_batch"] == {"seeds": SEEDS, "index": i}
        assert summary["training"]["episodes"] == 3 and summary["run_dir"] == str(run)
        assert len(pd.read_csv(run / "train_episodes.csv")) == 3 and len(pd.read_csv(run / "eval_episodes.csv")) == 2
        assert len(pd.read_csv(run / "validation.csv")) == 1
        config = (run / "config.yaml").read_text()
        assert f"seed: {seed}\n" in config and "seeds: null" in config
        algo, learner, _, _ = make_trained_learner(run)  # a seed's folder is a run folder: evaluate reads it
        assert learner.seeds is None
    assert [r.seed for r in find_runs([batch])] == SEEDS
    again = subprocess.run([*cmd, f"resume={batch}"], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    assert list((tmp_path / "runs").iterdir()) == [batch]  # a finished batch resumed: nothing new, nothing rerun


def _batch_cut(batch) -> int:
    """The episodes every seed of ``batch`` has checkpointed (0 before its first cut)."""
    return min((read_seed_batch(batch) or {}).get("checkpoint", {}).values(), default=0)


@pytest.mark.slow
def test_a_killed_seed_batch_resumes_on_sumo_from_its_last_shared_cut(tmp_path):
    """``kill -9`` in the middle of a batch's training on SUMO, then ``resume=true``: each seed's run goes on from the
    batch's last cut to its full length, with no episode logged twice and none missing, in the folders it began."""
    args = ["seeds=[3,5]", "episodes=8", "eval_episodes=1", "train.checkpoint_every=2", "train.eval_every=0", *TINY]
    train = ["kddrl_trl.train", *args]

    def cut():
        found = list((tmp_path / "runs").glob("baseline__kddrl__seeds3_5__*"))
        return found[0] if found and 2 <= _batch_cut(found[0]) < 8 else None

    batch, stderr = kill_when(train, tmp_path, cut)
    assert batch is not None, "no shared cut appeared before the batch ended: " + stderr
    killed_at = _batch_cut(batch)
    assert read_seed_batch(batch).get("finished") is not True
    assert not any((batch / f"baseline__kddrl__{s}" / "summary.json").exists() for s in SEEDS)

    run_module([*train, "resume=true"], tmp_path)  # asserts it succeeded
    assert list((tmp_path / "runs").iterdir()) == [batch]  # the resumed batch made no folder of its own
    assert read_seed_batch(batch)["finished"] is True and killed_at >= 2
    for seed in SEEDS:
        run = batch / f"baseline__kddrl__{seed}"
        summary = json.loads((run / "summary.json").read_text())
        assert summary["training"]["episodes"] == 8 and summary["run_dir"] == str(run)
        assert len(pd.read_csv(run / "train_episodes.csv")) == 8
        logged = (run / "logs/scalars/train/return_cf.csv").read_text().split()
        assert [int(float(line.split(",")[0])) for line in logged] == list(range(8))  # none twice, none missing
