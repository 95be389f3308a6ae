"""Hand-checked cases for the IDM (paper Eq. 11-12), MOBIL (Eq. 20-22) and the IDM+MOBIL baseline."""

import math

import pytest
import torch
from tensordict import TensorDict

from kddrl_trl.baselines import IDMMobilPolicy
from kddrl_trl.keys import (
    CF_ACTION,
    EGO_LANE,
    EGO_STATE,
    KEEP,
    LC_ACTION,
    LC_ACTION_MASK,
    LEFT,
    NEIGHBORS_KIN,
    NEIGHBORS_MASK,
    NEIGHBORS_REL,
    RIGHT,
    SLOT,
)
from kddrl_trl.physics import IDMParams, MOBILParams, idm_acceleration, idm_rollout, mobil_prior, mobil_utilities

P = IDMParams()
V0 = 130 / 3.6
L = 5.0


# ------------------------------------------------------------------------------------------------ IDM
def test_idm_free_road():
    # a = a_max (1 - (v/v0)^4), v = 20 m/s, v0 = 36.111 m/s
    expected = 5.0 * (1 - (20 / V0) ** 4)
    a = idm_acceleration(torch.tensor(20.0), 0.0, 1.0, has_leader=torch.tensor(False))
    assert a.item() == pytest.approx(expected, rel=1e-5)
    assert expected == pytest.approx(4.5295, abs=1e-3)
    # a leader infinitely far away is the same as no leader
    assert idm_acceleration(torch.tensor(20.0), 0.0, math.inf).item() == pytest.approx(expected, rel=1e-5)


def test_idm_with_leader_by_hand():
    # v = 20, v_lead = 15, gap = 30 m
    # s* = s0 + v T + v (v - v_lead) / (2 sqrt(a_max b)) = 5 + 30 + 100 / (2 sqrt(20)) = 46.18034
    # a  = 5 [1 - (20 / 36.111)^4 - (46.18034 / 30)^2] = 5 [1 - 0.094092 - 2.369582] = -7.31837
    s_star = 5.0 + 20.0 * 1.5 + 20.0 * 5.0 / (2 * math.sqrt(5.0 * 4.0))
    expected = 5.0 * (1 - (20 / V0) ** 4 - (s_star / 30.0) ** 2)
    assert expected == pytest.approx(-7.31837, abs=1e-4)
    a = idm_acceleration(torch.tensor(20.0), torch.tensor(15.0), torch.tensor(30.0))
    assert a.item() == pytest.approx(expected, rel=1e-5)


def test_idm_gap_clamp_is_finite():
    a = idm_acceleration(torch.tensor([20.0, 0.0, 20.0]), torch.tensor(0.0), torch.tensor([0.0, 0.0, -3.0]))
    assert torch.isfinite(a).all()
    assert (a < -100).all()  # very strong braking at (or past) contact
    # absent leader with garbage gap / speed: free road, no NaN
    a = idm_acceleration(
        torch.tensor(10.0), torch.tensor(float("nan")), torch.tensor(float("nan")), has_leader=torch.tensor(False)
    )
    assert a.item() == pytest.approx(5.0 * (1 - (10 / V0) ** 4), rel=1e-5)


