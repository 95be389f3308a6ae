"""Bad input fails before SUMO starts, with a message naming the key."""

from __future__ import annotations

import pytest

from kddrl_trl.envs import FakeHighwayEnv, SumoHighwayEnv, make_config, scenario_names, sim


@pytest.mark.parametrize(
    "kwargs, match",
    [
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
        ({"scenario": "mixed", "braking": {"probability": 0.0}}, "'braking.probability' = 0.0 must be in"),
        ({"scenario": "braking", "braking": {"probability": 1.5}}, "'braking.probability' = 1.5 must be in"),
    ],
)
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
    assert scenario_names() == ["baseline", "braking", "congested", "congested_text", "mixed"]
    assert make_config("braking").braking.probability == 1.0  # every episode, as the paper's
    mixed = make_config("mixed").braking
    assert mixed.enabled and mixed.probability == 0.5 and mixed.min_distance == 100.0
    assert make_config("congested").flow == pytest.approx(1.5 * 2325)  # Table A.1's flow + 50 % (default)
    assert make_config("congested_text").flow == pytest.approx(3 * 1329)  # §IV.D: 886 -> 1329 veh/h/lane
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


def test_a_run_saved_with_the_old_per_algo_compile_keys_loads_once_migrated():
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    from kddrl_trl.conf.schema import HierarchicalAlgo, algo_from_node
    from kddrl_trl.devtools.migrate_configs import migrate
    from kddrl_trl.factories import make_learner

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        cfg = compose(config_name="config")
    saved = OmegaConf.to_container(cfg.algo)  # as a run's config.yaml holds it, with the old compile keys
    saved["transforms"].update(compile="auto", aot=None)
    saved["learner"]["compile"] = "auto"
    with pytest.raises(Exception, match="compile"):  # unmigrated: refused, naming the key
        algo_from_node(OmegaConf.create(saved))
    assert migrate({"algo": saved}) == ["-algo.transforms.compile", "-algo.transforms.aot", "-algo.learner.compile"]
    algo = algo_from_node(OmegaConf.create(saved))
    assert isinstance(algo, HierarchicalAlgo) and algo.lc_period == 20
    assert make_learner(algo).compiled is False
    saved["learner"]["lrr"] = 1.0  # anything else unknown is still refused
    with pytest.raises(Exception, match="lrr"):
        algo_from_node(OmegaConf.create(saved))


def test_issue14_options_are_typed_and_checked():
    """Every safety / learning-signal option is a typed key; typos and bad values are refused."""
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    from kddrl_trl.conf.schema import algo_from_node

    assert make_config().reward == "paper" and make_config().ego_start == "entry"
    assert make_config(overrides={"reward": "safe", "ego_start": "window"}).reward == "safe"
    for key, bad in (("reward", "nice"), ("ego_start", "middle")):
        with pytest.raises(ValueError, match=key):
            make_config(overrides={key: bad})
    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        cfg = compose(config_name="config")
        ni = compose(config_name="config", overrides=["algo=ni"])
        rule = compose(config_name="config", overrides=["algo=idm_mobil", "algo.shield=ttc"])
        with pytest.raises(Exception, match="shieldd"):
            compose(config_name="config", overrides=["algo.shieldd=idm"])
    algo = algo_from_node(cfg.algo)
    assert algo.mobil_safety_mask and algo.lc_reward == "frames" and algo.shield == "none"
    assert algo.learner.td3.exploration_clip == 2.5 and algo.learner.d3qn.semi_mdp is False
    assert not algo_from_node(ni.algo).mobil_safety_mask and algo_from_node(rule.algo).shield == "ttc"
    for key, bad in (("shield", "cbf"), ("lc_reward", "mean")):
        node = OmegaConf.create(OmegaConf.to_container(cfg.algo))
        node[key] = bad
        with pytest.raises(ValueError, match=key):
            algo_from_node(node)
    # a run saved before these keys existed reads back as it ran: no mask, frame sums, no shield, unclipped noise
    old = OmegaConf.create(OmegaConf.to_container(cfg.algo))
    for key in ("mobil_safety_mask", "lc_reward", "shield", "shield_ttc"):
        del old[key]
    del old.learner.td3.exploration_clip
    algo = algo_from_node(old)
    assert not algo.mobil_safety_mask and algo.lc_reward == "frames" and algo.shield == "none"
    assert algo.learner.td3.exploration_clip is None


