"""Real-SUMO tests of the batched highway environment (paper §III.G, §IV.A-D, Table A.1)."""

from __future__ import annotations

import logging
from functools import partial

import libsumo
import numpy as np
import pytest
import torch
from testkit import command
from torchrl.envs import Compose, ParallelEnv, RewardSum, StepCounter, TransformedEnv
from torchrl.envs.utils import check_env_specs, step_mdp

from kddrl_trl import keys as K
from kddrl_trl.baselines import IDMMobilPolicy, RandomDrivingPolicy
from kddrl_trl.envs import SumoHighwayEnv, make_config
from kddrl_trl.envs.sim import HighwaySim
from kddrl_trl.eval import EpisodeTracker

pytestmark = pytest.mark.usefixtures("no_sumo_open")


def rollout(env, policy, steps):
    """Step with auto-reset of done roads; return the list of per-step tensordicts (with "next")."""
    td, out = env.reset(), []
    for _ in range(steps):
        td = policy(td)
        full, td = env.step_and_maybe_reset(td)
        out.append(full)
    return out


@pytest.mark.parametrize("scenario", ["baseline", "congested", "braking"])
@pytest.mark.parametrize("num_roads", [1, 8])
def test_check_env_specs(scenario, num_roads):
    env = SumoHighwayEnv(scenario, num_roads=num_roads, seed=1)
    try:
        check_env_specs(env, seed=None)
        tenv = TransformedEnv(env, Compose(StepCounter(), RewardSum(in_keys=env.reward_keys)))
        check_env_specs(tenv, seed=None)
        td = tenv.rollout(30, IDMMobilPolicy(), break_when_any_done=False)
        assert td["next", "step_count"].max() >= 1
        assert torch.isfinite(td["next", "lc", "episode_reward"]).all()
    finally:
        env.close()


def test_neighbour_slots_are_on_the_right_sides():
    """a/d are in the lane to the left (Δx ≈ +w), c/f to the right (Δx ≈ -w), b/e in the ego's lane."""
    env = SumoHighwayEnv("congested", num_roads=8, seed=3)
    try:
        steps = rollout(env, IDMMobilPolicy(), 60)
        w = env.config.lane_width
        seen = np.zeros(6, int)
        for full in steps:
            steady = ~full[K.LC_ACTIVE].squeeze(-1) & (full[K.EGO_STATE][:, 2] == 0)
            rel, mask = full[K.NEIGHBORS_REL][steady], full[K.NEIGHBORS_MASK][steady]
            for slot, dx in zip(range(6), (w, 0.0, -w, w, 0.0, -w)):
                present = mask[:, slot]
                seen[slot] += int(present.sum())
                # neighbours that are themselves changing lanes sit up to one lane width off
                assert ((rel[present, slot, 0] - dx).abs() <= w + 1e-3).all(), slot
                sign = 1 if slot < 3 else -1
                assert (sign * rel[present, slot, 1] >= -env.config.vehicle_length).all()
        assert (seen > 0).all(), seen
    finally:
        env.close()


def test_driving_into_the_leader_collides():
    env = SumoHighwayEnv("congested", num_roads=8, seed=0)
    try:
        td = env.reset()
        hits, frames = [], []
        for _ in range(400):
            full, td = env.step_and_maybe_reset(td.update(command(env, K.KEEP, 5.0)))
            frames.append(full)
            hit = full["next", "collision"].squeeze(-1)
            if hit.any():
                hits.append(full[hit])
        assert hits, "full throttle in congested traffic never hit a leader"
        for frame in hits:
            assert frame["next", "terminated"].all() and frame["next", "done"].all()
            assert (frame["next", "lc", "reward"] <= -99).all() and (frame["next", "cf", "reward"] <= -99).all()
            assert (frame["next", K.OUTCOME] == K.COLLIDED).all()
            assert (frame["next", K.COLLISION_KIND] == K.REAR_END).all()  # no lane change: into the leader
        collided = [e for e in EpisodeTracker()(torch.stack(frames, 1)) if e["collision"]]
        assert len(collided) == env.stats["collisions"] == sum(len(h) for h in hits)
        assert all(e["outcome"] == "collision" and e["collision_kind"] == "rear_end" for e in collided)
        assert all(e["collision_with"] == "b" for e in collided)  # the current leader
    finally:
        env.close()


