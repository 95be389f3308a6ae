"""The one episode-metrics path: ``EpisodeTracker`` on collected frames and ``evaluate_policy`` on the fake and the
SUMO env (bare or transformed), checked against the metrics the frames imply."""

from __future__ import annotations

import math

import pytest
from testkit import command, rollout
from torchrl.envs import StepCounter, TransformedEnv

from kddrl_trl import keys as K
from kddrl_trl.baselines import IDMMobilPolicy
from kddrl_trl.envs import FakeHighwayEnv, SumoHighwayEnv
from kddrl_trl.eval import EpisodeTracker, evaluate_policy, summarize


def implied_episodes(frames) -> list[dict]:
    """The episodes of ``frames`` [B, T], frame by frame in plain Python (the reference for the tracker)."""
    nxt = frames["next"]
    b, t = frames.batch_size
    out, open_ = [], [dict(frames=0, speed=0.0, accel=0.0, lc=0, r_lc=0.0, r_cf=0.0) for _ in range(b)]
    for j in range(t):
        for r in range(b):
            ep = open_[r]
            ep["frames"] += 1
            ep["speed"] += float(nxt[K.EGO_STATE][r, j, 1])
            ep["accel"] += float(nxt[K.EGO_ACCEL][r, j, 0])
            ep["lc"] += int(nxt[K.LC_STARTED][r, j, 0])
            ep["r_lc"] += float(nxt[K.LC_REWARD][r, j, 0])
            ep["r_cf"] += float(nxt[K.CF_REWARD][r, j, 0])
            if nxt["done"][r, j, 0]:
                out.append(
                    {
                        "road": r,
                        "frames": ep["frames"],
                        "mean_speed": ep["speed"] / ep["frames"],
                        "mean_accel": ep["accel"] / ep["frames"],
                        "lane_changes": ep["lc"],
                        "return_lc": ep["r_lc"],
                        "return_cf": ep["r_cf"],
                        "outcome": K.OUTCOMES[int(nxt[K.OUTCOME][r, j, 0])],
                    }
                )
                open_[r] = dict(frames=0, speed=0.0, accel=0.0, lc=0, r_lc=0.0, r_cf=0.0)
    return out


def assert_match(tracked: list[dict], implied: list[dict], ignore=()) -> None:
    """Same episodes, same fields (floats up to rounding: sums run in another order)."""
    assert len(tracked) == len(implied) > 0
    for got, want in zip(tracked, implied):
        for key, value in want.items():
            if key not in ignore:
                expected = pytest.approx(value, rel=1e-6, abs=1e-6, nan_ok=True) if isinstance(value, float) else value
                assert got[key] == expected, key


def test_tracker_matches_the_frames_and_carries_across_batches():
    env = FakeHighwayEnv("congested", num_roads=4, seed=0)
    frames = rollout(env, IDMMobilPolicy(), 400)
    whole = EpisodeTracker()(frames)
    assert_match(whole, implied_episodes(frames))
    assert [e["index"] for e in whole] == list(range(len(whole)))  # finish order
    chunked, tracker = [], EpisodeTracker()
    for part in frames.split([7, 93, 1, 299], dim=1):
        chunked += tracker(part)
    assert_match(chunked, whole)
    assert tracker.finished == len(whole)
    # start order: the 4 first episodes, then a new one on each row right after each done
    assert sorted(e["start"] for e in whole) == list(range(len(whole)))
    assert [e["road"] for e in sorted(whole, key=lambda e: e["start"])[:4]] == [0, 1, 2, 3]


def test_tracker_outcomes_and_collision_codes_on_the_fake():
    env = FakeHighwayEnv(num_roads=8, seed=0, flow_vph=6000.0)
    frames = rollout(env, lambda td: td.update(command(env, K.KEEP, 5.0)), 300)
    episodes = EpisodeTracker()(frames)
    assert_match(episodes, implied_episodes(frames))
    hit = [e for e in episodes if e["collision"]]
    assert hit and all(e["outcome"] == "collision" for e in hit)
    assert all(e["collision_kind"] in ("rear_end", "hit_from_behind") for e in hit)  # no lane change commanded
    assert {e["outcome"] for e in episodes} <= set(K.OUTCOMES[1:])
    assert all(e["collision_kind"] == "none" and e["collision_with"] == "" for e in episodes if not e["collision"])
    assert all(math.isnan(e["braking_distance"]) for e in episodes)  # no braking event in the fake


def test_tracker_refuses_frames_without_the_keys():
    frames = rollout(FakeHighwayEnv(num_roads=2, seed=0), IDMMobilPolicy(), 3)
    with pytest.raises(KeyError, match="episode"):
        EpisodeTracker()(frames.exclude(("next", *K.OUTCOME)))
    with pytest.raises(ValueError, match=r"\[B, T\]"):
        EpisodeTracker()(frames[:, 0])


