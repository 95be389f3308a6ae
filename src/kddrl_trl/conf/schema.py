"""Typed schemas of the Hydra configs (registered in Hydra's ConfigStore by :mod:`kddrl_trl.conf`).

The YAML files hold the values and say why; these dataclasses hold the types and the ranges. Hydra refuses a
misspelt key or a value of the wrong type while it composes the config, naming the key (``train.batch_size_cf=abc``,
``algo.learner.d3qn.lrr=1``); the range checks (``__post_init__``) run once, when an entry point turns the
composed config into these objects (``OmegaConf.to_object``), before any simulator starts.

=====================  =================================================================================
``env``                :class:`EnvNode`: every :class:`~kddrl_trl.highway_config.HighwayConfig` field + ``num_roads``,
                       ``simulator`` (``sumo`` | ``highwayenv``), ``highwayenv`` (HighwayEnv's own options)
``algo`` (learning)    :class:`HierarchicalAlgo`: ``lc_period``, ``transforms``, ``learner{d3qn, td3 | ddpg, ...}``;
                       :class:`JointD3QNAlgo` (``d3qn_unified``), :class:`PASACAlgo` (``pasac_unified``): one agent
                       acting every frame (``lc_period`` 1), ``learner{...}``
``algo`` (rule-based)  :class:`RuleAlgo`: ``idm``, ``mobil`` (fields of the physics parameter dataclasses)
``train``              :class:`TrainConfig`: the Algorithm 1 loop of :class:`~kddrl_trl.training.Trainer`
``logger``             :class:`LoggerConfig`
``collector``          :class:`CollectorConfig`: how many env processes collect for ``train.py`` (``workers``), and
                       through which TorchRL backend (``process`` | ``ray``)
``train.py`` job       :class:`TrainJob`; ``evaluate.py`` job: :class:`EvaluateJob`
=====================  =================================================================================

Each option of the ``algo`` group names its schema first in its defaults list (``/hierarchical_schema@_here_``,
``/joint_d3qn_schema@_here_``, ``/pasac_schema@_here_`` or ``/rule_schema@_here_``), so one group types every kind of
algo. The schemas are stored outside the groups, so ``--help`` offers only the options a user can choose; the algo's
``kind`` says which it is, also in a run's saved ``config.yaml`` (:func:`algo_from_node`).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Any, Optional

from omegaconf import MISSING, DictConfig, OmegaConf

from ..choices import BEST_METRICS, CF_AGENTS, SHIPPED_TRAFFIC, check_backend, check_extras
from ..highway_config import SCENARIOS, HighwayConfig, switch_scenario
from ..highwayenv_options import HighwayEnvOptions, check_config
from ..protocol import MAX_WORKERS, check_disjoint, test_seed


def _at_least(prefix: str, node, low: int, *names: str) -> None:
    for name in names:
        value = getattr(node, name)
        if value < low:
            raise ValueError(f"{prefix}{name} must be >= {low}, got {value!r}")


#: ``env.simulator`` values: our SUMO highway (``conf/env/highway.yaml``), HighwayEnv (``conf/env/highwayenv.yaml``,
#: the optional extra ``.[highway]``, :mod:`kddrl_trl.envs.highwayenv`)
SIMULATORS = ("sumo", "highwayenv")


@dataclass
class EnvNode(HighwayConfig):
    """The ``env`` node: the highway config plus the number of roads simulated side by side, the simulator and, for
    HighwayEnv, its own options (:class:`~kddrl_trl.highwayenv_options.HighwayEnvOptions`; checked here, before any
    simulator starts, with the :class:`HighwayConfig` values HighwayEnv cannot honour)."""

    num_roads: int = 8
    simulator: str = "sumo"
    highwayenv: Optional[HighwayEnvOptions] = None

    def __post_init__(self) -> None:
        _at_least("env.", self, 1, "num_roads")
        if self.simulator not in SIMULATORS:
            raise ValueError(f"env.simulator={self.simulator!r}: known simulators are {', '.join(SIMULATORS)}")
        self.validate()
        if self.simulator == "highwayenv":
            self.highwayenv = check_config(self, self.highwayenv)

    def highway(self) -> HighwayConfig:
        """This node's :class:`HighwayConfig` (its scenario preset was applied by Hydra: no preset applies again)."""
        return HighwayConfig(**{f.name: getattr(self, f.name) for f in fields(HighwayConfig)})

    def with_scenario(self, scenario: str) -> "EnvNode":
        """This node on the traffic of another ``scenario``
        (:func:`~kddrl_trl.highway_config.switch_scenario`: the current preset's keys reset, ``scenario`` 's applied)."""
        return OmegaConf.to_object(
            OmegaConf.merge(OmegaConf.structured(EnvNode), switch_scenario(OmegaConf.structured(self), scenario))
        )