def test_a_mixed_run_is_evaluated_on_each_scenario_it_names():
    """``+scenario=mixed eval_scenarios=[baseline,braking]``: the final evaluations' env nodes are the run's with the
    other scenario's preset (only the keys the preset sets change); unknown or repeated scenarios are refused."""
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        cfg = compose(
            config_name="config",
            overrides=["+scenario=mixed", "eval_scenarios=[baseline,braking]", "env.num_roads=3", "env.flow_vph=2658"],
        )
        plain = compose(config_name="config")
    job = OmegaConf.to_object(cfg)
    assert job.env.scenario == "mixed" and job.env.braking.probability == 0.5
    assert job.eval_scenarios == ["baseline", "braking"] and OmegaConf.to_object(plain).eval_scenarios == []
    base, braking = job.env.with_scenario("baseline"), job.env.with_scenario("braking")
    assert base.scenario == "baseline" and not base.braking.enabled and base.braking.probability == 1.0
    assert braking.scenario == "braking" and braking.braking.enabled and braking.braking.probability == 1.0
    assert base.num_roads == braking.num_roads == 3 and base.flow_vph == braking.flow_vph == 2658  # the run's own
    congested = OmegaConf.to_object(compose_env("congested")).env.with_scenario("baseline")
    assert congested.flow_scale == 1.0
    for bad in ("[rainy]", "[braking,braking]"):
        with pytest.raises(Exception, match=r"eval_scenarios=\['"):
            OmegaConf.to_object(compose_env("mixed", f"eval_scenarios={bad}"))


def compose_env(scenario: str, *overrides: str):
    from hydra import compose, initialize_config_module

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        return compose(config_name="config", overrides=[f"+scenario={scenario}", *overrides])


LEARNING_ALGOS = ("kddrl", "d3qn_td3", "d3qn_td3_lg", "kddrl_same_clock", "ni", "peng", "d3qn_unified", "pasac_unified")


@pytest.mark.parametrize("name", LEARNING_ALGOS)
def test_state_extras_reach_every_learner_and_default_off(name):
    """``algo.state_extras`` (issue 14): off in every algo's config and in runs saved before the key; when set, the
    learner of every algo builds its states (and networks) with the features; a bad name is refused."""
    import torch
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    from kddrl_trl.conf.schema import algo_from_node
    from kddrl_trl.factories import make_learner

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        plain = compose(config_name="config", overrides=[f"algo={name}"])
        extras = compose(config_name="config", overrides=[f"algo={name}", "algo.state_extras=[ttc,thw]"])
    assert algo_from_node(plain.algo).state_extras == []
    old = OmegaConf.create(OmegaConf.to_container(plain.algo))
    del old["state_extras"]
    assert algo_from_node(old).state_extras == []  # a run saved before the key: no extras, as it ran
    bad = OmegaConf.create(OmegaConf.to_container(plain.algo))
    bad.state_extras = ["headway"]
    with pytest.raises(ValueError, match=r"algo.state_extras=\['headway'\]"):
        algo_from_node(bad)
    torch.manual_seed(0)
    learners = [make_learner(algo_from_node(node.algo)) for node in (plain, extras)]
    builders = [
        [m for m in (getattr(lr, "cf_state", None), getattr(lr, "state", None)) if m is not None][0] for lr in learners
    ]
    assert [b.module.extras for b in builders] == [(), ("thw", "ttc")]
    sizes = [sum(p.numel() for p in lr.parameters()) for lr in learners]
    assert sizes[1] > sizes[0]  # the first layers take the two extra inputs


@pytest.mark.parametrize("name", LEARNING_ALGOS)
@pytest.mark.parametrize("scenario", ["baseline", "braking"])
def test_the_plus_preset_sets_the_same_options_for_every_algo(name, scenario):
    """``+preset=plus`` (issue 14's best combination) changes the same option keys, to the same values, whatever
    the algo and scenario, and nothing else; the report names such a run by those options (so it pools with the
    screening runs of that configuration); a command-line key still wins over the preset."""
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    from kddrl_trl.conf.schema import algo_from_node
    from kddrl_trl.reporting.records import option_label

    extra = [] if scenario == "baseline" else [f"+scenario={scenario}"]
    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        plain = OmegaConf.to_container(compose(config_name="config", overrides=[f"algo={name}", *extra]), resolve=True)
        plus = OmegaConf.to_container(
            compose(config_name="config", overrides=[f"algo={name}", *extra, "+preset=plus"]), resolve=True
        )
        mine = compose(config_name="config", overrides=[f"algo={name}", *extra, "+preset=plus", "algo.shield=ttc"])
        assert option_label(plus, name, scenario) == "algo.shield=idm"
    assert algo_from_node(OmegaConf.create(plus["algo"])).shield == "idm" and mine.algo.shield == "ttc"
    plus["algo"]["shield"] = plain["algo"]["shield"]
    assert plus == plain  # nothing else changed


def test_a_scenario_preset_on_highwayenv_names_its_simulator():
    """``env=highwayenv +scenario=congested`` applies the preset (flow_scale 1.5: HighwayEnv's density) under the
    name ``highwayenv_congested``: its run folder and report rows never pool with SUMO's ``congested``; moved to
    another scenario (``eval_scenarios``), it keeps naming its simulator."""
    from testkit import compose_job

    hw = compose_job("env=highwayenv", "+scenario=congested")
    sumo = compose_job("+scenario=congested")
    assert (hw.env.scenario, hw.env.flow_scale) == ("highwayenv_congested", 1.5)
    assert (sumo.env.scenario, sumo.env.flow_scale) == ("congested", 1.5)
    assert compose_job("env=highwayenv").env.scenario == "highwayenv"
    moved = hw.env.with_scenario("baseline")
    assert (moved.scenario, moved.flow_scale) == ("highwayenv_baseline", 1.0)
    assert sumo.env.with_scenario("baseline").scenario == "baseline"