def test_unsafe_lane_change_into_occupied_gap_collides():
    env = SumoHighwayEnv("baseline", num_roads=1, seed=0, ego_lane=1)
    try:
        env.reset()
        ego = env.sim.ego[0]
        other = next(v for v in env.sim.road_vehicles(0) if v != ego)
        y_ego = env.sim.longitudinal(ego)
        for v in env.sim.road_vehicles(0):  # clear lane 2 around the ego, so only `other` is there
            if (
                v not in (ego, other)
                and libsumo.vehicle.getLaneIndex(v) == 2
                and abs(env.sim.longitudinal(v) - y_ego) < 60
            ):
                libsumo.vehicle.remove(v)
        edge, pos = libsumo.vehicle.getRoadID(ego), libsumo.vehicle.getLanePosition(ego)
        libsumo.vehicle.moveTo(other, f"{edge}_2", pos)  # put a car right beside the ego, on its left
        libsumo.vehicle.setSpeed(other, libsumo.vehicle.getSpeed(ego))
        td = env.step(command(env, K.LEFT, 0.0))
        collided = bool(td["next", "collision"].item())
        for _ in range(20):
            if collided:
                break
            td = env.step(step_mdp(td).update(command(env, K.KEEP, 0.0)))
            collided = bool(td["next", "collision"].item())
        assert collided and env.stats["collisions"] == 1
        assert td["next", K.COLLISION_KIND].item() == K.SIDE_CONTACT
        assert K.NEIGHBOR_SLOTS[td["next", K.COLLISION_SLOT].item()] in ("a", "d")  # the car on the left
    finally:
        env.close()


def test_lane_change_lasts_20_frames_and_masks_commands():
    env = SumoHighwayEnv("baseline", num_roads=1, seed=0, flow_vph=0.0, ego_lane=1)  # empty road
    try:
        td = env.reset()
        assert env.stats["insert_steps"] > 0  # an empty road needs an inserted ego
        assert td[K.LC_ACTION_MASK].tolist() == [[True, True, True]]
        obs, active, lanes, vx, started, offset = td, [], [], [], 0, []
        assert abs(td[K.EGO_LANE_OFFSET].item()) < 1e-3  # centred in its lane before the manoeuvre
        for k in range(26):  # LEFT commanded at the first frame and then held: ignored once started
            if k > 0:
                expected = [False, True, False] if obs[K.LC_ACTIVE].item() else [False, True, True]
                assert obs[K.LC_ACTION_MASK][0].tolist() == expected
            full = env.step(obs.update(command(env, K.LEFT)))
            assert full["next", "lc", "started"].item() == (k == 0)
            started += int(full["next", "lc", "started"].item())
            obs = step_mdp(full)
            active.append(obs[K.LC_ACTIVE].item())
            lanes.append(obs[K.EGO_LANE].item())
            vx.append(obs[K.EGO_STATE][0, 2].item())
            offset.append(obs[K.EGO_LANE_OFFSET].item())
        # the ego moves sideways at 3.2 m / 2 s during exactly 20 frames; the manoeuvre is complete (and a
        # new command accepted) in the observation after the 20th frame
        assert vx[:20] == pytest.approx([3.2 / 2.0] * 20) and vx[20:] == [0.0] * 6
        assert active == [True] * 19 + [False] * 7
        assert lanes[0] == 1 and lanes[-1] == 2
        assert started == 1  # the held command did not start a second manoeuvre
        # the offset from the lane centre: +0.16 m per frame in lane 1, then from the centre of lane 2 (-1.6 m at
        # the switch), back to 0 at the end
        moved = [o + 3.2 * (lane - 1) for o, lane in zip(offset, lanes)]
        assert moved == pytest.approx([0.16 * min(k + 1, 20) for k in range(26)], abs=1e-3)
        assert all(-1.6 - 1e-3 <= o <= 1.6 + 1e-3 for o in offset)
    finally:
        env.close()


def test_speed_follows_commanded_acceleration():
    env = SumoHighwayEnv("baseline", num_roads=1, seed=0, flow_vph=0.0)
    try:
        td = env.reset()
        v = td[K.EGO_STATE][0, 1].item()
        accels = [2.0, 5.0, 7.5, -1.0, 0.0] + [-5.0] * 120
        for a in accels:
            td = env.step(td.update(command(env, K.KEEP, a)))
            expected = max(v + 0.1 * float(np.clip(a, -5, 5)), 0.0)
            got = td["next", K.EGO_STATE][0, 1].item()
            assert got == pytest.approx(expected, abs=1e-4)
            assert td["next", K.EGO_ACCEL].item() == pytest.approx((expected - v) / 0.1, abs=1e-3)
            v = got
            td = step_mdp(td)
        assert v == 0.0
    finally:
        env.close()


