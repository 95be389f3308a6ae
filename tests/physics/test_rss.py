"""The worst-case safety layer's physics (kddrl_trl.physics.rss): the safe distance against Intel's ad-rss on random
states, the longitudinal bound as the largest command that keeps it, no contact ever under the bound in a 1-D
car-following model whose leader brakes within the assumptions (hypothesis), and the lane-change gap check."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from kddrl_trl.physics.rss import RSSParams, lane_change_safe, longitudinal_bound, safe_distance

P = RSSParams()
LOW, HIGH, DT = -5.0, 5.0, 0.1


def _ad_rss_object(rss, v: float, accel: float, brake_max: float, brake_min: float, response: float):
    """An ad-rss RelativeObjectState of a car in its lane at speed ``v`` with the given RSS dynamics."""
    phys = rss.physics
    o = rss.rss.core.RelativeObjectState()
    o.object_type = rss.rss.world.ObjectType.OtherVehicle
    d = o.dynamics
    d.alpha_lon.accel_max = phys.Acceleration(accel)
    d.alpha_lon.brake_max = phys.Acceleration(-brake_max)
    d.alpha_lon.brake_min = phys.Acceleration(-brake_min)
    d.alpha_lon.brake_min_correct = phys.Acceleration(-brake_min)
    d.alpha_lat.accel_max = phys.Acceleration(0.1)
    d.alpha_lat.brake_min = phys.Acceleration(-0.8)
    d.response_time = phys.Duration(response)
    d.max_speed_on_acceleration = phys.Speed(100.0)
    d.lateral_fluctuation_margin = phys.Distance(0.0)
    d.min_longitudinal_safety_distance = phys.Distance(0.0)
    u = d.unstructured_settings  # unused by the structured check, but validated: plausible values
    u.pedestrian_turning_radius, u.drive_away_max_angle = phys.Distance(2.0), phys.Angle(2.4)
    u.vehicle_yaw_rate_change, u.vehicle_min_radius = phys.AngularAcceleration(0.3), phys.Distance(3.5)
    u.vehicle_trajectory_calculation_step = phys.Duration(0.2)
    for name in dir(u):
        if name.endswith("_steps"):
            setattr(u, name, 1)
    s = o.unstructured_object_state
    s.yaw, s.yaw_rate, s.steering_angle = phys.Angle(0.0), phys.AngularVelocity(0.0), phys.Angle(0.0)
    s.dimension.length, s.dimension.width = phys.Distance(5.0), phys.Distance(1.8)
    s.center_point.x, s.center_point.y = phys.Distance(0.0), phys.Distance(0.0)
    s.speed_range.minimum, s.speed_range.maximum = phys.Speed(0.0), phys.Speed(max(v, 0.0))
    st_ = o.structured_object_state
    st_.velocity.speed_lon_min = st_.velocity.speed_lon_max = phys.Speed(v)
    st_.velocity.speed_lat_min = st_.velocity.speed_lat_max = phys.Speed(0.0)
    st_.has_priority, st_.is_in_correct_lane = False, True
    st_.distance_to_enter_intersection = st_.distance_to_leave_intersection = phys.Distance(1000.0)
    return o


def test_the_safe_distance_is_ad_rss_on_random_states():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # its boost converters, registered twice on import
        rss = pytest.importorskip("ad_rss")
    rng = np.random.default_rng(0)
    n = 300
    v_rear, v_front = rng.uniform(0, 50, n), rng.uniform(0, 50, n)
    response, accel = rng.uniform(0.05, 2.0, n), rng.uniform(0.0, 5.0, n)
    brake_min, brake_max = rng.uniform(2.0, 6.0, n), rng.uniform(6.0, 10.0, n)
    ours = safe_distance(*(torch.as_tensor(x) for x in (v_rear, v_front, response, accel, brake_min, brake_max)))
    for i in range(n):
        front = _ad_rss_object(rss, v_front[i], 2.0, brake_max[i], 4.0, 1.0)  # only the front's brake_max counts
        rear = _ad_rss_object(rss, v_rear[i], accel[i], 9.0, brake_min[i], response[i])
        out = rss.physics.Distance(0.0)
        assert rss.rss.structured.calculateSafeLongitudinalDistanceSameDirection(front, rear, out)
        assert float(ours[i]) == pytest.approx(out.mDistance, abs=1e-3), i  # ad-rss rounds to its precision


def test_the_bound_is_the_largest_command_that_keeps_the_safe_distance():
    rng = np.random.default_rng(1)
    v, v_lead = torch.as_tensor(rng.uniform(0, 45, 2000)), torch.as_tensor(rng.uniform(0, 45, 2000))
    gap = torch.as_tensor(rng.uniform(0, 250, 2000))
    bound = longitudinal_bound(v, v_lead, gap, P, LOW, HIGH)
    assert ((bound >= LOW) & (bound <= HIGH)).all()
    # the distance before RSS's clamp at 0 (a faster leader, which stops after the ego, needs none)
    raw = P.response * (2 * v + bound * P.response) / 2 + (v + bound * P.response) ** 2 / (2 * P.ego_brake)
    keeps = (raw - v_lead**2 / (2 * P.other_brake) <= gap - P.margin + 1e-6) | (v + bound * P.response <= 0)
    inner = (bound > LOW) & (bound < HIGH)
    assert keeps[bound > LOW].all() and inner.sum() > 20
    more = safe_distance(v, v_lead, P.response, bound + 0.01, P.ego_brake, P.other_brake)
    assert (more[inner] > gap[inner] - P.margin).all()  # a hundredth more would not keep it: the largest
    # a leader far ahead leaves the command free; a standing car just ahead at speed asks for full braking
    free = longitudinal_bound(torch.tensor([30.0]), torch.tensor([30.0]), torch.tensor([500.0]), P, LOW, HIGH)
    close = longitudinal_bound(torch.tensor([30.0]), torch.tensor([0.0]), torch.tensor([20.0]), P, LOW, HIGH)
    assert float(free) == HIGH and float(close) == LOW


def _move(x: float, v: float, a: float) -> tuple[float, float]:
    """One frame of ballistic motion that stops at zero speed (SUMO's update)."""
    if v + a * DT < 0:
        return x + v * v / (2 * -a), 0.0
    return x + v * DT + 0.5 * a * DT * DT, v + a * DT


@settings(max_examples=300, deadline=None)
@given(
    v=st.floats(0.0, 45.0),
    v_lead=st.floats(0.0, 45.0),
    slack=st.floats(0.0, 100.0),
    lead_accel=st.lists(st.floats(-P.other_brake, 3.0), min_size=400, max_size=400),
    commands=st.lists(st.floats(LOW, HIGH), min_size=1, max_size=20),
)
def test_no_contact_ever_under_the_bound_while_the_leader_brakes_within_the_assumptions(
    v, v_lead, slack, lead_accel, commands
):
    """1-D car following for 40 s: the leader brakes or accelerates at random, never harder than ``other_brake``,
    from any state where the ego can still stop behind it; the ego asks for any command (a cycle of random ones,
    full throttle among them), the layer executes ``min(command, bound)``; the gap never closes."""
    gap = P.margin + max(0.0, v * v / (2 * P.ego_brake) - v_lead**2 / (2 * P.other_brake)) + slack
    x, x_lead = 0.0, gap
    for t, a_lead in enumerate(lead_accel):
        bound = float(longitudinal_bound(*(torch.tensor([z]) for z in (v, v_lead, x_lead - x)), P, LOW, HIGH)[0])
        a = min(commands[t % len(commands)], bound)
        x, v = _move(x, v, a)
        x_lead, v_lead = _move(x_lead, v_lead, a_lead)
        assert x_lead - x > 0, (t, x_lead - x, v, v_lead)


def test_a_lane_change_starts_only_into_a_gap_safe_for_both_new_neighbours():
    v = torch.tensor([30.0, 30.0, 30.0, 30.0])
    gap_lead, v_lead = torch.tensor([80.0, 5.0, 80.0, 80.0]), torch.tensor([30.0, 30.0, 30.0, 30.0])
    gap_follow, v_follow = torch.tensor([100.0, 100.0, 3.0, 3.0]), torch.tensor([30.0, 30.0, 30.0, 30.0])
    follow_present = torch.tensor([True, True, True, False])
    ok = lane_change_safe(v, gap_lead, v_lead, gap_follow, v_follow, P, follow_present=follow_present)
    assert ok.tolist() == [True, False, False, True]  # too close to the new leader, or to the new follower