@pytest.mark.parametrize("preset", [[], ["+scenario=congested"]])
def test_report_names_highwayenv_runs_by_the_options_they_set(preset):
    """A HighwayEnv run is compared with its own simulator's defaults: with the default GAN weights (``auto``: those
    of HighwayEnv's traffic) it has no option label, with the SUMO weights it is a row of its own."""
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    from kddrl_trl.reporting.records import option_label

    def config(*overrides):
        with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
            cfg = compose(config_name="config", overrides=["env=highwayenv", *preset, *overrides])
        return OmegaConf.to_container(cfg, resolve=True)

    scenario = config()["env"]["scenario"]
    assert option_label(config(), "kddrl", scenario) == ""
    assert option_label(config("algo.transforms.weights=sumo"), "kddrl", scenario) == "algo.transforms.weights=sumo"
    assert option_label(config("algo.shield=idm"), "kddrl", scenario) == "algo.shield=idm"


def test_matmul_precision_is_checked_and_applied_by_every_job():
    """``matmul_precision=high`` (TF32 where the hardware has it) is set by ``make_job``, process-wide, and the next
    job sets its own (the default ``highest``); an unknown value is refused, naming the key."""
    import torch
    from hydra import compose, initialize_config_module

    from kddrl_trl.factories import make_job

    before = torch.get_float32_matmul_precision()
    try:
        with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
            make_job(compose(config_name="config", overrides=["matmul_precision=high"]))
            assert torch.get_float32_matmul_precision() == "high"
            make_job(compose(config_name="config"))
            assert torch.get_float32_matmul_precision() == "highest"
            with pytest.raises(Exception, match="matmul_precision"):
                make_job(compose(config_name="config", overrides=["matmul_precision=low"]))
    finally:
        torch.set_float32_matmul_precision(before)


def test_flush_denormal_is_applied_by_every_job_on_every_intra_op_thread():
    """``flush_denormal`` (on by default) flushes float32 denormals to zero in an operation split over two threads
    (the OpenMP pool already running); ``flush_denormal=false`` keeps them; each job sets its own."""
    import torch
    from hydra import compose, initialize_config_module

    from kddrl_trl.factories import make_job

    tiny = torch.finfo(torch.float32).tiny
    threads = torch.get_num_threads()
    torch.set_num_threads(2)

    def denormals() -> int:
        out = torch.full((1 << 22,), 3e-39) * 0.5  # split over both threads
        return int(((out != 0) & (out.abs() < tiny)).sum())

    try:
        torch.set_flush_denormal(False)  # as before any job (an earlier test's job may have set it)
        assert denormals() == 1 << 22  # the pool runs, denormals kept
        with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
            make_job(compose(config_name="config"))
            assert denormals() == 0
            make_job(compose(config_name="config", overrides=["flush_denormal=false"]))
            assert denormals() == 1 << 22
    finally:
        torch.set_flush_denormal(False)
        torch.set_num_threads(threads)


def test_the_idm_and_mobil_nodes_are_the_physics_parameters_as_floats():
    """``algo.idm`` / ``algo.mobil`` are written out as plain dataclasses; they must stay the physics parameters'
    fields with their defaults (paper Table A.1)."""
    from dataclasses import fields

    from kddrl_trl.conf.schema import IDMNode, MOBILNode
    from kddrl_trl.physics import IDMParams, MOBILParams

    for node, params in ((IDMNode, IDMParams), (MOBILNode, MOBILParams)):
        assert [(f.name, f.default) for f in fields(node)] == [(f.name, float(f.default)) for f in fields(params)]
        assert all(f.type == "float" for f in fields(node))


def test_every_schema_node_is_a_plain_dataclass_of_the_schema_module():
    """Every node an editor reads: a class written in ``conf/schema.py``, none built at run time."""
    import inspect
    from dataclasses import is_dataclass

    from kddrl_trl.conf import schema

    nodes = [o for o in vars(schema).values() if isinstance(o, type) and is_dataclass(o)]
    own = [o for o in nodes if o.__module__ != "kddrl_trl.conf.schema"]
    assert all(o.__module__.startswith("kddrl_trl.") and o.__module__ != "types" for o in own), own
    source = inspect.getsource(schema)
    for node in (o for o in nodes if o.__module__ == "kddrl_trl.conf.schema"):
        assert f"\nclass {node.__name__}(" in source or f"\nclass {node.__name__}:" in source, node.__name__
