"""The worst-case safety layer in the env (``algo.shield=rss``): the factory wires its two halves, the lane-change
gap check masks an unsafe side, and on SUMO's braking scenario (the event at its random times) a policy that asks
for full throttle all the time never runs into a car ahead under the layer, while it does without it."""

from __future__ import annotations

import torch
from testkit import compose_job
from torchrl.envs import TransformedEnv

from kddrl_trl import keys as K
from kddrl_trl.envs import FakeHighwayEnv, SumoHighwayEnv
from kddrl_trl.eval import EpisodeTracker
from kddrl_trl.physics.rss import RSSParams, lane_safe
from kddrl_trl.transforms import RSSLaneMask, SafetyShield


def test_the_factory_wires_the_gap_check_and_the_bound_for_every_algo():
    from kddrl_trl.factories import make_transforms
    from kddrl_trl.transforms import DecisionClock

    job = compose_job("algo=d3qn_td3", "algo.shield=rss")
    kinds = [type(t) for t in make_transforms(job.algo, 0, job.env.highway()).transforms]
    assert kinds == [RSSLaneMask, DecisionClock, SafetyShield]
    rule = compose_job("algo=idm_mobil", "algo.shield=rss")
    assert [type(t) for t in make_transforms(rule.algo, 0, rule.env.highway()).transforms] == [
        RSSLaneMask,
        SafetyShield,
    ]


def test_the_gap_check_masks_the_side_whose_new_follower_is_too_close():
    ego = torch.tensor([[100.0, 30.0, 0.0]])
    kin = torch.zeros(1, 6, 3)
    kin[0, K.SLOT["d"]] = torch.tensor([97.0, 35.0, 0.0])  # left follower 2 m behind, faster: unsafe
    kin[0, K.SLOT["c"]] = torch.tensor([200.0, 30.0, 0.0])  # right leader 95 m ahead: safe
    mask = torch.zeros(1, 6, dtype=torch.bool)
    mask[0, K.SLOT["d"]] = mask[0, K.SLOT["c"]] = True
    assert lane_safe(ego, kin, mask, RSSParams(), 5.0).tolist() == [[False, True, True]]


def _full_throttle(td):
    """Keep the lane, ask for +5 m/s² always."""
    td.set(K.LC_ACTION, torch.nn.functional.one_hot(torch.full(td.shape, K.KEEP), 3).float())
    td.set(K.CF_ACTION, torch.full((*td.shape, 1), 5.0))
    return td


def _episodes(env, steps: int) -> list[dict]:
    td, frames = env.reset(), []
    for _ in range(steps):
        full, td = env.step_and_maybe_reset(_full_throttle(td))
        frames.append(full)
    return EpisodeTracker()(torch.stack(frames, 1))


def test_full_throttle_under_the_layer_never_runs_into_a_car_ahead_on_braking():
    runs = {}
    for name, steps, wrap in (("safe", 1200, True), ("wild", 400, False)):  # libsumo: one simulation at a time
        env = SumoHighwayEnv("braking", num_roads=4, seed=3)
        env = TransformedEnv(env, SafetyShield("rss")) if wrap else env
        try:
            runs[name] = _episodes(env, steps)
        finally:
            env.close()
    safe, wild = runs["safe"], runs["wild"]
    assert len(safe) >= 8
    ahead = [e for e in safe if e["collision"] and e["collision_with"] in ("a", "b", "c")]
    assert ahead == [], [(e["collision_with"], e["crash_speed"]) for e in ahead]
    assert any(e["collision"] and e["collision_with"] == "b" for e in wild)  # without it the same policy crashes
    assert sum(e["shield_interventions"] for e in safe) > 0
    # RSS's blame: under the layer the ego keeps its proper response, so no collision is its fault; without it the
    # same policy's crashes into the braking car are
    assert all(e["collision_fault"] in ("other", "unknown") for e in safe if e["collision"])
    assert any(e["collision_fault"] == "ego" for e in wild if e["collision_with"] == "b")


def test_the_correction_signal_costs_the_reward_its_correction():
    """``penalty`` per m/s²: each frame's car-following reward loses penalty x (a_agent - a_exec); the actions, the
    executed commands and every other entry stay those of the shield without it."""
    rolls = {}
    for penalty in (0.0, 0.1):
        env = TransformedEnv(
            FakeHighwayEnv(num_roads=4, seed=0, ego_start="window"), SafetyShield("rss", penalty=penalty)
        )
        rolls[penalty] = env.rollout(60, _full_throttle, break_when_any_done=False)[:, :-1]
    plain, told = rolls[0.0], rolls[0.1]
    executed = plain[K.CF_ACTION][..., 0]
    flag = plain["next", *K.CF_SHIELD][..., 0]
    assert flag.any() and torch.equal(executed, told[K.CF_ACTION][..., 0])
    cost = plain["next", *K.CF_REWARD][..., 0] - told["next", *K.CF_REWARD][..., 0]
    assert torch.allclose(cost, 0.1 * (5.0 - executed), atol=1e-5)
    assert (cost[~flag] == 0).all() and (cost[flag] > 0).all()
    assert torch.equal(plain["next", *K.LC_REWARD], told["next", *K.LC_REWARD])


def test_record_command_keeps_the_agents_command_in_the_frame_and_executes_the_bound():
    """``record="command"`` (``algo.shield_buffer=command``): the env executes the same bounded commands, the frame
    (what buffer L stores) keeps the agent's +5 m/s², and the flag and the penalty are those of the default."""
    from torchrl.collectors import Collector

    rolls = {}
    for record in ("executed", "command"):
        env = TransformedEnv(
            FakeHighwayEnv(num_roads=4, seed=0, ego_start="window"), SafetyShield("rss", penalty=0.1, record=record)
        )
        collector = Collector(env, _full_throttle, frames_per_batch=160, total_frames=160, trust_policy=True)
        rolls[record] = next(iter(collector))
        collector.shutdown()
    executed, command = rolls["executed"], rolls["command"]
    flag = executed["next", *K.CF_SHIELD][..., 0]
    assert flag.any() and torch.equal(flag, command["next", *K.CF_SHIELD][..., 0])
    assert (command[K.CF_ACTION][..., 0] == 5.0).all() and (executed[K.CF_ACTION][..., 0][flag] < 5.0).all()
    assert torch.equal(executed["next", *K.EGO_ACCEL], command["next", *K.EGO_ACCEL])  # the same driving
    assert torch.equal(executed["next", *K.CF_REWARD], command["next", *K.CF_REWARD])
