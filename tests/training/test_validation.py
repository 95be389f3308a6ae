"""Periodic validation beside the training: each validation is of the learner as it was when it started, the
training goes on while it runs, a checkpoint does not wait for it but lists it with the learner it was given, and a
resumed run starts again, on those weights, every one its checkpoint lists as under way."""

from __future__ import annotations

import copy
from concurrent.futures import Future
from functools import partial

import pandas as pd
import pytest
import torch
from testkit import compose_job, fake_trainer
from torchrl.envs.utils import ExplorationType, set_exploration_type

from kddrl_trl.eval.periodic import PeriodicEvaluator
from kddrl_trl.eval.rollout import evaluate_policy
from kddrl_trl.factories import make_env, make_learner
from kddrl_trl.run_folder import checkpoint_candidates
from kddrl_trl.training import CheckpointError, load_training_checkpoint, save_training_checkpoint

SMALL = ("env.num_roads=2", "compile=false", "algo.learner.d3qn.hidden=[16]", "algo.learner.td3.hidden=[16]")
COUNTS = ("frames", "decisions", "cf_updates", "lc_updates")
TRAIN = dict(warmup_frames=20, batch_size_cf=16, batch_size_lc=4, frames_per_env=10, checkpoint_every=1, eval_every=1)


def _weight_sum(state: dict) -> float:
    return float(sum(v.double().sum() for v in state.values() if v.is_floating_point()))


class LaggingEvaluator:
    """An in-process stand-in for :class:`PeriodicEvaluator` whose validations finish only when the trainer asks for
    their result (``waited`` counts those asks): every one is still running at the next batch and checkpoint. A
    validation's ``mean_speed_kmh`` is a function of the learner's weights when it started (kept here too, to
    compare); its score falls with each validation, so the first one is the best."""

    def __init__(self, learner):
        self.learner, self.started, self.waited = learner, [], 0

    def submit(self, policy) -> Future:
        future = Future()
        future.state, future.order = copy.deepcopy(self.learner.state_dict()), len(self.started)
        self.started.append(future.state)
        return future

    def result(self, future: Future):
        self.waited += 1
        future.set_result(None)
        keys = ("mean_accel", "lane_changes", "return_lc", "return_cf", "collision_rate")
        summary = {"score": -float(future.order), "mean_speed_kmh": _weight_sum(future.state)}
        return [], {**summary, **{k: 0.0 for k in keys}}

    def close(self) -> None:
        pass


def _trained(tmp_path, episodes: int = 3):
    """(learner, trainer) of a 3-episode run on the fake env, validated and checkpointed after every batch."""
    env, learner, trainer, collector = fake_trainer(compose_job(*SMALL), tmp_path, **TRAIN)
    trainer.evaluator, trainer.episodes = LaggingEvaluator(learner), episodes
    try:
        trainer.run(collector)
    finally:
        env.close()
    return learner, trainer


def test_validations_are_recorded_at_their_episodes_with_the_weights_they_started_with(tmp_path):
    learner, trainer = _trained(tmp_path)
    started = trainer.evaluator.started
    steps = [v["episodes_trained"] for v in trainer.validations]
    assert len(steps) == len(started) >= 2 and steps == sorted(set(steps)) and steps[-1] == 3
    # each record is of the weights at its start, and the training went on between them
    assert [v["mean_speed_kmh"] for v in trainer.validations] == [_weight_sum(s) for s in started]
    assert len({v["mean_speed_kmh"] for v in trainer.validations}) == len(steps)
    # best.pt holds the learner as it was when the best (the first) validation started, not as it is now
    saved = torch.load(tmp_path / "checkpoints" / "best.pt", weights_only=False)
    assert saved["validation"]["episodes_trained"] == steps[0]
    for name, value in started[0].items():
        torch.testing.assert_close(saved["learner"]["modules"][name], value, rtol=0, atol=0, msg=name)
    assert _weight_sum(saved["learner"]["modules"]) != _weight_sum(learner.state_dict())
    # eval/ rows logged once each, at the validations' episodes
    rows = (tmp_path / "logs" / "scalars" / "eval" / "score.csv").read_text().split()
    assert [int(float(r.split(",")[0])) for r in rows] == steps
    # a checkpoint lists the validations under way with the learner each was given; the last lists none
    for path in checkpoint_candidates(tmp_path)[1:]:
        payload = load_training_checkpoint(path)
        under_way = payload["validating"]
        assert under_way and under_way == sorted(under_way) and under_way[-1] <= len(payload["history"])
        for step, given in zip(under_way, payload["validating_learners"], strict=True):
            assert _weight_sum(given["modules"]) == _weight_sum(started[steps.index(step)])
    last = load_training_checkpoint(checkpoint_candidates(tmp_path)[0])
    assert last["validating"] == [] and last["validating_learners"] == []