def _check_train(train) -> None:
    _at_least(
        "train.",
        train,
        1,
        "frames_per_env",
        "batch_size_cf",
        "batch_size_lc",
        "buffer_cf",
        "buffer_lc",
        "checkpoint_every",
        "n_steps",
    )
    _at_least("train.", train, 0, "warmup_frames", "updates_per_frame", "updates_per_decision", "eval_every")
    _at_least("train.", train, 1, "eval_episodes")
    if not 0.0 < train.priority_alpha <= 1.0:
        raise ValueError(f"train.priority_alpha must be in (0, 1], got {train.priority_alpha!r}")
    if not 0.0 <= train.priority_beta <= 1.0:
        raise ValueError(f"train.priority_beta must be in [0, 1], got {train.priority_beta!r}")
    if train.best_metric not in BEST_METRICS:
        raise ValueError(f"train.best_metric={train.best_metric!r}: known metrics are {', '.join(BEST_METRICS)}")


@dataclass
class LoggerConfig:
    """``logger``: CSV and TensorBoard (true | false | auto: when installed)."""

    csv: bool = MISSING
    tensorboard: Any = MISSING


@dataclass
class TrainConfig:
    """The ``train`` node (``conf/config.yaml``): collection, replay buffers, update ratios, checkpoints."""

    frames_per_env: int = MISSING
    warmup_frames: int = MISSING
    batch_size_cf: int = MISSING
    batch_size_lc: int = MISSING
    buffer_cf: int = MISSING
    buffer_lc: int = MISSING
    updates_per_frame: int = MISSING
    updates_per_decision: int = MISSING
    checkpoint_every: int = MISSING
    keep_buffers: bool = MISSING
    eval_every: int = MISSING
    eval_episodes: int = MISSING
    best_metric: str = MISSING
    n_steps: int = MISSING
    prioritized: bool = MISSING
    priority_alpha: float = MISSING
    priority_beta: float = MISSING

    def __post_init__(self) -> None:
        _check_train(self)


#: ``algo.transforms.weights`` values: the traffic the shipped GAN weights were trained on, or ``auto`` (that of
#: the env's simulator)
GAN_WEIGHTS = ("auto", *SHIPPED_TRAFFIC)


def _check_transforms(t) -> None:
    if t.weights not in GAN_WEIGHTS:
        raise ValueError(f"algo.transforms.weights={t.weights!r}: known values are {', '.join(GAN_WEIGHTS)}")


@dataclass
class TransformsConfig:
    """``algo.transforms``: options of :func:`~kddrl_trl.transforms.make_kddrl_transforms` (``enabled=false``: none);
    ``mobil_criteria``: add :class:`~kddrl_trl.transforms.MOBILCriteria` (Peng et al.); ``weights``: the shipped GAN
    weights used without a checkpoint path (``auto``: those trained on the env simulator's traffic);
    ``event_oracle``: the braking car's key gaps from its script (:class:`~kddrl_trl.transforms.EventOracleKeyGaps`,
    the braking study's oracle, not the paper's method)."""

    enabled: bool = MISSING
    trajgan: bool = MISSING
    priors: bool = MISSING
    num_samples: int = MISSING
    reduce: str = MISSING
    trajgan_checkpoint: Optional[str] = MISSING
    lcgan_checkpoint: Optional[str] = MISSING
    mobil_criteria: bool = MISSING
    weights: str = MISSING
    event_oracle: bool = MISSING

    def __post_init__(self) -> None:
        _check_transforms(self)


@dataclass
class D3QNConfig:
    """``algo.learner.d3qn``: :func:`~kddrl_trl.objectives.make_d3qn` options and the learning rate."""

    hidden: list[int] = MISSING
    dueling: bool = MISSING
    double: bool = MISSING
    gamma: float = MISSING
    tau: float = MISSING
    lr: float = MISSING
    eps_init: float = MISSING
    eps_end: float = MISSING
    eps_decisions: int = MISSING
    semi_mdp: bool = MISSING


