"""Multi-timescale collection: decision clock, two-clock policy, macro-transitions of buffer H."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModuleBase
from testkit import compose_job
from torchrl.envs import Compose, TransformedEnv
from torchrl.envs.utils import check_env_specs

from kddrl_trl import keys as K
from kddrl_trl.collectors import MacroTransitionWriter, MultiRatePolicy, MultiTimescaleCollector
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.transforms import DecisionClock

# ------------------------------------------------------------------------------------------ helpers


def episode_frames(lengths_per_row: list[list[int]], period: int):
    """Frames [B, T] of rows running back-to-back episodes of the given lengths, as an env + DecisionClock
    write them: 'obs' = a global frame id, decide on t_in_episode % period == 0, reward = frame id."""
    rows = []
    for r, lengths in enumerate(lengths_per_row):
        frames = []
        for e, n in enumerate(lengths):
            for t in range(n):
                fid = 1000 * r + 100 * e + t
                last = t == n - 1
                frames.append(
                    {
                        "obs": fid,
                        "decide": t % period == 0,
                        "next_obs": fid + 1,
                        "next_decide": (t + 1) % period == 0 and not last,
                        "reward": float(fid),
                        "done": last,
                        "start": 100 * e,
                    }
                )
        rows.append(frames)
    t_len = min(len(f) for f in rows)
    rows = [f[:t_len] for f in rows]

    def col(name, dtype=torch.float32):
        return torch.tensor([[f[name] for f in row] for row in rows], dtype=dtype).unsqueeze(-1)

    b = len(rows)
    td = TensorDict(
        {
            "obs": col("obs"),
            K.LC_DECIDE: col("decide", torch.bool),
            K.LC_ACTION: torch.nn.functional.one_hot(col("obs", torch.long).squeeze(-1) % 3, 3).float(),
            "collector": {"traj_ids": torch.zeros(b, t_len, dtype=torch.long)},
            "next": {
                "obs": col("next_obs"),
                K.LC_DECIDE: col("next_decide", torch.bool),
                K.LC_REWARD: col("reward"),
                "done": col("done", torch.bool),
                "terminated": col("done", torch.bool),
                "truncated": torch.zeros(b, t_len, 1, dtype=torch.bool),
            },
        },
        batch_size=[b, t_len],
    )
    return td, rows


def reference_macros(rows, period: int) -> list[tuple]:
    """(start obs, next obs, reward sum, frames, done) computed naively, episode by episode."""
    out = []
    for frames in rows:
        i = 0
        while i < len(frames):
            f = frames[i]
            assert f["decide"]
            j = i
            while not (frames[j]["next_decide"] or frames[j]["done"]):
                j += 1
                if j == len(frames):
                    break
            if j == len(frames):
                break  # interval still open at the end of the data
            out.append(
                (
                    f["obs"],
                    frames[j]["next_obs"],
                    sum(frames[k]["reward"] for k in range(i, j + 1)),
                    j - i + 1,
                    frames[j]["done"],
                )
            )
            i = j + 1
    return sorted(out)


def as_tuples(macros) -> list[tuple]:
    return sorted(
        zip(
            macros["obs"].squeeze(-1).tolist(),
            macros["next", "obs"].squeeze(-1).tolist(),
            macros["next", K.LC_REWARD].squeeze(-1).tolist(),
            macros["next", K.LC_MACRO_FRAMES].squeeze(-1).tolist(),
            macros["next", "done"].squeeze(-1).tolist(),
        )
    )


# --------------------------------------------------------------------------------- macro writer


def test_macro_transition_by_hand():
    # one row, period 3, an episode of 5 frames (rewards 0..4) then one of 4: decisions at frames 0 and 3 of
    # each; the second interval of the first episode is closed by its termination after 2 frames
    td, _ = episode_frames([[5, 4]], period=3)
    macros = MacroTransitionWriter()(td)
    assert macros.batch_size == (4,)
    first, second = macros[0], macros[1]
    assert first["obs"].item() == 0 and first["next", "obs"].item() == 3  # next state = next decision
    assert first["next", K.LC_REWARD].item() == 0 + 1 + 2  # undiscounted sum
    assert first["next", K.LC_MACRO_FRAMES].item() == 3 and not first["next", "done"].item()
    assert second["obs"].item() == 3 and second["next", "obs"].item() == 5  # the terminal frame
    assert second["next", K.LC_REWARD].item() == 3 + 4 and second["next", "done"].item()
    assert second["next", K.LC_MACRO_FRAMES].item() == 2
    assert torch.equal(first[K.LC_ACTION], td[0, 0][K.LC_ACTION])  # action taken at the decision
    assert "collector" not in macros.keys()


@pytest.mark.parametrize("chunk", [1, 2, 4, 7, 50])
def test_macro_transitions_match_reference_across_batches_and_partial_resets(chunk):
    # three rows with episodes of different lengths: resets happen at different times in each row, and the
    # batches cut intervals at arbitrary points
    period = 4
    td, rows = episode_frames([[9, 3, 14, 6, 10], [1, 2, 17, 5, 20], [30, 4, 4, 4, 5]], period)
    writer = MacroTransitionWriter()
    got = []
    for s in range(0, td.shape[1], chunk):
        out = writer(td[:, s : s + chunk])
        if out is not None:
            got += as_tuples(out)
    assert sorted(got) == reference_macros(rows, period)
    assert writer.dropped_frames == 0


def test_decision_reading_counts_the_efficiency_term_once_per_decision():
    """F5, ``algo.lc_reward=decision`` (§III.G, "calculated at each 2-second decision step"): sum(r - e) + mean(e) over
    the interval, e the per-frame efficiency term; the same across batch cuts."""

    def with_efficiency(td):  # the env's efficiency term e = 0.5 obs of each frame, under "next"
        td["next", *K.EFFICIENCY_TERM] = 0.5 * td["next", "obs"][..., :1]
        return td

    td = with_efficiency(episode_frames([[5, 4]], period=3)[0])
    with pytest.raises(KeyError, match="efficiency term"):
        MacroTransitionWriter(efficiency_key=("reward_terms", "absent"))(td)
    macros = MacroTransitionWriter(efficiency_key=K.EFFICIENCY_TERM)(td)
    # frames 0-2: r = 0, 1, 2 and e = 0.5, 1, 1.5 -> 3 - 3 + 1; frames 3-4 (terminal): r = 3, 4, e = 2, 2.5
    assert macros[0]["next", K.LC_REWARD].item() == pytest.approx(0.0 + 1.0)
    assert macros[1]["next", K.LC_REWARD].item() == pytest.approx(7.0 - 4.5 + 2.25)
    td = with_efficiency(episode_frames([[9, 3, 14], [1, 2, 17], [30, 4, 4]], period=4)[0])
    whole = MacroTransitionWriter(efficiency_key=K.EFFICIENCY_TERM)(td)
    writer, parts = MacroTransitionWriter(efficiency_key=K.EFFICIENCY_TERM), []
    for s in range(td.shape[1]):
        out = writer(td[:, s : s + 1])
        if out is not None:
            parts.append(out)
    parts = torch.cat(parts)
    key = lambda m: float(m["obs"])  # noqa: E731
    got = sorted((key(m), round(float(m["next", K.LC_REWARD]), 4)) for m in parts)
    assert got == sorted((key(m), round(float(m["next", K.LC_REWARD]), 4)) for m in whole)


def test_macro_writer_errors_name_the_missing_key():
    td, _ = episode_frames([[5]], period=2)
    with pytest.raises(KeyError, match="decide"):
        MacroTransitionWriter()(td.exclude(K.LC_DECIDE))
    with pytest.raises(ValueError, match=r"\[B, T\]"):
        MacroTransitionWriter()(td[0])


def test_macro_writer_counts_frames_before_the_first_decision():
    td, _ = episode_frames([[9]], period=4)
    writer = MacroTransitionWriter()
    writer(td[:, 1:])  # starts mid-interval: frames 1..3 cannot form a transition
    assert writer.dropped_frames == 3


# ------------------------------------------------------------------------------------ clock + policy


class Recorder(TensorDictModuleBase):
    """Lane-change 'policy' that records how many rows it saw and answers LEFT, or a fixed CF policy."""

    def __init__(self, in_keys, out_key, value):
        super().__init__()
        self.in_keys, self.out_keys, self.value, self.calls = list(in_keys), [out_key], value, []

    def forward(self, td):
        self.calls.append(td.batch_size.numel())
        td.set(self.out_keys[0], self.value.expand(*td.batch_size, -1).clone())
        return td


def lc_recorder(action=K.LEFT):
    return Recorder([K.EGO_STATE], K.LC_ACTION, torch.nn.functional.one_hot(torch.tensor(action), 3).float())


def cf_recorder():
    return Recorder([K.EGO_STATE, K.LC_ACTION], K.CF_ACTION, torch.tensor([0.5]))


def clocked_env(k=3, period=5, **kw):
    return TransformedEnv(FakeHighwayEnv(num_roads=k, seed=1, **kw), Compose(DecisionClock(period)))


def test_decision_clock_specs_and_partial_reset():
    env = clocked_env(k=2, period=3)
    check_env_specs(env)
    td = env.reset()
    assert td[K.LC_DECIDE].all() and (td[K.LC_HELD].argmax(-1) == K.KEEP).all()
    decides = []
    for t in range(7):
        td[K.LC_ACTION] = torch.nn.functional.one_hot(torch.tensor([t % 3, 2]), 3).float()
        td[K.CF_ACTION] = torch.zeros(2, 1)
        held_sent = td[K.LC_ACTION].clone()
        td = env.step(td)["next"]
        decides.append(td[K.LC_DECIDE][:, 0].tolist())
        assert torch.equal(td[K.LC_HELD], held_sent)  # the action executed in the last frame
    assert [d[0] for d in decides] == [False, False, True, False, False, True, False]  # frames 1..7
    # partial reset of road 1 only: its clock restarts, road 0 keeps counting (frame 8 -> not a decision)
    td.set("_reset", torch.tensor([[False], [True]]))
    td[K.LC_ACTION] = torch.zeros(2, 3)
    td = env.reset(td)
    assert td[K.LC_DECIDE][:, 0].tolist() == [False, True]
    assert td[K.LC_HELD][1].argmax().item() == K.KEEP


def test_decision_clock_rejects_bad_period():
    for bad in (0, -2, 1.5, True):
        with pytest.raises(ValueError, match="lc_period"):
            DecisionClock(bad)


def test_lane_change_policy_acts_only_on_decision_frames_and_its_action_is_held():
    period, k = 5, 3
    env = clocked_env(k=k, period=period)
    lc, cf = lc_recorder(K.LEFT), cf_recorder()
    policy = MultiRatePolicy(lc, cf)
    roll = env.rollout(12, policy, break_when_any_done=False)
    decide = roll[K.LC_DECIDE][..., 0]
    # the lane-change policy saw exactly the decision rows, frame by frame
    assert lc.calls == [int(d.sum()) for d in decide.T if d.any()]
    assert sum(lc.calls) == int(decide.sum())
    # on non-decision frames the action is the held one (the action of the previous frame)
    actions = roll[K.LC_ACTION]
    assert torch.equal(actions[:, 1:][~decide[:, 1:]], roll[K.LC_HELD][:, 1:][~decide[:, 1:]])
    assert (roll[K.CF_ACTION] == 0.5).all() and len(cf.calls) == 12
    # no intermediate key of the policies leaks into the data
    assert K.EMBED_S_E not in roll.keys(True) and K.LC_OBS not in roll.keys(True)


def test_collector_fills_both_buffers_with_consistent_macro_steps():
    from kddrl_trl.training import make_buffer

    period, k = 4, 3
    env = clocked_env(k=k, period=period, ego_start="window")  # distinct start positions: y identifies a frame
    policy = MultiRatePolicy(lc_recorder(K.KEEP), cf_recorder())
    rb_l, rb_h = make_buffer(10_000, 8, 0), make_buffer(10_000, 8, 0)
    mtc = MultiTimescaleCollector.from_env(env, policy, frames_per_env=7, frame_buffer=rb_l, macro_buffer=rb_h)
    batches = []
    for i, batch in enumerate(mtc):
        batches.append(batch)
        if i == 5:
            break
    mtc.shutdown()
    frames = torch.cat([b.frames for b in batches], dim=1)  # [K, 42]
    assert len(rb_l) == frames.numel()
    macros = torch.cat([b.macros for b in batches if b.macros is not None])
    assert len(rb_h) == macros.numel()
    # every macro-transition: starts on a decision frame, next state = the frame after its last frame
    y = frames[K.EGO_STATE][..., 0]
    ny = frames["next", *K.EGO_STATE][..., 0]
    for m in macros:
        r, c = (y == m[K.EGO_STATE][0]).nonzero()[0].tolist()
        n = int(m["next", K.LC_MACRO_FRAMES])
        assert frames[r, c][K.LC_DECIDE].item()
        assert ny[r, c + n - 1] == m["next", *K.EGO_STATE][0]
        assert m["next", K.LC_REWARD].item() == pytest.approx(
            frames["next", *K.LC_REWARD][r, c : c + n].sum().item(), rel=1e-5, abs=1e-4
        )
        assert n == period or m["next", "done"].item()


def test_sumo_training_env_specs():
    pytest.importorskip("libsumo")
    from kddrl_trl.factories import make_env

    job = compose_job("env.num_roads=2")
    assert job.algo.lc_period == 20 and job.algo.transforms.enabled
    env = make_env(job.env, job.algo, seed=0, compile=False)
    try:
        check_env_specs(env)
        td = env.reset()
        for key in (K.LC_DECIDE, K.LC_HELD, K.PRED_KEY_GAPS, K.PRIOR_P_MOBIL, K.PRIOR_P_LCGAN):
            assert key in td.keys(True)
    finally:
        env.close()


def _fake_clocked_env():
    return clocked_env(k=2, period=4)


def _recording_policy():
    return MultiRatePolicy(lc_recorder(K.KEEP), cf_recorder())


def test_works_with_multisync_collector_workers():
    from torchrl.collectors import MultiSyncCollector

    collector = MultiSyncCollector(
        [_fake_clocked_env, _fake_clocked_env],
        policy_factory=_recording_policy,
        frames_per_batch=2 * 2 * 10,
        total_frames=-1,
        cat_results=0,
    )
    writer = MacroTransitionWriter()
    mtc = MultiTimescaleCollector(collector, writer=writer)
    try:
        got = []
        for i, batch in enumerate(mtc):
            assert batch.frames.batch_dims == 2 and batch.frames.shape[0] == 4  # 2 workers x 2 roads
            if batch.macros is not None:
                got.append(batch.macros)
            if i == 3:
                break
    finally:
        mtc.shutdown()
    macros = torch.cat(got)
    n = macros["next", K.LC_MACRO_FRAMES].squeeze(-1)
    assert ((n == 4) | macros["next", "done"].squeeze(-1)).all() and writer.dropped_frames == 0