def test_braking_event_distance_and_durations():
    env = SumoHighwayEnv("braking", num_roads=8, seed=0)
    try:
        eps = EpisodeTracker()(torch.stack(rollout(env, IDMMobilPolicy(), 400), 1))
        assert len(eps) >= 8
        assert env.stats["braking_missed"] == 0
        for e in eps:
            assert 100.0 <= e["braking_distance"] <= 300.0
        resumed = [e for e in eps if "braking_resume_frame" in e]
        assert resumed, "no braking vehicle stood and resumed within an episode"
        for e in resumed:
            assert e["braking_resume_frame"] - e["braking_stop_frame"] == 30  # 3 s standing
            # from ~30 m/s at 8 m/s² a stop takes about 4 s
            assert 10 <= e["braking_stop_frame"] - e["braking_start_frame"] <= 80
    finally:
        env.close()


def test_braking_episodes_record_the_onset_and_crashes_explain_themselves():
    """Every braking episode records the event's onset (gap, speeds, headway, time to collision); a crash episode
    records the ego's speed and commands, since when its lane command was held, and whether it hit the event's car;
    a clean episode leaves the crash fields empty. Roads 0-1 keep their lane at +3 m/s² (they crash), roads 2-3
    drive IDM+MOBIL."""
    from kddrl_trl.envs.episode_metrics import CRASH_FIELDS, ONSET_FIELDS

    env = SumoHighwayEnv("braking", num_roads=4, seed=0)
    rule = IDMMobilPolicy()

    def policy(td):
        td = rule(td)
        td[K.LC_ACTION][:2] = torch.tensor([0.0, 1.0, 0.0])
        td[K.CF_ACTION][:2] = 3.0
        return td

    try:
        eps = EpisodeTracker()(torch.stack(rollout(env, policy, 500), 1))
    finally:
        env.close()
    crashes = [e for e in eps if e["collision"]]
    clean = [e for e in eps if not e["collision"]]
    assert crashes and clean
    gassing = [e for e in crashes if e["road"] < 2]
    assert gassing and any(e["crash_with_event_car"] is True for e in gassing)
    assert any(e["collision_with"] == "b" for e in gassing)
    for e in crashes:
        assert all(
            e[name] != "" and not (isinstance(e[name], float) and np.isnan(e[name]))
            for name in CRASH_FIELDS
            if name not in ("crash_lane_change_frame", "crash_event_gap", "crash_event_speed")
            and not name.startswith("crash_other")
        ), e
        assert e["crash_lc_command"] in K.LC_ACTIONS and 1 <= e["crash_lc_command_frame"] <= e["frames"]
        assert isinstance(e["crash_with_event_car"], bool) and e["crash_speed"] >= 0
    for e in gassing:
        assert e["crash_cf_command"] == 3.0 and e["crash_lc_command"] == "keep" and e["crash_lc_command_frame"] == 1
        assert np.isnan(e["crash_lane_change_frame"])  # it never changed lane
        if e["crash_with_event_car"]:
            assert -1.0 < e["crash_event_gap"] < 5.0  # the last observation before the contact
        if e["collision_with"] == "b":  # it ran into its leader: just ahead, slower
            assert 0.0 < e["crash_other_dy"] < 15.0 and e["crash_other_speed"] < e["crash_speed"]
    for e in clean:
        assert all(e[name] == "" or np.isnan(e[name]) for name in CRASH_FIELDS), e
    for e in eps:
        assert all(np.isfinite(e[name]) or e[name] == np.inf for name in ONSET_FIELDS), e  # an event every episode
        assert e["onset_gap"] == pytest.approx(e["braking_distance"] - 5.0, abs=1e-3)  # 5 m cars: bumper to bumper
        assert e["onset_headway"] == pytest.approx(e["onset_gap"] / e["onset_speed"])
        closing = e["onset_speed"] - e["onset_leader_speed"]
        assert e["onset_ttc"] == (pytest.approx(e["onset_gap"] / closing) if closing > 0 else np.inf)
        assert e["event_car_lane_changes"] >= 0


