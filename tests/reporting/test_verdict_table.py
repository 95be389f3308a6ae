"""The guide home page's short verdict table reads each primary claim's verdicts from ``report.json`` as the report wrote them."""

import pytest

from kddrl_trl.reporting.verdict_table import table


def _claim(i: int, **extra) -> dict:
    claim = {"id": f"P{i}", "family": "primary", "scenario": "baseline", "a": "kddrl", "b": "ni"}
    claim |= {"metric": "collision_rate", "claimed": "less", "paper": -0.013, "difference": -0.02, "ci": [-0.03, -0.01]}
    return claim | {"direction": "holds", "size": "compatible", "reading": None, "seeds_needed": None} | extra


def test_each_row_carries_the_claims_verdicts_and_the_underpowered_reading():
    claims = [_claim(i) for i in range(1, 17)]
    claims.append(_claim(17, direction="inconclusive", size="compatible", reading="underpowered", seeds_needed=156.0))
    rows = table({"claims": claims}).splitlines()
    assert rows[2] == "| P1 | baseline: KDDRL collides less than Ni | -2.0 [-3.0, -1.0] | -1.3 | holds | compatible |"
    assert rows[-1].endswith("| inconclusive (156) | compatible |")


def test_pending_rows_show_the_estimate_so_far():
    description = {"difference": 0.01, "ci": [-0.01, 0.03], "n": [15, 14]}
    claims = [_claim(i, direction="pending", size="pending", description=description) for i in range(1, 18)]
    assert "| +1.0 [-1.0, +3.0], n=14 so far | -1.3 | pending | pending |" in table({"claims": claims})


def test_a_report_without_the_plans_17_primary_claims_is_refused():
    with pytest.raises(ValueError, match="16 primary claims"):
        table({"claims": [_claim(i) for i in range(1, 17)]})
