"""Bad input fails before SUMO starts, with a message naming the key."""
from __future__ import annotations

import pytest

from kddrl_trl.envs import FakeHighwayEnv, SumoHighwayEnv, make_config, scenario_names
from kddrl_trl.envs import sim


@pytest.mark.parametrize("kwargs, match", [
    ({"scenario": "rainy"}, "unknown scenario 'rainy'"),
    ({"flow_vph": -10.0}, "'flow_vph'"),
    ({"num_roads": 0}, "num_roads"),
    ({"num_roads": 2.5}, "num_roads"),
    ({"ego_lane": 3}, "'ego_lane'"),
    ({"ego_lane": -1}, "'ego_lane'"),
    ({"flow_vph": "lots"}, "'flow_vph'"),
    ({"flow_vhp": 100.0}, "'flow_vhp'"),
    ({"braking": {"stand_time": "long"}}, "'braking.stand_time'"),
    ({"braking": {"min_distance": 400.0}}, "'braking.min_distance'"),
    ({"drivers": [{"name": "x", "v0": -1.0}]}, r"'drivers\[0\].v0'"),
    ({"drivers": [{"name": "x", "colour": 1}]}, "colour"),
    ({"lc_duration": 1.25}, "'lc_duration'"),
    ({"section_length": 0.0}, "'section_length'"),
])
@pytest.mark.parametrize("env_cls", [SumoHighwayEnv, FakeHighwayEnv])
def test_bad_input_names_the_key_before_sumo_starts(env_cls, kwargs, match):
    kwargs = dict(kwargs)
    scenario = kwargs.pop("scenario", "baseline")
    num_roads = kwargs.pop("num_roads", 1)
    with pytest.raises(ValueError, match=match):
        env_cls(scenario, num_roads=num_roads, **kwargs)
    assert sim._ACTIVE is None


def test_error_message_is_one_clear_line():
    with pytest.raises(ValueError) as err:
        make_config("baseline", {"flow_vph": "lots"})
    assert "\n" not in str(err.value) and "flow_vph" in str(err.value)


def test_scenarios_and_overrides():
    assert scenario_names() == ["baseline", "braking", "congested"]
    assert make_config("congested").flow == pytest.approx(1.5 * 2325)
    assert make_config("braking").braking.enabled and not make_config("baseline").braking.enabled
    cfg = make_config("congested", {"flow_vph": 2658.0, "braking": {"stand_time": 5.0}})
    assert cfg.flow == pytest.approx(1.5 * 2658) and cfg.braking.stand_time == 5.0 and cfg.scenario == "congested"
    assert make_config(overrides={"scenario": "braking"}).scenario == "braking"


def test_a_ready_config_is_not_given_its_scenario_preset_again():
    cfg = make_config("braking")
    cfg.braking.enabled, cfg.braking.stand_time = False, 9.0  # e.g. set on the composed Hydra env node
    again = make_config(cfg, {"flow_vph": 2000.0})
    assert again.scenario == "braking" and not again.braking.enabled and again.braking.stand_time == 9.0
    assert again.flow_vph == 2000.0



def test_a_run_saved_with_the_old_per_algo_compile_keys_still_loads():
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    from kddrl_trl.conf.schema import HierarchicalAlgo, algo_from_node
    from kddrl_trl.factories import make_learner

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        cfg = compose(config_name="config")
    saved = OmegaConf.create(OmegaConf.to_yaml(cfg.algo))  # as a run's config.yaml holds it
    saved.transforms.compile, saved.transforms.aot, saved.learner.compile = "auto", None, "auto"
    algo = algo_from_node(saved)
    assert isinstance(algo, HierarchicalAlgo) and algo.lc_period == 20
    assert make_learner(algo).compiled is False
    saved.learner.lrr = 1.0  # anything else unknown is still refused
    with pytest.raises(Exception, match="lrr"):
        algo_from_node(saved)