@pytest.mark.parametrize("release", ["sumo", "programmed"])
def test_released_braking_car_resumes_as_its_release_says(release):
    """``programmed``: after standing, the car keeps its lane and gains at most ``resume_accel`` per second until
    it is back at the speed it had before braking, then SUMO drives it again. ``sumo``: SUMO drives it at once,
    and (IDM from a standstill) some car pulls away faster than ``resume_accel`` allows."""
    env = SumoHighwayEnv("braking", num_roads=8, seed=0, braking={"release": release, "resume_accel": 2.0})
    gains, lanes_changed, handed_back, td = [], 0, 0, env.reset()
    try:
        for _ in range(600):
            before = {  # the released cars this frame moves, and whether the ramp commands it
                br["vid"]: (
                    libsumo.vehicle.getSpeed(br["vid"]),
                    libsumo.vehicle.getLaneIndex(br["vid"]),
                    br.get("ramping"),
                )
                for br in env.sim.braking.state
                if br["phase"] == K.BRAKE_RESUMED and br.get("vid") in libsumo.vehicle.getIDList()
            }
            td = env.step_and_maybe_reset(IDMMobilPolicy()(td))[1]
            for vid, (v, lane, ramping) in before.items():
                if vid not in libsumo.vehicle.getIDList() or (release == "programmed" and not ramping):
                    handed_back += release == "programmed" and not ramping
                    continue
                gains.append((libsumo.vehicle.getSpeed(vid) - v) / env.sim.dt)
                lanes_changed += libsumo.vehicle.getLaneIndex(vid) != lane
    finally:
        env.close()
    assert len(gains) > 20
    if release == "programmed":
        assert max(gains) <= 2.0 + 1e-6
        assert lanes_changed == 0
        assert handed_back > 0, "no programmed release reached its earlier speed and was handed back"
    else:
        assert max(gains) > 3.0


def test_braking_release_is_checked():
    with pytest.raises(ValueError, match="braking.release"):
        make_config("braking", {"braking": {"release": "gentle"}})
    with pytest.raises(ValueError, match="braking.resume_accel"):
        make_config("braking", {"braking": {"release": "programmed", "resume_accel": 0.0}})


@pytest.mark.slow
def test_congested_carries_half_more_vehicles():
    counts = {}
    for scenario in ("baseline", "congested"):
        cfg = make_config(scenario, {"warmup_s": 600.0})
        sim = HighwaySim(cfg, 4, seed=0)
        counts[scenario] = len(sim.vehicle_params)
        sim.close()
    expected = 4 * 600 / 3600 * 2325
    assert counts["baseline"] == pytest.approx(expected, rel=0.1)
    assert counts["congested"] / counts["baseline"] == pytest.approx(1.5, abs=0.12)


def test_driver_classes_are_drawn_and_recorded():
    sim = HighwaySim(make_config("baseline", {"warmup_s": 300.0}), 4, seed=0)
    try:
        params = list(sim.vehicle_params.values())
        shares = {d.name: d.share for d in sim.cfg.drivers}
        for name, share in shares.items():
            mine = [p for p in params if p["driver"] == name]
            assert len(mine) / len(params) == pytest.approx(share, abs=0.07)
            cls = next(d for d in sim.cfg.drivers if d.name == name)
            v0 = np.array([p["v0"] for p in mine])
            assert abs(v0.mean() - cls.v0) < 0.02 * cls.v0 and np.all(np.abs(v0 / cls.v0 - 1) <= 2 * cls.spread + 1e-9)
            vid = next(
                v for v, p in sim.vehicle_params.items() if p["driver"] == name and v in libsumo.vehicle.getIDList()
            )
            assert libsumo.vehicle.getTau(vid) == pytest.approx(sim.vehicle_params[vid]["T"])
    finally:
        sim.close()


def test_parameters_of_vehicles_that_left_are_forgotten():
    """The per-vehicle parameters and release marks follow the vehicles in the simulation (plus those waiting
    for insertion): a long run does not keep one entry per vehicle ever inserted (the soak's memory growth)."""
    sim = HighwaySim(make_config("baseline", {"warmup_s": 300.0}), 2, seed=0)
    try:
        inserted = int(sim.arrivals.sum())
        on_road = set(libsumo.vehicle.getIDList())
        assert set(sim.vehicle_params) <= on_road | set(libsumo.simulation.getPendingVehicles())
        assert {v for v in on_road if v.startswith("h")} <= set(sim.vehicle_params)  # the present ones stay
        assert len(sim.vehicle_params) < 0.5 * inserted  # before: one entry per vehicle ever inserted
        sim._released |= {"gone.1", next(iter(on_road))}
        sim._forget_gone()
        assert sim._released == {next(iter(on_road))}
    finally:
        sim.close()