def test_evaluate_policy_on_the_fake_in_start_order():
    env = FakeHighwayEnv("baseline", num_roads=4, seed=123)
    seen = []
    episodes = evaluate_policy(env, IDMMobilPolicy(), 10, seed=5, progress=False, on_episode=seen.append)
    assert [e["start"] for e in episodes] == list(range(10))
    assert [e["start"] for e in sorted(seen, key=lambda e: e["start"])] == list(range(10))
    # the same seed gives the same episodes, bare or transformed; the episodes are the frames'
    again = evaluate_policy(
        TransformedEnv(FakeHighwayEnv("baseline", num_roads=4), StepCounter()),
        IDMMobilPolicy(),
        10,
        seed=5,
        progress=False,
    )
    assert_match(again, episodes)
    env.set_seed(5)
    frames = rollout(env, IDMMobilPolicy(), 600)
    tracked = sorted(EpisodeTracker()(frames), key=lambda e: e["start"])[:10]
    assert_match(tracked, episodes, ignore=("index",))
    summary = summarize(episodes)
    assert summary["episodes"] == 10 and summary["collision_rate"] == 0.0
    with pytest.raises(ValueError, match="episodes"):
        evaluate_policy(env, IDMMobilPolicy(), 0, seed=0)


@pytest.mark.usefixtures("no_sumo_open")
def test_evaluate_policy_on_sumo_matches_the_frames():
    env = SumoHighwayEnv("braking", num_roads=4, seed=0)
    try:
        episodes = evaluate_policy(TransformedEnv(env, StepCounter()), IDMMobilPolicy(), 6, seed=3, progress=False)
        assert [e["start"] for e in episodes] == list(range(6))
        assert all(100.0 <= e["braking_distance"] <= 300.0 for e in episodes)
        assert all(e["outcome"] in K.OUTCOMES[1:] for e in episodes)
        env.set_seed(3)  # the same traffic again: the frames imply the same episodes
        frames = rollout(env, IDMMobilPolicy(), 300)
        tracked = EpisodeTracker()(frames)
        assert_match(tracked, implied_episodes(frames))
        by_start = {e["start"]: e for e in tracked}
        same = [e for e in episodes if e["start"] in by_start]
        assert len(same) >= 4
        assert_match([by_start[e["start"]] for e in same], same, ignore=("index",))
    finally:
        env.close()


def test_the_same_seed_gives_the_same_episodes_again_on_an_env_with_generative_noise():
    """The KDDRL transform stack draws trajGAN / lcGAN noise from streams of its own: evaluating twice on one env
    (as every periodic validation does) must restart them with the env's seed, or the second evaluation meets other
    predictions, and so other episodes, than the first."""
    import pandas as pd
    from testkit import compose_job

    from kddrl_trl.factories import make_env, make_learner

    job = compose_job("env.num_roads=2", "compile=false")
    env = make_env(job.env, job.algo, seed=0, compile=False, fake=True)
    policy = make_learner(job.algo, compile=False).policy(explore=False)
    try:
        first, again = (pd.DataFrame(evaluate_policy(env, policy, 3, seed=4, progress=False)) for _ in range(2))
    finally:
        env.close()
    assert first.equals(again)


@pytest.mark.parametrize("collisions_only", [True, False])
def test_trace_recorder_can_keep_only_the_crashes(collisions_only):
    """``video_select=collisions``: the recorder keeps the first episodes that end in a collision and no other; by
    default it keeps the first episodes whatever their end."""
    from kddrl_trl.baselines import RandomDrivingPolicy
    from kddrl_trl.eval.trace import TraceRecorder

    env = FakeHighwayEnv("braking", num_roads=4, seed=0)
    policy, recorder, td = RandomDrivingPolicy(), TraceRecorder(2, collisions_only=collisions_only), env.reset()
    for _ in range(2000):
        full, td = env.step_and_maybe_reset(policy(td))
        recorder(full)
    outcomes = [t["outcome"] for t in recorder.chosen()]
    if collisions_only:
        assert outcomes == ["collision", "collision"] and recorder.done
    else:
        assert len(outcomes) == 2 and "collision" in {t["outcome"] for t in recorder.traces} != {"collision"}


def test_a_crash_trace_labels_its_last_frame_and_the_frame_explains_itself():
    """The recorder marks the collision frame (kind, other slot) and each frame's braking car; the drawn frame has
    the colour legend, the braking car in its colour with the event's phase, and the collision's label."""
    import numpy as np
    from matplotlib.colors import to_rgb

    from kddrl_trl.baselines import RandomDrivingPolicy
    from kddrl_trl.eval.render import BRAKING_COLOR, LEGEND, _plt, draw_frame, frame_rgb
    from kddrl_trl.eval.trace import TraceRecorder

    env = FakeHighwayEnv("braking", num_roads=4, seed=0)
    policy, recorder, td = RandomDrivingPolicy(), TraceRecorder(1, collisions_only=True), env.reset()
    while not recorder.done:
        full, td = env.step_and_maybe_reset(policy(td))
        recorder(full)
    (trace,) = recorder.chosen()
    last = trace["frames"][-1]
    assert last["collision"] == trace["collision_kind"] != "none" and "collision" not in trace["frames"][-2]
    assert all("braking_slot" in f for f in trace["frames"])
    frame = {**last, "braking_phase": "standing", "braking_slot": "b", "neighbours": {"b": [last["y"] + 8, last["x"]]}}
    frame["collision_with"] = "b"
    fig = _plt().figure()
    ax = fig.add_subplot(1, 1, 1)
    draw_frame(ax, frame, trace)
    texts = [t.get_text() for t in ax.texts]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [label for _, label in LEGEND]
    assert "standing" in texts and any(t.startswith("COLLISION: ") and t.endswith("with b") for t in texts)
    rgb = frame_rgb(frame, trace).astype(int)
    orange = (np.abs(rgb - 255 * np.array(to_rgb(BRAKING_COLOR))).sum(-1) < 30).sum()
    assert rgb.shape[1] >= 1000 and orange > 50  # legible width; the braking car (and its legend patch) drawn