@dataclass
class TD3Config:
    """``algo.learner.td3``: :func:`~kddrl_trl.objectives.make_td3` options and the learning rates."""

    hidden: list[int] = MISSING
    gamma: float = MISSING
    tau: float = MISSING
    actor_lr: float = MISSING
    critic_lr: float = MISSING
    policy_noise: float = MISSING
    noise_clip: float = MISSING
    policy_delay: int = MISSING
    exploration_sigma: float = MISSING
    exploration_clip: Optional[float] = None


@dataclass
class DDPGConfig:
    """``algo.learner.ddpg``: :func:`~kddrl_trl.objectives.make_ddpg` options and the learning rates."""

    hidden: list[int] = MISSING
    gamma: float = MISSING
    tau: float = MISSING
    actor_lr: float = MISSING
    critic_lr: float = MISSING
    exploration_sigma: float = MISSING
    exploration_clip: Optional[float] = None


def _check_learner(learner) -> None:
    if learner.cf_agent not in CF_AGENTS:
        raise ValueError(f"algo.learner.cf_agent={learner.cf_agent!r}: known agents are {', '.join(CF_AGENTS)}")
    if getattr(learner, learner.cf_agent) is None:
        raise ValueError(
            f"algo.learner.cf_agent={learner.cf_agent}: the algo.learner.{learner.cf_agent} node is missing"
        )


@dataclass
class LearnerConfig:
    """``algo.learner``: keyword arguments of :class:`~kddrl_trl.training.HierarchicalLearner`."""

    cf_agent: str = MISSING
    mobil_criteria: bool = MISSING
    priors: bool = MISSING
    key_gaps: bool = MISSING
    embed_dim: int = MISSING
    embed_hidden: int = MISSING
    embed_lr: float = MISSING
    d3qn: D3QNConfig = MISSING
    td3: Optional[TD3Config] = None
    ddpg: Optional[DDPGConfig] = None

    def __post_init__(self) -> None:
        _check_learner(self)


def _check_levels(learner) -> None:
    _at_least("algo.learner.", learner, 2, "num_levels")
    if not learner.high > learner.low:
        raise ValueError(f"algo.learner: low < high needed, got [{learner.low}, {learner.high}]")


@dataclass
class JointD3QNLearnerConfig:
    """``algo.learner`` of ``d3qn_unified``: keyword arguments of :class:`~kddrl_trl.training.JointD3QNLearner`."""

    num_levels: int = MISSING
    low: float = MISSING
    high: float = MISSING
    d3qn: D3QNConfig = MISSING

    def __post_init__(self) -> None:
        _check_levels(self)


@dataclass
class PASACConfig:
    """``algo.learner.pasac``: :func:`~kddrl_trl.objectives.make_pasac` options and the learning rates."""

    hidden: list[int] = MISSING
    gamma: float = MISSING
    tau: float = MISSING
    actor_lr: float = MISSING
    critic_lr: float = MISSING
    alpha_lr: float = MISSING
    alpha_init: float = MISSING
    alpha_min: float = MISSING
    alpha_max: float = MISSING
    target_entropy_lane: float = MISSING
    target_entropy_param: float = MISSING
    low: float = MISSING
    high: float = MISSING


@dataclass
class PASACLearnerConfig:
    """``algo.learner`` of ``pasac_unified``: keyword arguments of :class:`~kddrl_trl.training.PASACLearner`."""

    pasac: PASACConfig = MISSING


#: ``algo.shield`` values: no shield, the IDM interaction bound, the TTC bound, RSS's worst-case bound with its
#: lane-change gap check (:class:`~kddrl_trl.transforms.SafetyShield`, :class:`~kddrl_trl.transforms.RSSLaneMask`)
SHIELDS = ("none", "idm", "ttc", "rss")
#: ``algo.shield_buffer`` values: buffer L stores the executed action, or the agent's own command (the shield as
#: part of the env; what the correction signal ``algo.shield_penalty`` needs to reach the actor)
SHIELD_BUFFERS = ("executed", "command")
#: ``algo.lc_reward`` values (:class:`~kddrl_trl.collectors.MacroTransitionWriter`): Algorithm 1 lines 26/35 sum
#: the per-frame r_D3QN over the interval; §III.G computes it once "at each 2-second decision step"
LC_REWARDS = ("frames", "decision")