def _observations(seed, road2_random):
    env = SumoHighwayEnv("baseline", num_roads=3, seed=seed)
    rule, rand = IDMMobilPolicy(), RandomDrivingPolicy(generator=torch.Generator().manual_seed(5))
    try:

        def policy(td):
            td = rule(td)
            if road2_random:
                wild = rand(td[2:3].clone())
                td[2:3] = wild
            return td

        steps = torch.stack(rollout(env, policy, 250), 1)
        return steps["next"].exclude("lc", "cf"), EpisodeTracker()(steps)
    finally:
        env.close()


def test_roads_never_interact_and_seeds_reproduce():
    calm, calm_eps = _observations(0, road2_random=False)
    wild, wild_eps = _observations(0, road2_random=True)
    # roads 0 and 1 are bit-identical whatever road 2 does
    assert (calm[:2] == wild[:2]).all()

    # (``start`` numbers episodes in start order, as the old ``index`` did; ``index`` counts finishes on all roads)
    def mine(eps):
        return [{k: v for k, v in e.items() if k != "index"} for e in eps if e["road"] < 2]

    assert mine(calm_eps) == mine(wild_eps)
    assert not (calm[2] == wild[2]).all()
    again, _ = _observations(0, road2_random=False)
    assert (again == calm).all()  # same seed, same rollout
    other, _ = _observations(1, road2_random=False)
    assert not (other[K.EGO_STATE] == calm[K.EGO_STATE]).all()  # another seed, another rollout


def test_sumo_error_on_one_road_truncates_only_that_road(caplog):
    env = SumoHighwayEnv("baseline", num_roads=4, seed=0)
    try:
        td = env.reset()
        policy = IDMMobilPolicy()
        frames = []
        for _ in range(3):
            full, td = env.step_and_maybe_reset(policy(td))
            frames.append(full)
        libsumo.vehicle.remove(env.sim.ego[1])
        with caplog.at_level(logging.WARNING):
            full, td = env.step_and_maybe_reset(policy(td))
        frames.append(full)
        assert full["next", "truncated"][1].item() and not full["next", "terminated"][1].item()
        assert env.stats["sumo_errors"] == 1 and "lost ego" in caplog.text
        episodes = EpisodeTracker()(torch.stack(frames, 1))
        assert episodes[-1]["outcome"] == "lost" and episodes[-1]["road"] == 1
        for _ in range(50):  # everything runs on, road 1 with a new ego
            full, td = env.step_and_maybe_reset(policy(td))
        assert env.sim.ego[1] is not None and env.stats["sumo_errors"] == 1
    finally:
        env.close()


def test_close_releases_sumo_and_one_sim_per_process():
    env = SumoHighwayEnv("baseline", num_roads=2, seed=0)
    with pytest.raises(RuntimeError, match="one simulation per process"):
        SumoHighwayEnv("baseline", num_roads=2, seed=0)
    env.close()
    env.close()  # idempotent
    env2 = SumoHighwayEnv("braking", num_roads=2, seed=0)
    env2.rollout(5, IDMMobilPolicy())
    env2.close()


def test_set_seed_restarts_the_simulation():
    env = SumoHighwayEnv("baseline", num_roads=2, seed=0)
    try:
        env.set_seed(7)
        a = env.rollout(30, IDMMobilPolicy(), break_when_any_done=False)
        env.set_seed(7)
        b = env.rollout(30, IDMMobilPolicy(), break_when_any_done=False)
        assert (a[K.EGO_STATE] == b[K.EGO_STATE]).all()
    finally:
        env.close()


def test_parallel_env_runs_one_simulation_per_worker():
    env = ParallelEnv(2, partial(SumoHighwayEnv, "baseline", num_roads=2, seed=0), mp_start_method="fork")
    try:
        check_env_specs(env, seed=None)
        td = env.rollout(20, IDMMobilPolicy(), break_when_any_done=False)
        assert td.batch_size == torch.Size([2, 2, 20])
    finally:
        env.close()


