"""The SUMO env's outputs are exactly those of the reference rollouts in ``tests/envs/env_reference.npz``
(produced by ``tests/envs/env_reference.py`` from the code before the observation building was vectorised): same seed,
same actions -> every observation key, reward, done flag and episode event identical, frame by frame, on the
baseline, braking and congested scenarios at K = 2-4, with partial resets, collisions and truncations."""

import numpy as np
import pytest
from env_reference import CASES, FIXTURE, rollout

pytest.importorskip("libsumo")

#: keys the env gained after the fixture was made (the lane offsets of the lcGAN condition; the rewards' named terms);
#: every other key must match the fixture exactly
ADDED_SINCE_FIXTURE = {
    *(f"{pre}{key}" for pre in ("", "next/") for key in ("ego/lane_offset", "neighbors/lane_offset")),
    *(f"next/reward_terms/{term}" for term in ("efficiency", "lane_change", "collision", "comfort")),
    # the braking event's car, labels for the records (keys.EPISODE_LABEL_KEYS)
    *(
        f"{pre}braking/{key}"
        for pre in ("", "next/")
        for key in ("gap", "speed", "lane_changes", "contact", "slot", "future", "future_known")
    ),
}


@pytest.fixture(scope="module")
def reference():
    return dict(np.load(FIXTURE))


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_rollout_matches_reference(case, reference):
    scenario = case[0]
    new = rollout(*case)
    expected = {name.split(":", 1)[1]: arr for name, arr in reference.items() if name.startswith(f"{scenario}:")}
    assert sorted(set(new) - ADDED_SINCE_FIXTURE) == sorted(expected)
    assert expected["next/done"].any() and expected["next/lc/started"].any()  # the case exercises resets
    for name, arr in expected.items():
        assert new[name].dtype == arr.dtype, name
        np.testing.assert_array_equal(new[name], arr, err_msg=f"{scenario}: {name}")