@dataclass
class SafetyOptions:
    """Options every algo has, learning or rule-based. Schema defaults = how runs saved before these keys
    existed behaved; the algo YAMLs set the project's defaults (README, "Safety and learning-signal options")."""

    shield: str = "none"  # car-following shield: none | idm | ttc | rss (a_exec = min(a_agent, a_safe))
    shield_ttc: float = 3.0  # s, time-to-collision below which the ttc shield bounds the acceleration
    shield_penalty: float = 0.0  # per m/s²: the car-following reward loses penalty x (a_agent - a_exec) (0: none)
    shield_buffer: str = "executed"  # what buffer L stores as the action: executed (a_exec) | command (a_agent)

    def _check_safety(self) -> None:
        if self.shield not in SHIELDS:
            raise ValueError(f"algo.shield={self.shield!r}: known shields are {', '.join(SHIELDS)}")
        if not self.shield_ttc > 0:
            raise ValueError(f"algo.shield_ttc must be > 0 (s), got {self.shield_ttc!r}")
        if not self.shield_penalty >= 0:
            raise ValueError(
                f"algo.shield_penalty must be >= 0 (reward per m/s² of correction), got {self.shield_penalty!r}"
            )
        if self.shield_buffer not in SHIELD_BUFFERS:
            raise ValueError(f"algo.shield_buffer={self.shield_buffer!r}: known values are {', '.join(SHIELD_BUFFERS)}")
        if self.shield_penalty and self.shield == "none":
            raise ValueError(
                "algo.shield_penalty > 0 needs a shield (algo.shield=idm|ttc|rss): nothing corrects the command"
            )


@dataclass
class LearningAlgo(SafetyOptions):
    """What every learning algo has: a lane-change clock, the env's transforms and the safety and learning-signal
    safety and learning-signal options (``kind`` picks the learner)."""

    name: str = MISSING
    kind: str = MISSING
    lc_period: int = MISSING
    mobil_safety_mask: bool = False  # AND MOBIL's safety check (Eq. 20-21) into ("lc","action_mask") (§III.C.2)
    lc_reward: str = "frames"  # D3QN macro reward: frames (Algorithm 1 line 35) | decision (§III.G)
    # features appended to every agent's state (not in the paper): thw (time headway), ttc (time to collision)
    state_extras: list[str] = field(default_factory=list)
    transforms: TransformsConfig = MISSING

    def __post_init__(self) -> None:
        _at_least("algo.", self, 1, "lc_period")
        self._check_safety()
        check_extras(self.state_extras)
        if self.lc_reward not in LC_REWARDS:
            raise ValueError(f"algo.lc_reward={self.lc_reward!r}: known readings are {', '.join(LC_REWARDS)}")


@dataclass
class HierarchicalAlgo(LearningAlgo):
    """A hierarchical learning algo: KDDRL and its configuration-only comparison systems (ni, peng, ablations)."""

    kind: str = "hierarchical"
    learner: LearnerConfig = MISSING


@dataclass
class UnifiedAlgo(LearningAlgo):
    """One agent choosing both actions on every frame (the paper's unified frameworks): ``lc_period`` is 1."""

    lc_period: int = 1

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.lc_period != 1:
            raise ValueError(
                f"algo.lc_period must be 1 for algo={self.name} (one agent deciding both actions every "
                f"frame), got {self.lc_period!r}"
            )


@dataclass
class JointD3QNAlgo(UnifiedAlgo):
    """``algo=d3qn_unified``: one D3QN over (lane command x acceleration level)."""

    kind: str = "joint_d3qn"
    learner: JointD3QNLearnerConfig = MISSING


@dataclass
class PASACAlgo(UnifiedAlgo):
    """``algo=pasac_unified``: one parameterised-action SAC agent."""

    kind: str = "pasac"
    learner: PASACLearnerConfig = MISSING


@dataclass
class IDMNode:
    """``algo.idm``: :class:`~kddrl_trl.physics.IDMParams` as floats (defaults: paper Table A.1; a test keeps the two
    equal)."""

    v0: float = 130 / 3.6
    T: float = 1.5
    s0: float = 5.0
    a_max: float = 5.0
    b: float = 4.0
    delta: float = 4.0
    length: float = 5.0