def test_final_observation_is_of_the_last_frame():
    """The frame that ends an episode by leaving the section observes the ego beyond the section."""
    env = SumoHighwayEnv("baseline", num_roads=8, seed=2)
    try:
        steps = torch.stack(rollout(env, IDMMobilPolicy(), 250), 1)
        left = steps["next", "terminated"].squeeze(-1) & ~steps["next", "collision"].squeeze(-1)
        assert left.any()
        assert (steps["next", K.EGO_STATE][left][:, 0] > env.config.section_length).all()
        # and the frame before was still inside
        assert (steps[K.EGO_STATE][left][:, 0] <= env.config.section_length).all()
    finally:
        env.close()


def test_a_closed_env_says_so():
    env = SumoHighwayEnv("baseline", num_roads=1, seed=0)
    env.close()
    with pytest.raises(RuntimeError, match="closed"):
        env.reset()


def test_ego_starts_at_the_section_entry_by_default():
    """F3: ego_start=entry designates the steady vehicle nearest the study section's entry (the next to enter it);
    ego_start=window (the old behaviour) any one in the last pick_window metres; both start before the entry."""
    from kddrl_trl.envs.network import edge_ids

    starts = {}
    for mode in ("entry", "window"):
        env = SumoHighwayEnv(num_roads=8, seed=3, ego_start=mode)
        td = env.reset()
        y = td[K.EGO_STATE][:, 0]
        assert (y <= 0.0).all() and (y >= -env.config.pick_window - 1.0).all()
        if mode == "entry":
            cfg = env.config
            for r in range(8):
                ego = env.sim.ego[r]
                others = [
                    v
                    for v in libsumo.edge.getLastStepVehicleIDs(edge_ids(r)[0])
                    if v != ego
                    and libsumo.vehicle.getLateralSpeed(v) == 0.0
                    and libsumo.vehicle.getLanePosition(v) >= cfg.entry_length - cfg.pick_window
                ]
                assert all(libsumo.vehicle.getLanePosition(v) <= libsumo.vehicle.getLanePosition(ego) for v in others)
        starts[mode] = float(y.mean())
        env.close()
    assert starts["entry"] > starts["window"]


# ------------------------------------------------------------------- mixed-traffic curriculum (issue 14)
class _StubSim:
    """What :class:`~kddrl_trl.envs.braking.BrakingEvents` reads of a simulator at an episode start (no SUMO)."""

    def __init__(self, probability: float, seed: int, roads: int = 4):
        self.cfg = make_config("mixed", {"braking": {"probability": probability}})
        self.num_roads = roads
        self.rngs = [np.random.default_rng([seed, r]) for r in range(roads)]
        from kddrl_trl.envs.observe import observation_arrays

        self.obs = observation_arrays(self.cfg, roads)
        self.stats = {"braking_skipped": 0, "braking_missed": 0}


def _draws(probability: float, seed: int, episodes: int = 500) -> np.ndarray:
    from kddrl_trl.envs.braking import BrakingEvents

    sim = _StubSim(probability, seed)
    events = BrakingEvents(sim)
    out = np.zeros((episodes, sim.num_roads), bool)
    for e in range(episodes):
        for r in range(sim.num_roads):
            events.start(r)
            out[e, r] = events.state[r]["active"]
            events.end(r, recorded=False)
    assert sim.stats["braking_skipped"] == (~out).sum()
    return out


@pytest.mark.parametrize("p", [0.2, 0.5, 0.9])
def test_braking_event_fires_in_about_p_of_the_episodes_reproducibly(p):
    drawn = _draws(p, seed=3)
    assert abs(drawn.mean() - p) < 0.05, drawn.mean()  # 2000 episodes: sd of the share <= 0.012
    assert all(abs(drawn[:, r].mean() - p) < 0.1 for r in range(drawn.shape[1]))  # on every road
    assert np.array_equal(drawn, _draws(p, seed=3))  # the seed gives the same mix
    assert not np.array_equal(drawn, _draws(p, seed=4))


def test_probability_one_draws_what_the_braking_scenario_always_drew():
    """p = 1 (every run saved before the key) takes nothing extra from the road's stream: same targets as before."""
    from kddrl_trl.envs.braking import BrakingEvents

    sim = _StubSim(1.0, seed=0)
    events = BrakingEvents(sim)
    events.start(0)
    assert events.state[0]["target"] == np.random.default_rng([0, 0]).uniform(100.0, 300.0)
    assert sim.stats["braking_skipped"] == 0


