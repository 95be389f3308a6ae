"""Hydra configs of kddrl_trl, shipped inside the package (found from an installed package too).

Importing this module registers in Hydra's ConfigStore:

* the typed schemas of :mod:`kddrl_trl.conf.schema` (``env/highway_schema``, ``algo/hierarchical_schema``,
  ``algo/joint_d3qn_schema``, ``algo/pasac_schema``, ``algo/rule_schema``, ``logger/logger_schema``, ``train_job``,
  ``evaluate_job``, ``report_job``), so a misspelt key or a wrong type fails at composition, naming the key;
* the ``scenario`` group: one option per preset of :data:`kddrl_trl.highway_config.SCENARIOS` (the same
  presets ``SumoHighwayEnv(scenario=...)`` applies), an ``env:`` block in the global package, appended with
  ``+scenario=<name>``;
* the resolvers of :mod:`kddrl_trl.conf.resolvers` (run folders chosen before Hydra creates them).
"""

from hydra.core.config_store import ConfigStore

from ..highway_config import SCENARIOS
from . import resolvers
from .schema import (
    EnvNode,
    EvaluateJob,
    HierarchicalAlgo,
    JointD3QNAlgo,
    LoggerConfig,
    PASACAlgo,
    ReportJob,
    RuleAlgo,
    TrainJob,
)


def register() -> None:
    store = ConfigStore.instance()
    store.store(name="highway_schema", node=EnvNode)
    store.store(name="hierarchical_schema", node=HierarchicalAlgo)
    store.store(name="joint_d3qn_schema", node=JointD3QNAlgo)
    store.store(name="pasac_schema", node=PASACAlgo)
    store.store(name="rule_schema", node=RuleAlgo)
    store.store(name="logger_schema", node=LoggerConfig)
    store.store(name="train_job", node=TrainJob)
    store.store(name="evaluate_job", node=EvaluateJob)
    store.store(name="report_job", node=ReportJob)
    for name, preset in SCENARIOS.items():
        label = f"${{kddrl_scenario:{name},${{env.simulator}}}}"  # highwayenv_<name> on HighwayEnv
        store.store(group="scenario", name=name, node={"env": {"scenario": label, **preset}}, package="_global_")
    resolvers.register()


register()