@dataclass
class MOBILNode:
    """``algo.mobil``: :class:`~kddrl_trl.physics.MOBILParams` as floats (defaults: paper Table A.1; a test keeps
    the two equal)."""

    politeness: float = 0.1
    threshold: float = 0.3
    b_safe: float = 4.0
    y_safe: float = 5.0


@dataclass
class RuleAlgo(SafetyOptions):
    """A rule-based algo: MOBIL lane choice + IDM car following (``algo=idm_mobil``)."""

    name: str = MISSING
    kind: str = "rule"
    lc_period: int = 1
    idm: IDMNode = field(default_factory=IDMNode)
    mobil: MOBILNode = field(default_factory=MOBILNode)

    def __post_init__(self) -> None:
        self._check_safety()


#: the algo schema of each ``algo.kind``
ALGO_SCHEMAS = {"hierarchical": HierarchicalAlgo, "joint_d3qn": JointD3QNAlgo, "pasac": PASACAlgo, "rule": RuleAlgo}


def algo_from_node(node: DictConfig) -> LearningAlgo | RuleAlgo:
    """The typed algo of an ``algo`` node read back from a run's saved ``config.yaml`` (a run saved by an earlier
    version is migrated first: ``python -m kddrl_trl.devtools.migrate_configs``)."""
    node = OmegaConf.create(OmegaConf.to_container(node))
    kind = node.get("kind")
    if kind not in ALGO_SCHEMAS:
        raise ValueError(f"algo.kind={kind!r}: known kinds are {', '.join(ALGO_SCHEMAS)}")
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(ALGO_SCHEMAS[kind]), node))


def unknown_keys(node: DictConfig, obj: Any, prefix: str = "") -> list[str]:
    """The keys of a composed config ``node`` that its typed object ``obj`` (``OmegaConf.to_object``) has no field
    for, as dotted paths: a key added with ``+`` (``+episods=5``) passes Hydra's struct check and would otherwise be
    dropped without a word. Nested typed nodes are checked too; free-form ones (dicts, lists) are not."""
    if not is_dataclass(obj) or not isinstance(node, DictConfig):
        return []
    names = {f.name for f in fields(obj)}
    found = []
    for key in node.keys():
        if key not in names:
            found.append(f"{prefix}{key}")
        elif OmegaConf.is_dict(node._get_node(key)):
            found += unknown_keys(node[key], getattr(obj, str(key)), f"{prefix}{key}.")
    return found


def check_device(device: str) -> None:
    """``device`` must be ``auto``, ``cpu``, ``cuda`` or ``cuda:N`` (whether a GPU is there is checked by
    :func:`kddrl_trl.factories.make_device`)."""
    if not (device in ("auto", "cpu", "cuda") or re.fullmatch(r"cuda:\d+", str(device))):
        raise ValueError(f"device must be auto, cpu, cuda or cuda:N, got {device!r}")


#: ``matmul_precision`` values (``torch.set_float32_matmul_precision``): ``highest``, IEEE float32 matmuls (torch's
#: default); ``high``, TensorFloat-32 where the hardware has it (NVIDIA GPUs since Ampere), faster, with a 10-bit
#: mantissa in the products; ``medium``, bfloat16 products where supported
MATMUL_PRECISIONS = ("highest", "high", "medium")
#: which evaluation episodes ``video=true`` records (:class:`kddrl_trl.eval.trace.TraceRecorder`)
VIDEO_SELECTS = ("any", "collisions")