def test_mixed_scenario_has_braking_and_baseline_episodes_on_sumo():
    env = SumoHighwayEnv("mixed", num_roads=8, seed=0, max_steps=120, warmup_s=20.0)
    try:
        eps = EpisodeTracker()(torch.stack(rollout(env, IDMMobilPolicy(), 250), 1))
        with_event = [e for e in eps if e["braking_distance"] == e["braking_distance"]]  # not NaN
        assert len(eps) >= 12 and 0 < len(with_event) < len(eps)
        assert env.stats["braking_skipped"] > 0 and env.stats["braking_missed"] == 0
        for e in with_event:
            assert 100.0 <= e["braking_distance"] <= 300.0
    finally:
        env.close()


def test_reward_terms_are_written_and_sum_to_the_rewards():
    """The env writes the rewards' named terms (keys.TERM_KEYS) beside them: r_D3QN = eff + lc + collision and
    r_TD3 = eff + comfort + collision, frame by frame, the lane-change term on the frames a change starts, the
    efficiency term Eq. 27 of the ego's speed."""
    from kddrl_trl.envs.rewards import efficiency_term

    env = SumoHighwayEnv("baseline", num_roads=4, seed=2)
    try:
        td = torch.stack(rollout(env, RandomDrivingPolicy(generator=torch.Generator().manual_seed(0)), 200), 1)
    finally:
        env.close()
    nxt = td["next"]
    eff, lc, col, acc = (nxt[key] for key in K.TERM_KEYS)
    torch.testing.assert_close(nxt[K.LC_REWARD], eff + lc + col, rtol=0, atol=1e-5)
    torch.testing.assert_close(nxt[K.CF_REWARD], eff + acc + col, rtol=0, atol=1e-5)
    started = nxt[K.LC_STARTED].float()
    assert started.any() and torch.equal(lc, -started)
    assert torch.equal(col, -100.0 * nxt[K.COLLISION].float())
    torch.testing.assert_close(eff, efficiency_term(nxt[K.EGO_STATE][..., 1:2], env.config), rtol=0, atol=1e-4)


def test_the_roads_of_a_seed_in_one_simulation_of_several_seeds_carry_its_traffic_alone():
    """``road_seeds``: one simulation of 3 seeds x 2 roads (braking: random events per road), the rule driving; the
    rows of seed 7 equal, frame for frame and bit for bit, those of a simulation of its own with ``seed=7``
    (observations, rewards, events); the rows of seed 3 differ from them. A road_seeds list of the wrong length is
    refused, naming num_roads."""
    alone = SumoHighwayEnv("braking", num_roads=2, seed=7)
    try:
        own = torch.stack(rollout(alone, IDMMobilPolicy(), 300), -1)
    finally:
        alone.close()
    batch = SumoHighwayEnv("braking", num_roads=6, seed=3, road_seeds=[3, 3, 7, 7, 9, 9])
    try:
        rows = torch.stack(rollout(batch, IDMMobilPolicy(), 300), -1)
    finally:
        batch.close()
    assert own.batch_size == (2, 300) and rows.batch_size == (6, 300)
    lateral = [k for k in own.keys(True, True) if k[-1] == "lane_offset"]
    for k in own.keys(True, True):
        if k not in lateral:
            assert torch.equal(rows.get(k)[2:4], own.get(k)), k
    # a lateral offset carries the road's place in the network in its rounding (1e-14 m), and at a lane change's
    # mid-point it may fall on the other side of the lane boundary: +w/2 for -w/2, the same place
    width = make_config("braking").lane_width
    for k in lateral:
        d = (rows.get(k)[2:4].double() - own.get(k).double()).abs()
        assert bool(((d < 1e-12) | ((d - width).abs() < 1e-5)).all()), k
        assert int((d > 1e-12).sum()) < 0.02 * d.numel()
    assert not torch.equal(rows.get(K.EGO_STATE)[0:2], own.get(K.EGO_STATE))
    assert bool(own.get(("next", "done")).any())  # episodes ended and restarted within the window
    with pytest.raises(ValueError, match="num_roads=4"):
        HighwaySim(make_config("baseline"), 4, seed=0, road_seeds=[1, 2])