def test_a_checkpoint_does_not_wait_for_a_validation_under_way(tmp_path):
    """Every validation of the stand-in runs until the trainer asks for it: the checkpoints after each batch ask
    for none (counted after each), even those written while a validation started at an earlier episode still runs;
    only the last one (``final``) does."""
    env, learner, trainer, collector = fake_trainer(compose_job(*SMALL), tmp_path, **TRAIN)
    trainer.evaluator, trainer.episodes = LaggingEvaluator(learner), 8
    saves = []
    checkpoint = trainer.checkpoint

    def counted(final=False):
        path = checkpoint(final)
        running = [step for step, _, _ in trainer.pending]
        saves.append((final, trainer.evaluator.waited, any(s < len(trainer.history) for s in running)))
        return path

    trainer.checkpoint = counted
    try:
        trainer.run(collector)
    finally:
        env.close()
    assert any(earlier for final, _, earlier in saves if not final), "no checkpoint met an earlier validation"
    assert all(waited == 0 for final, waited, _ in saves if not final)
    assert saves[-1][0] and trainer.evaluator.waited == len(trainer.validations) == len(trainer.evaluator.started)


class PromptEvaluator(LaggingEvaluator):
    """Its validations are done as soon as they are started."""

    def submit(self, policy) -> Future:
        future = super().submit(policy)
        future.set_result(None)
        return future

    def result(self, future: Future):
        keys = ("mean_accel", "lane_changes", "return_lc", "return_cf", "collision_rate")
        summary = {"score": -float(future.order), "mean_speed_kmh": _weight_sum(future.state)}
        return [], {**summary, **{k: 0.0 for k in keys}}


def test_a_finished_validation_is_logged_after_the_next_batch_not_at_the_next_checkpoint(tmp_path):
    env, learner, trainer, collector = fake_trainer(compose_job(*SMALL), tmp_path, **{**TRAIN, "checkpoint_every": 100})
    trainer.evaluator, trainer.episodes, logged = PromptEvaluator(learner), 4, []
    log_scalar = trainer.logger.log_scalar
    trainer.logger.log_scalar = lambda name, value, step: (logged.append((name, step)), log_scalar(name, value, step))
    try:
        trainer.run(collector)
    finally:
        env.close()
    first = next(i for i, (name, _) in enumerate(logged) if name == "eval/score")
    assert any(name.startswith("train/") for name, _ in logged[first:])  # before the final checkpoint
    assert [s for name, s in logged if name == "eval/score"] == [v["episodes_trained"] for v in trainer.validations]


def test_a_resumed_run_validates_again_what_its_checkpoint_left_under_way(tmp_path):
    """Resumed from a checkpoint that lists several validations under way, the run starts each again on the very
    weights it was given (bit for bit), then trains on with the checkpoint's own learner (bit for bit)."""
    _, trainer = _trained(tmp_path, episodes=8)  # 2 roads: at least 4 batches, so several validations under way
    previous = checkpoint_candidates(tmp_path)[1]  # the newest but one: written while its validations ran
    payload = load_training_checkpoint(previous)
    done, under_way = len(payload["history"]), payload["validating"]
    assert len(under_way) >= 2 and under_way[-1] == done
    (tmp_path / "checkpoints" / checkpoint_candidates(tmp_path)[0].name).unlink()  # resume from `previous`
    (tmp_path / "checkpoints" / "latest").unlink()
    env, learner, again, collector = fake_trainer(compose_job(*SMALL), tmp_path, **TRAIN)
    again.evaluator, again.episodes = LaggingEvaluator(learner), trainer.episodes
    trained_from = []
    explore_step = learner.explore_step  # the first thing the loop does with the learner, after the restarts
    learner.explore_step = lambda *a: (trained_from.append(copy.deepcopy(learner.state_dict())), explore_step(*a))
    try:
        assert again.load(tmp_path) == done and [s for s, _ in again.unfinished] == under_way
        again.run(collector)
    finally:
        env.close()
    started = trainer.evaluator.started
    steps = [v["episodes_trained"] for v in trainer.validations]
    for k, step in enumerate(under_way):  # started again in order, each on its own weights
        for name, value in started[steps.index(step)].items():
            torch.testing.assert_close(again.evaluator.started[k][name], value, rtol=0, atol=0, msg=f"{step} {name}")
    for name, value in payload["learner"]["modules"].items():  # the training goes on from the checkpoint's learner
        torch.testing.assert_close(trained_from[0][name], value, rtol=0, atol=0, msg=name)
    ours = {v["episodes_trained"]: v["mean_speed_kmh"] for v in trainer.validations}
    theirs = {v["episodes_trained"]: v["mean_speed_kmh"] for v in again.validations}
    assert all(theirs[s] == ours[s] for s in under_way)
    assert sorted(theirs) == [v["episodes_trained"] for v in again.validations]


