"""The paper's published results (Tables II-V), as data, to print beside ours.

Transcribed from ``shared/paper/kddrl-paper.md``. Each value is ``(mean, sd)`` as printed (``sd`` None where the
paper gives none); the paper does not say whether its ``±`` is a spread over episodes, frames or runs.
"Number of lane changes" is a total: "the cumulative number of lane changes across all vehicles during 1000
episodes" (§IV.D, Scenario 2), i.e. the ego's lane changes summed over the 1000 test episodes. Collision rate is
the fraction of test episodes that ended in a collision.
"""

from __future__ import annotations

#: which table gives each scenario's comparison
TABLES = {
    "baseline": "Table II (and Table V, ablations)",
    "congested": "Table III",
    "braking": "Table IV",
    "congested_text": "Table III (the text's flow, 3 x 1329 veh/h)",
}

#: the paper's name of each of our algos (docs/design.md, "Comparison systems")
PAPER_NAMES = {
    "kddrl": "D3QN+TD3 (KDDRL)",
    "ni": "DDQN+TD3 (Ni)",
    "peng": "D3QN+DDPG (Peng)",
    "d3qn_unified": "D3QN (Unit)",
    "pasac_unified": "PASAC (Unit)",
    "idm_mobil": "IDM+MOBIL",
    "d3qn_td3": "D3QN+TD3",
    "d3qn_td3_lg": "D3QN+TD3+LG",
    "kddrl_same_clock": "KDDRL with same control frequency",
}


def _row(speed, accel, lane_changes, collision_pct):
    return {
        "mean_speed_kmh": speed,
        "mean_accel": accel,
        "lane_changes_per_1000_episodes": lane_changes,
        "collision_rate": (collision_pct / 100.0, None),
    }


#: scenario -> algo -> metric -> (mean, sd); lane changes per 1000 episodes; collision rate as a fraction
PAPER = {
    "baseline": {  # Table II; the ablations and IDM+MOBIL from Table V (no lane-change counts there)
        "ni": _row((157.7, 23.8), (1.49, 1.0), (492, 17), 1.4),
        "peng": _row((158.6, 17.8), (1.75, 2.3), (1778, 39), 2.7),
        "d3qn_unified": _row((115.0, 16.0), (0.22, 2.8), (2175, 45), 2.1),
        "pasac_unified": _row((77.6, 12.0), (-0.75, 4.0), (1709, 62), 0.7),
        "kddrl": _row((159.4, 22.5), (2.33, 0.3), (1243, 29), 0.1),
        "idm_mobil": _row((146.6, 25.5), (1.20, 0.8), None, 0.0),
        "d3qn_td3": _row((152.5, 30.6), (2.42, 0.6), None, 3.4),
        "d3qn_td3_lg": _row((157.3, 30.4), (2.42, 0.6), None, 2.6),
        "kddrl_same_clock": _row((157.7, 27.2), (1.66, 0.5), None, 0.9),
    },
    "congested": {  # Table III
        "ni": _row((136.3, 24.1), (0.99, 0.9), (837, 24), 1.8),
        "peng": _row((152.5, 21.4), (1.69, 2.2), (1202, 27), 1.8),
        "kddrl": _row((154.4, 20.2), (2.13, 0.5), (1081, 29), 0.3),
    },
    "braking": {  # Table IV
        "ni": _row((132.9, 22.1), (0.67, 2.1), (525, 19), 24.8),
        "peng": _row((140.2, 23.2), (0.78, 3.2), (870, 20), 24.1),
        "kddrl": _row((153.9, 20.7), (2.04, 0.7), (1226, 29), 1.0),
    },
}

PAPER["congested_text"] = PAPER["congested"]  # the same Table III, read with the text's flow (highway_config.SCENARIOS)


def paper_value(scenario: str, algo: str, metric: str) -> tuple[float, float | None] | None:
    """The paper's (mean, sd) of ``metric`` for ``algo`` on ``scenario``, or None where it published none."""
    return PAPER.get(scenario, {}).get(algo, {}).get(metric)
