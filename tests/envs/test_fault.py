"""The collision's fault class (``kddrl_trl.envs.fault``, ``collision_fault`` of the episode records): one crash of
each class, the breaches of the proper response on hand-made states, and the held breach across batches."""

from __future__ import annotations

import torch
from testkit import command, rollout

from kddrl_trl import keys as K
from kddrl_trl.envs import FakeHighwayEnv
from kddrl_trl.envs.episode_metrics import FAULT_KEYS
from kddrl_trl.envs.fault import breaches, fault
from kddrl_trl.eval import EpisodeTracker
from kddrl_trl.physics.rss import RSSParams


def crashes(episodes) -> set[tuple[str, str, str]]:
    return {(e["collision_kind"], e["collision_with"], e["collision_fault"]) for e in episodes if e["collision"]}


def test_one_crash_of_each_class():
    """A car braking hard in dense traffic is hit by its follower: the follower's fault. A car at full throttle
    runs into its leader: the ego's. Without the observation the action was taken in: unknown."""
    env = FakeHighwayEnv(num_roads=4, seed=0, flow_vph=6000.0)
    braking = EpisodeTracker()(rollout(env, lambda td: td.update(command(env, K.KEEP, -5.0)), 200))
    assert crashes(braking) == {("hit_from_behind", "e", "other")}
    env = FakeHighwayEnv(num_roads=4, seed=0, flow_vph=6000.0)
    frames = rollout(env, lambda td: td.update(command(env, K.KEEP, 5.0)), 200)
    assert ("rear_end", "b", "ego") in crashes(EpisodeTracker()(frames))
    blind = EpisodeTracker()(frames.exclude(*FAULT_KEYS))
    assert {e["collision_fault"] for e in blind if e["collision"]} == {"unknown"}
    assert all(e["collision_fault"] == "" for e in blind if not e["collision"])


def test_the_class_does_not_depend_on_how_the_frames_are_batched():
    env = FakeHighwayEnv(num_roads=4, seed=1, flow_vph=6000.0)
    frames = rollout(env, lambda td: td.update(command(env, K.LEFT, 1.0)), 300)
    whole = EpisodeTracker()(frames)
    tracker, chunked = EpisodeTracker(), []
    for part in frames.split([7, 93, 1, 199], dim=1):
        chunked += tracker(part)
    assert [e["collision_fault"] for e in chunked] == [e["collision_fault"] for e in whole]
    assert {e["collision_fault"] for e in whole if e["collision"]} >= {"ego"}


def state(v: float, leader: tuple[float, float] | None = None, follower_left: tuple[float, float] | None = None):
    """One observation: the ego at y = 0 and speed ``v``; a leader b at (gap, speed), a follower d in the left lane
    at (distance behind, speed); vehicles 5 m long."""
    ego = torch.tensor([[0.0, v, 0.0]])
    kin, mask = torch.zeros(1, 6, 3), torch.zeros(1, 6, dtype=torch.bool)
    if leader is not None:
        kin[0, K.SLOT["b"]] = torch.tensor([leader[0] + 5.0, leader[1], 0.0])
        mask[0, K.SLOT["b"]] = True
    if follower_left is not None:
        kin[0, K.SLOT["d"]] = torch.tensor([-follower_left[0] - 5.0, follower_left[1], 0.0])
        mask[0, K.SLOT["d"]] = True
    return ego, kin, mask


def breach(obs, accel: float, started: bool = False, cmd: int = K.KEEP, speed_after: float | None = None):
    ego, kin, mask = obs
    return breaches(
        ego,
        kin,
        mask,
        torch.zeros(1, 1, dtype=torch.bool),
        torch.tensor([accel]),
        torch.tensor([float(ego[0, 1]) + 0.1 * accel if speed_after is None else speed_after]),
        torch.tensor([started]),
        torch.tensor([cmd]),
        torch.tensor([started]),
        RSSParams(),
        5.0,
        -5.0,
    )


def test_the_proper_response_on_hand_made_states():
    far = state(30.0, leader=(200.0, 30.0))
    assert not breach(far, 5.0)["lon"] and breach(far, 5.0)["lon_clear"]
    close = state(30.0, leader=(20.0, 0.0))  # no command keeps the safe distance: only the hardest braking is proper
    assert breach(close, 0.0)["lon"] and not breach(close, -5.0)["lon"]
    assert not breach(close, -5.0)["lon_clear"]  # still in danger: a held breach stays held
    standing = state(0.0, leader=(0.5, 0.0))
    assert not breach(standing, 0.0, speed_after=0.0)["lon"]  # a car that stands can brake no more
    cut_in = state(30.0, leader=(200.0, 30.0), follower_left=(3.0, 30.0))
    assert breach(cut_in, 0.0, started=True, cmd=K.LEFT)["lat"]
    assert not breach(cut_in, 0.0, started=True, cmd=K.RIGHT)["lat"]  # the right lane is empty
    wide = state(30.0, leader=(200.0, 30.0), follower_left=(80.0, 30.0))
    assert not breach(wide, 0.0, started=True, cmd=K.LEFT)["lat"]


def test_the_class_from_the_slot_and_the_held_breaches():
    assert fault(K.SLOT["b"], lon_held=True, lat_held=False) == "ego"
    assert fault(K.SLOT["b"], lon_held=False, lat_held=False) == "other"
    assert fault(K.SLOT["e"], lon_held=True, lat_held=False) == "other"  # the follower answers for the distance
    assert fault(K.SLOT["d"], lon_held=False, lat_held=True) == "ego"  # it cut in
    assert fault(-1, lon_held=True, lat_held=False) == "unknown"