@dataclass
class Job:
    """What every entry point that runs a policy has: seed, evaluation size, the env, logging, compiling."""

    seed: int = MISSING
    eval_episodes: int = MISSING
    eval_seed: Optional[int] = None  # env seed of the evaluation; null: seed + protocol.TEST_OFFSET
    video: bool = False  # record evaluation episodes: traces/*.json (Fig. 14) and videos/*.mp4
    video_episodes: int = 3
    video_select: str = "any"  # any | collisions: which evaluation episodes the video records (collisions: only those)
    progress: bool = MISSING
    compile: Any = MISSING  # true | false | auto: torch.compile the fused transform stack and the learner update
    env: EnvNode = MISSING
    logger: LoggerConfig = MISSING
    device: str = "auto"  # auto | cpu | cuda (cuda:N): the learner's networks, sampled batches and updates
    cudagraphs: Any = "auto"  # true | false | auto (on with a CUDA learner): CudaGraphModule around the updates
    matmul_precision: str = "highest"  # torch.set_float32_matmul_precision: highest | high (TF32) | medium
    flush_denormal: bool = True  # torch.set_flush_denormal: CPU float32 values under 1.18e-38 taken as zero
    torch_threads: Any = "auto"  # auto | N: torch's CPU threads (auto: the free cores, followed while training)
    gui: bool = False  # the final evaluation in sumo-gui: a live view of road 0's ego in real time (needs a display)

    def __post_init__(self) -> None:
        _at_least("", self, 1, "eval_episodes", "video_episodes")
        if self.gui and getattr(self.env, "simulator", "sumo") != "sumo":
            raise ValueError(
                f"gui=true drives sumo-gui: env=highway (SUMO) only, got env.simulator={self.env.simulator}"
            )
        if self.gui and not os.environ.get("DISPLAY"):
            raise ValueError(
                "gui=true: sumo-gui needs a display and DISPLAY is not set; on a machine without one, run the "
                "command under a virtual display: xvfb-run -a python -m ... (Debian's xvfb package)"
            )
        if str(self.torch_threads) != "auto" and not (
            isinstance(self.torch_threads, int) and not isinstance(self.torch_threads, bool) and self.torch_threads >= 1
        ):
            raise ValueError(f"torch_threads must be auto or a positive integer, got {self.torch_threads!r}")
        if self.video_select not in VIDEO_SELECTS:
            raise ValueError(f"video_select={self.video_select!r}: known values are {', '.join(VIDEO_SELECTS)}")
        if self.matmul_precision not in MATMUL_PRECISIONS:
            raise ValueError(
                f"matmul_precision={self.matmul_precision!r}: known values are {', '.join(MATMUL_PRECISIONS)}"
            )
        if self.compile not in (True, False, "auto"):
            raise ValueError(f"compile must be true, false or auto, got {self.compile!r}")
        check_device(self.device)
        if self.cudagraphs not in (True, False, "auto"):
            raise ValueError(f"cudagraphs must be true, false or auto, got {self.cudagraphs!r}")
        if self.cudagraphs is True and not str(self.device).startswith(("cuda", "auto")):
            raise ValueError(f"cudagraphs=true needs device=cuda (or auto on a GPU machine), got device={self.device}")


@dataclass
class CollectorConfig:
    """The ``collector`` node of ``train.py``: ``workers`` env processes, each its own simulator, K roads
    (``env.num_roads``) and transform stack, collecting through TorchRL's multi-process collector with ``backend``
    (``process``: local processes; ``ray``: Ray actors, the optional extra ``.[ray]``; checked here, before any
    simulator starts). ``workers=1`` with ``process`` runs the env in the learner process
    (:meth:`kddrl_trl.collectors.MultiTimescaleCollector.from_env`); worker seeds: :mod:`kddrl_trl.protocol`.
    ``sync=false``: one worker process collects while the learner updates
    (:class:`~kddrl_trl.collectors.OverlappedCollector`; one batch more policy lag, runs still repeat exactly)."""

    workers: int = 1
    backend: str = "process"
    sync: bool = True

    def __post_init__(self) -> None:
        _at_least("collector.", self, 1, "workers")
        if self.workers > MAX_WORKERS:
            raise ValueError(
                f"collector.workers must be <= {MAX_WORKERS} (each worker's env seeds stay below the "
                f"validation seed, kddrl_trl/protocol.py), got {self.workers}"
            )
        check_backend(self.backend)
        if not self.sync and (self.workers != 1 or self.backend != "process"):
            raise ValueError(
                "collector.sync=false runs one worker process: it needs collector.workers=1 and "
                f"collector.backend=process, got workers={self.workers}, backend={self.backend}"
            )