def test_a_run_resumed_at_its_last_episode_trains_no_further(tmp_path):
    """Killed after its last checkpoint (in its final evaluation), a run resumes with the learner that checkpoint
    holds: no batch more is collected or learned from, and the checkpoint is left as it was."""
    learner, trainer = _trained(tmp_path)
    final = checkpoint_candidates(tmp_path)[0]
    written = final.read_bytes()
    env, learner_again, again, collector = fake_trainer(compose_job(*SMALL), tmp_path, **TRAIN)
    again.evaluator = LaggingEvaluator(learner_again)
    try:
        assert again.load(tmp_path) == 3
        again.run(collector)
    finally:
        env.close()
    assert {k: again.counters[k] for k in COUNTS} == {k: trainer.counters[k] for k in COUNTS}
    assert again.evaluator.started == [] and again.validations == trainer.validations
    for name, value in learner.state_dict().items():
        torch.testing.assert_close(learner_again.state_dict()[name], value, rtol=0, atol=0, msg=name)
    assert checkpoint_candidates(tmp_path)[0] == final and final.read_bytes() == written


@pytest.mark.parametrize("finish", [True, False])
def test_a_run_resumed_at_its_last_episode_records_the_validation_left_under_way(tmp_path, finish):
    """``finish=False`` is what ``train`` does: the validation started again runs beside the final evaluation and
    :meth:`Trainer.finish` records it, in the last checkpoint too."""
    _, trainer = _trained(tmp_path)
    final = checkpoint_candidates(tmp_path)[0]
    payload = load_training_checkpoint(final)
    assert payload["validations"][-1]["episodes_trained"] == 3
    payload["validating"], payload["validations"] = [3], payload["validations"][:-1]  # killed while it ran
    payload["validating_learners"] = [payload["learner"]]
    payload.pop("format")
    save_training_checkpoint(tmp_path, 3, payload)
    env, learner, again, collector = fake_trainer(compose_job(*SMALL), tmp_path, **TRAIN)
    again.evaluator = LaggingEvaluator(learner)
    try:
        assert again.load(tmp_path) == 3 and [s for s, _ in again.unfinished] == [3]
        again.run(collector, finish=finish)
    finally:
        env.close()
    assert len(again.validations) == len(trainer.validations) - (not finish)
    if not finish:
        again.finish()
    assert {k: again.counters[k] for k in COUNTS} == {k: trainer.counters[k] for k in COUNTS}
    assert len(again.evaluator.started) == 1  # that validation only, of the same weights, recorded
    assert again.validations[:-1] == trainer.validations[:-1]
    assert again.validations[-1]["episodes_trained"] == 3  # the stand-in's score counts its own validations
    assert again.validations[-1]["mean_speed_kmh"] == trainer.validations[-1]["mean_speed_kmh"]
    resaved = load_training_checkpoint(checkpoint_candidates(tmp_path)[0])
    assert resaved["validating"] == [] and resaved["validations"] == again.validations