def test_idm_broadcast_per_vehicle_params():
    v0 = torch.tensor([20.0, 30.0, 40.0])
    params = IDMParams(v0=v0, a_max=torch.tensor([1.0, 2.0, 3.0]))
    v = torch.full((2, 1), 20.0)  # [2, 1] x params [3] -> [2, 3]
    a = idm_acceleration(v, 0.0, 1e9, params)
    assert a.shape == (2, 3)
    expected = torch.tensor([1.0, 2.0, 3.0]) * (1 - (20.0 / v0) ** 4)
    torch.testing.assert_close(a[0], expected, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(a[1], expected, rtol=1e-4, atol=1e-4)


# -------------------------------------------------------------------------------------------- rollout
def test_rollout_free_at_desired_speed():
    y = idm_rollout(
        torch.tensor([10.0]),
        torch.tensor([V0]),
        torch.tensor([0.0]),
        torch.tensor([0.0]),
        torch.tensor([False]),
        steps=20,
        dt=0.1,
    )
    assert y.shape == (1, 20)
    expected = 10.0 + V0 * 0.1 * torch.arange(1, 21, dtype=torch.float32)
    torch.testing.assert_close(y[0], expected, rtol=1e-5, atol=1e-4)


def test_rollout_stops_behind_stopped_vehicle():
    y_stop = 150.0
    y = idm_rollout(
        torch.tensor(0.0),
        torch.tensor(30.0),
        torch.tensor(y_stop),
        torch.tensor(0.0),
        torch.tensor(True),
        steps=400,
        dt=0.1,
    )
    assert y.shape == (400,)
    v = torch.diff(y, prepend=torch.zeros(1)) / 0.1  # speeds v' of the semi-implicit Euler steps
    assert (y < y_stop - L).all()  # never reaches the stopped vehicle's rear bumper
    assert (torch.diff(y) >= 0).all()  # never reverses
    assert v[-1] < 0.5  # has (almost) stopped
    assert (torch.diff(v) <= 1e-4).all()  # decelerates throughout


# ---------------------------------------------------------------------------------------------- MOBIL
def scene(lane=1, ego_v=25.0, **slots):
    """Ego at y = 0; each slot given as (bumper-to-bumper gap to ego, speed)."""
    kin, mask = torch.zeros(6, 3), torch.zeros(6, dtype=torch.bool)
    for name, (gap, v) in slots.items():
        i = SLOT[name]
        y = gap + L if name in "abc" else -(gap + L)
        kin[i] = torch.tensor([y, v, 0.0])
        mask[i] = True
    return torch.tensor(0.0), torch.tensor(ego_v), kin, mask, torch.tensor(lane)


def test_mobil_safety_violation_zeroes_direction():
    # slow leader ahead; left lane free ahead but a follower only 3 m behind (< y_safe = 5 m)
    args = scene(b=(50.0, 22.0), d=(3.0, 25.0))
    U, safe = mobil_utilities(*args)
    assert not safe[LEFT] and safe[KEEP] and safe[RIGHT]
    p = mobil_prior(*args)
    assert p[LEFT] == 0.0
    assert p[RIGHT] > 0.9  # right lane empty: the big incentive goes there


def test_mobil_small_incentive_keeps():
    # current leader slightly slower and far: tiny gain from moving to the free right lane
    args = scene(ego_v=30.0, b=(250.0, 29.8))
    U, safe = mobil_utilities(*args)
    assert 0.0 < U[RIGHT] < 0.3 and safe[RIGHT]
    p = mobil_prior(*args)
    assert p[KEEP] == pytest.approx(1.0) and p[LEFT] == 0.0 and p[RIGHT] == 0.0


def test_mobil_big_incentive():
    # slow leader close-ish ahead, right lane free, left lane blocked by a slow leader
    args = scene(b=(50.0, 22.0), a=(20.0, 15.0))
    p = mobil_prior(*args)
    assert p[RIGHT] > 0.9 and p[LEFT] == 0.0
    assert p.sum() == pytest.approx(1.0)


def test_mobil_politeness_flips_decision():
    # slow leader b ahead (ego gains ~5.18 m/s² by going left); left follower 40 m behind at 25 m/s, who
    # goes from free road (+3.85) to braking behind the ego (-1.80, still > -b_safe)
    args = scene(b=(50.0, 22.0), d=(40.0, 25.0), lane=1)
    U_rude, safe = mobil_utilities(*args, mobil=MOBILParams(politeness=0.1))
    U_polite, _ = mobil_utilities(*args, mobil=MOBILParams(politeness=1.0))
    assert safe[LEFT]
    assert U_rude[LEFT] > 0.3 > U_polite[LEFT]
    # the right lane is closed (lane 0 is rightmost: use lane 0 so only left vs keep is in play)
    args0 = scene(b=(50.0, 22.0), d=(40.0, 25.0), lane=0)
    p_rude = mobil_prior(*args0, mobil=MOBILParams(politeness=0.1))
    p_polite = mobil_prior(*args0, mobil=MOBILParams(politeness=1.0))
    assert p_rude.argmax() == LEFT
    assert p_polite[LEFT] == 0.0 and p_polite[KEEP] == pytest.approx(1.0)


def test_mobil_edge_lanes():
    # strong incentive everywhere, but lane 0 has no right and lane 2 has no left
    p0 = mobil_prior(*scene(lane=0, b=(30.0, 15.0)))
    p2 = mobil_prior(*scene(lane=2, b=(30.0, 15.0)))
    assert p0[RIGHT] == 0.0 and p0[LEFT] > 0.5
    assert p2[LEFT] == 0.0 and p2[RIGHT] > 0.5
    _, safe0 = mobil_utilities(*scene(lane=0))
    _, safe2 = mobil_utilities(*scene(lane=2))
    assert not safe0[RIGHT] and not safe2[LEFT]


def test_mobil_all_absent_free_road():
    kin = torch.full((6, 3), float("nan"))  # garbage in absent slots must not leak
    mask = torch.zeros(6, dtype=torch.bool)
    U, safe = mobil_utilities(torch.tensor(0.0), torch.tensor(25.0), kin, mask, torch.tensor(1))
    p = mobil_prior(torch.tensor(0.0), torch.tensor(25.0), kin, mask, torch.tensor(1))
    assert torch.isfinite(U).all() and torch.isfinite(p).all()
    torch.testing.assert_close(p, torch.tensor([0.0, 1.0, 0.0]))
    assert U[KEEP] == pytest.approx(5.0 * (1 - (25 / V0) ** 4), rel=1e-5)  # U_keep = a_AV_old here


def test_mobil_batched_simplex():
    g = torch.Generator().manual_seed(0)
    B = (64, 3)
    kin = torch.rand(*B, 6, 3, generator=g) * torch.tensor([200.0, 40.0, 2.0]) - torch.tensor([100.0, 0.0, 1.0])
    mask = torch.rand(*B, 6, generator=g) > 0.3
    lane = torch.randint(0, 3, B, generator=g)
    ego_v = torch.rand(*B, generator=g) * 40
    p = mobil_prior(torch.zeros(B), ego_v, kin, mask, lane)
    assert p.shape == (*B, 3)
    assert torch.isfinite(p).all() and (p >= 0).all()
    torch.testing.assert_close(p.sum(-1), torch.ones(B))
    assert (p[..., RIGHT][lane == 0] == 0).all() and (p[..., LEFT][lane == 2] == 0).all()


# ---------------------------------------------------------------------------------------------- policy
def make_td(batch):
    kin, mask = torch.zeros(*batch, 6, 3), torch.zeros(*batch, 6, dtype=torch.bool)
    kin[..., SLOT["b"], :] = torch.tensor([150.0 + 50.0 + L, 22.0, 0.0])  # slow leader 50 m ahead
    mask[..., SLOT["b"]] = True
    ego = torch.zeros(*batch, 3)
    ego[..., 0], ego[..., 1] = 150.0, 25.0
    return TensorDict(
        {
            EGO_STATE: ego,
            EGO_LANE: torch.ones(*batch, 1, dtype=torch.int64),
            NEIGHBORS_KIN: kin,
            NEIGHBORS_MASK: mask,
            NEIGHBORS_REL: torch.zeros(*batch, 6, 4),
            LC_ACTION_MASK: torch.ones(*batch, 3, dtype=torch.bool),
        },
        batch_size=batch,
    )


def test_policy_batch_respects_mask():
    policy = IDMMobilPolicy(IDMParams(), MOBILParams())
    assert LC_ACTION in policy.out_keys and EGO_STATE in policy.in_keys
    td = make_td([4])
    td[LC_ACTION_MASK][1] = torch.tensor([False, True, True])  # left not allowed
    td[LC_ACTION_MASK][2] = torch.tensor([True, True, False])  # right not allowed
    td[LC_ACTION_MASK][3] = torch.tensor([False, True, False])  # only keep
    td[NEIGHBORS_KIN][..., SLOT["b"], 0] = torch.tensor([155.5, 205.0, 205.0, 205.0])  # row 0: 0.5 m gap
    out = policy(td)
    lc, cf = out[LC_ACTION], out[CF_ACTION]
    assert lc.shape == (4, 3) and lc.dtype == torch.float32 and cf.shape == (4, 1)
    assert (lc.sum(-1) == 1).all() and ((lc == 0) | (lc == 1)).all()
    assert (lc.bool() <= td[LC_ACTION_MASK]).all()
    # left and right have equal utility (both empty); argmax takes left where allowed
    assert lc.argmax(-1).tolist() == [LEFT, RIGHT, LEFT, KEEP]
    assert ((cf >= -5) & (cf <= 5)).all()
    assert cf[0].item() == -5.0  # near-contact leader: clipped hard braking


def test_policy_unbatched():
    td = make_td([])
    out = IDMMobilPolicy()(td)
    assert out[LC_ACTION].shape == (3,) and out[CF_ACTION].shape == (1,)
    assert out[LC_ACTION].sum() == 1
    # IDM behind b: v = 25, v_b = 22, gap = 50 -> s* = 42.5 + 75 / (2 sqrt(20)) = 50.8853
    s_star = 5 + 25 * 1.5 + 25 * 3 / (2 * math.sqrt(20))
    expected = 5 * (1 - (25 / V0) ** 4 - (s_star / 50) ** 2)
    assert out[CF_ACTION].item() == pytest.approx(expected, rel=1e-5)


def test_policy_brakes_for_target_lane_leader_during_lane_change():
    """While straddling two lanes (|dx| < lane width) the ego follows the closer of both leaders."""
    td = make_td([2])
    td[NEIGHBORS_KIN][..., SLOT["a"], :] = torch.tensor([150.0 + 8.0 + L, 20.0, 0.0])  # 8 m gap, left lane
    td[NEIGHBORS_MASK][..., SLOT["a"]] = True
    td[NEIGHBORS_REL][0, SLOT["a"], 0] = 1.6  # row 0: mid-manoeuvre, leader a half a lane away
    td[NEIGHBORS_REL][1, SLOT["a"], 0] = 3.2  # row 1: a is a full lane away: ignored
    cf = IDMMobilPolicy()(td)[CF_ACTION].squeeze(-1)
    assert cf[0] == -5.0 and cf[1] > -5.0