@dataclass
class TrainJob(Job):
    """``conf/config.yaml``: ``python -m kddrl_trl.train``."""

    episodes: int = MISSING
    resume: Any = MISSING  # false | true | a run folder
    train: TrainConfig = MISSING
    algo: Any = MISSING  # a LearningAlgo or RuleAlgo, typed by the option's own schema
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    # scenarios of the final evaluation ([]: the training scenario); each is written to <run>/final__<scenario>/
    eval_scenarios: list[str] = field(default_factory=list)
    # a seed batch: these seeds' learners trained in one process, each into <run>/<scenario>__<algo>__<seed>/
    # (kddrl_trl/training/seed_batch_trainer.py); null: one run of ``seed``
    seeds: Optional[list[int]] = None

    def __post_init__(self) -> None:
        super().__post_init__()
        _at_least("", self, 1, "episodes")
        if self.seeds is not None:
            self._check_seed_batch()
        unknown = [s for s in self.eval_scenarios if s not in SCENARIOS]
        if unknown or len(set(self.eval_scenarios)) != len(self.eval_scenarios):
            raise ValueError(
                f"eval_scenarios={list(self.eval_scenarios)}: each must be one of "
                f"{', '.join(sorted(SCENARIOS))}, at most once"
            )
        for seed in self.seeds or [self.seed]:
            check_disjoint("eval_seed", test_seed(seed, self.eval_seed), seed, self.episodes, self.collector.workers)

    def seed_jobs(self) -> list[TrainJob]:
        """A seed batch's seeds, each as the job of its run alone (``seed`` set, ``seeds`` null), in batch order."""
        return [replace(self, seed=int(s), seeds=None) for s in self.seeds]

    def _check_seed_batch(self) -> None:
        """A seed batch trains hierarchical learners (the batched learner of ``modules/seed_batch.py``) on one env in
        this process, with uniform replay, each seed evaluated on its training scenario, on its own test traffic;
        distinct seeds, each with the training, validation and test seeds a run of its own has (``protocol.py``)."""
        seeds = list(self.seeds)
        if not seeds or len(set(seeds)) != len(seeds) or any(isinstance(s, bool) or s < 0 for s in seeds):
            raise ValueError(f"seeds={seeds}: a seed batch needs one or more distinct seeds >= 0")
        kind = getattr(self.algo, "kind", "rule")
        if kind != "hierarchical":
            raise ValueError(
                f"seeds={seeds}: a seed batch trains the hierarchical learners (algo=kddrl, d3qn_td3, ...); "
                f"algo={self.algo.name} is of kind {kind!r}: run its seeds as a sweep (-m seed=...)"
            )
        refused = {
            "collector.workers": (self.collector.workers, 1),
            "collector.backend": (self.collector.backend, "process"),
            "collector.sync": (self.collector.sync, True),
            "train.prioritized": (self.train.prioritized, False),
            "eval_scenarios": (list(self.eval_scenarios), []),
            "video": (self.video, False),  # (a seed's folder: python -m kddrl_trl.evaluate run=<it> video=true)
            "gui": (self.gui, False),
        }
        for key, (value, needed) in refused.items():
            if value != needed:
                raise ValueError(f"seeds={seeds}: a seed batch runs with {key}={needed}, got {key}={value}")
        if self.eval_seed is not None:
            raise ValueError(
                f"seeds={seeds}: each seed's test traffic is its own (eval_seed=null), got {self.eval_seed}"
            )


@dataclass
class ReportJob:
    """``conf/report.yaml``: ``python -m kddrl_trl.report <run or sweep folders ...> [out=<folder>]``."""

    runs: list[str] = field(default_factory=list)
    out: str = "report"
    lcgan_metrics: Optional[str] = None  # JSON of lcGAN test metrics for Figs. 16-17 (default: beside the weights)
    lcgan_figures: bool = True  # false: Figs. 16-17 not drawn (they show the lcGAN, not the runs)
    space_time_figures: bool = True  # false: Fig. 14 not drawn (another report of the same runs draws it)
    claims: Optional[str] = None  # a study's claims file, tested (reporting/claims.py, reporting/verdict.py)
    title: Optional[str] = None  # the heading of report.md (default "kddrl_trl report")

    def __post_init__(self) -> None:
        if not self.runs:
            raise ValueError("report: name at least one run or sweep folder (python -m kddrl_trl.report <dir> ...)")


@dataclass
class EvaluateJob(Job):
    """``conf/evaluate.yaml``: ``python -m kddrl_trl.evaluate``."""

    run: str = MISSING
    checkpoint: str = "latest"  # latest | best (the best validation score during training)
    shield: str | None = None  # null: the run's own shield | none | idm | ttc | rss: the trained policy under it

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.checkpoint not in ("latest", "best"):
            raise ValueError(f"checkpoint must be latest or best, got {self.checkpoint!r}")
        if self.shield is not None and self.shield not in SHIELDS:
            raise ValueError(f"shield={self.shield!r}: known shields are {', '.join(SHIELDS)} (null: the run's own)")