def test_run_without_finish_leaves_the_last_validation_running_for_the_final_evaluation(tmp_path):
    """``run(finish=False)``: the validations still running when ``run`` returns, the last episode's among them, are
    under way (the last checkpoint lists them, a resumed run starts them again), and :meth:`Trainer.finish` records
    them, writes the last checkpoint again with them (the learner and counters unchanged) and stops the evaluator."""
    env, learner, trainer, collector = fake_trainer(compose_job(*SMALL), tmp_path, **TRAIN)
    trainer.evaluator = LaggingEvaluator(learner)
    closed = []
    trainer.evaluator.close = lambda: closed.append(True)
    try:
        trainer.run(collector, finish=False)
    finally:
        env.close()
    steps = [v["episodes_trained"] for v in trainer.validations]
    running = [s for s, _, _ in trainer.pending]
    assert 3 not in steps and running[-1] == 3 and not closed
    last = checkpoint_candidates(tmp_path)[0]
    before = load_training_checkpoint(last)
    assert before["validating"] == running and before["validations"] == trainer.validations
    assert trainer.finish() is trainer.validations and closed
    assert [v["episodes_trained"] for v in trainer.validations] == [*steps, *running] and not trainer.pending
    assert trainer.validations[-1]["mean_speed_kmh"] == _weight_sum(learner.state_dict())  # the final weights
    after = load_training_checkpoint(last)
    assert checkpoint_candidates(tmp_path)[0] == last
    assert after["validating"] == [] and after["validations"] == trainer.validations
    assert {k: after["counters"][k] for k in COUNTS} == {k: before["counters"][k] for k in COUNTS}
    torch.testing.assert_close(after["learner"], before["learner"], rtol=0, atol=0)  # weights, optimiser states


@pytest.mark.parametrize(
    ("validating", "learners", "message"),
    [
        ([1, 2], None, r"under way at episodes \[1, 2\] without the learners"),  # older code's, earlier ones
        ([1, 2], ["one"], r"'validating' \[1, 2\] and 'validating_learners' \(1\) do not pair up"),
        ([9], ["one"], r"do not pair up as evaluations started by episode 3"),
    ],
)
def test_a_checkpoint_whose_validations_under_way_cannot_be_started_again_is_refused(
    tmp_path, validating, learners, message
):
    _trained(tmp_path)
    payload = load_training_checkpoint(checkpoint_candidates(tmp_path)[0])
    payload["validating"] = validating
    if learners is None:
        del payload["validating_learners"]
    else:
        payload["validating_learners"] = [payload["learner"]] * len(learners)
    payload.pop("format")
    path = save_training_checkpoint(tmp_path, 3, payload)
    env, learner, again, _ = fake_trainer(compose_job(*SMALL), tmp_path, **TRAIN)
    env.close()
    with pytest.raises(CheckpointError, match=message) as err:
        again.load(tmp_path)
    assert str(path) in str(err.value)


def test_an_older_checkpoint_listing_its_own_episode_starts_it_again_on_its_own_learner(tmp_path):
    _trained(tmp_path)
    payload = load_training_checkpoint(checkpoint_candidates(tmp_path)[0])
    payload["validating"], payload["validations"] = [3], payload["validations"][:-1]
    del payload["validating_learners"]  # as the code before this contract wrote it
    payload.pop("format")
    save_training_checkpoint(tmp_path, 3, payload)
    env, learner, again, _ = fake_trainer(compose_job(*SMALL), tmp_path, **TRAIN)
    env.close()
    assert again.load(tmp_path) == 3 and [s for s, _ in again.unfinished] == [3]
    assert _weight_sum(again.unfinished[0][1]["modules"]) == _weight_sum(payload["learner"]["modules"])


def test_a_validation_is_of_the_policy_as_it_was_when_it_started(tmp_path):
    """The real worker: the learner's weights change right after the start, the validation does not see it."""
    job = compose_job(*SMALL)
    learner = make_learner(job.algo, compile=False)
    factory = partial(make_env, job.env, job.algo, seed=7, compile=False, fake=True)
    evaluator = PeriodicEvaluator(factory, episodes=2, seed=7)
    try:
        before = copy.deepcopy(learner.policy(explore=False))
        future = evaluator.submit(learner.policy(explore=False))
        with torch.no_grad():
            for p in learner.parameters():
                p.add_(1.0)
        episodes, summary = evaluator.result(future)
    finally:
        evaluator.close()
    env = factory()
    try:
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            expected = evaluate_policy(env, before, 2, 7, progress=False)
            moved = evaluate_policy(env, learner.policy(explore=False), 2, 7, progress=False)
    finally:
        env.close()
    assert pd.DataFrame(episodes).equals(pd.DataFrame(expected)) and "score" in summary
    assert not pd.DataFrame(moved).equals(pd.DataFrame(expected))  # the change would have shown
