"""The policies that ship with the package (``kddrl_trl/policies/``, the safety study's chosen seeds): each loads as a
trained run with the layer it was trained with, its card names where it came from, and one drives on SUMO from
``run=shipped:<name>`` as a user would run it."""

from __future__ import annotations

import json

import pytest
from testkit import run_module

SHIPPED = [f"{algo}_safe_{sc}" for algo in ("kddrl", "d3qn_td3") for sc in ("baseline", "congested", "braking")]


def test_the_safety_studys_chosen_policies_ship_and_load():
    from kddrl_trl.factories import make_trained_learner
    from kddrl_trl.policies import CARD_FILE, shipped_names, shipped_policy

    assert set(SHIPPED) <= set(shipped_names())
    for name in SHIPPED:
        folder = shipped_policy(f"shipped:{name}")
        card = json.loads((folder / CARD_FILE).read_text())
        algo, scenario = name.split("_safe_")
        assert card["algo"] == algo and card["scenario"] == scenario and card["episodes_trained"] == 1000
        assert "validation traffic only" in card["chosen"] and card["commit"].startswith("cf0f089")
        assert card["final_evaluation"]["episodes"] == 1000
        spec, learner, _, saved = make_trained_learner(folder)
        assert spec.shield == "rss" and saved.seed == card["seed"] and sum(p.numel() for p in learner.parameters())


def test_a_shipped_policy_drives_from_its_name(tmp_path):
    done = run_module(
        ["kddrl_trl.evaluate", "run=shipped:kddrl_safe_braking", "+scenario=braking", "eval_episodes=1",
         "progress=false", "env.num_roads=1"],
        cwd=tmp_path,
    )  # fmt: skip
    (folder,) = list((tmp_path / "runs" / "shipped__kddrl_safe_braking").glob("eval__braking__*"))
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["episodes"] == 1 and summary["trained_on"] == "braking", done.stdout[-2000:]
    assert summary["checkpoint"].endswith("policy.pt")


@pytest.mark.parametrize("name", ["nope", "../kddrl_safe_braking"])
def test_an_unknown_shipped_name_is_refused_in_one_line(tmp_path, name):
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "kddrl_trl.evaluate", f"run=shipped:{name}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert done.returncode != 0 and f"run=shipped:{name}: no such shipped policy" in done.stderr + done.stdout
    assert "kddrl_safe_braking" in done.stderr + done.stdout  # it lists the shipped ones
    assert not (tmp_path / "runs").exists()
