"""Builders of the parts the entry points wire (``train.py``, ``evaluate.py``, ``pretrain.py``), as TorchRL's
``sota-implementations/*/utils.py`` do: each ``make_*`` turns a typed config node (:mod:`kddrl_trl.conf.schema`)
into one part, and holds no algorithm. The final evaluation ``train.py`` and ``evaluate.py`` share runs in
:mod:`kddrl_trl.eval.final` on the env of :func:`make_test_env`; the datasets of the generative models are built by
:mod:`kddrl_trl.data.gan_datasets`.

=============================  ===========================================================================
:func:`make_device`            ``auto`` | ``cpu`` | ``cuda``
:func:`make_job`               the typed job of a config; a refused one leaves no run folder behind
:func:`make_torch_settings`    a job's process-wide torch arithmetic, for every process it starts
:func:`make_run_dir`           the folder Hydra made for this run, and whether it resumes
:func:`make_logger`            TorchRL CSV (+ TensorBoard) loggers of a run folder
:func:`make_transforms`        the algo's predictive-state transforms, safety mask, :class:`DecisionClock`, shield
:func:`make_env`               the batched highway env (SUMO, HighwayEnv or the fake) with the algo's transforms
:func:`make_env_factories`     one picklable env factory per collection worker (``collector.workers``), seeded
:func:`make_learner`           the :class:`~kddrl_trl.training.Learner` of a learning algo (by ``algo.kind``)
:func:`make_policy`            the acting policy of any algo, exploration off
:func:`make_buffers`           replay buffers L (frames) and H (macro-transitions), on the learner's device
:func:`make_collector`         the two-clock collector filling both buffers (one env here, or N worker processes)
:func:`make_evaluator`         the periodic evaluation during training (validation traffic, a worker process)
:func:`make_test_env`          the env of a final evaluation (the test seed)
:func:`make_trained_learner`   a training run's learner, from its latest (or best) checkpoint
=============================  ===========================================================================

``compile`` (the top-level ``compile: true | false | auto`` key) reaches the two compile sites: the fused
transform stack (:func:`make_transforms`) and the learner's update (:func:`make_learner`); a learner that
only acts is built with ``compile=False``. ``device`` (``auto | cpu | cuda``) places the learner
(:func:`make_learner`, :func:`make_trained_learner`) and its buffers (:func:`make_buffers`), ``cudagraphs`` graphs
its compiled updates on CUDA; the env, SUMO, the transforms and acting stay on the CPU.
"""

from __future__ import annotations

import importlib.util
import logging
from collections.abc import Sequence
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path

import torch
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf
from torchrl.data import TensorDictReplayBuffer
from torchrl.envs import Compose, EnvBase, TransformedEnv
from torchrl.record.loggers import CSVLogger, TensorboardLogger

from . import keys as K
from .baselines import IDMMobilPolicy
from .collectors import MacroTransitionWriter, MultiTimescaleCollector
from .collectors.nstep import NStepReturns
from .collectors.workers import WorkerEnv
from .compiling import resolve_compile, resolve_cudagraphs
from .conf.schema import (
    LC_REWARDS,
    CollectorConfig,
    EnvNode,
    Job,
    LearningAlgo,
    LoggerConfig,
    RuleAlgo,
    TrainConfig,
    TrainJob,
    algo_from_node,
    unknown_keys,
)
from .envs.fake import FakeHighwayEnv
from .envs.highwayenv import HighwayEnvAdapter
from .envs.sumo_env import SumoHighwayEnv
from .eval.periodic import PeriodicEvaluator
from .eval.seed_validation import SeedBatchValidation
from .generative import shipped_traffic
from .highway_config import HighwayConfig
from .loggers import MultiLogger
from .modules.seed_batch import load_seeds
from .physics import IDMParams, MOBILParams
from .physics.rss import RSSParams
from .policies import POLICY_FILE
from .process_settings import TorchSettings, seed_everything
from .protocol import test_seed, validation_seed, worker_seed
from .run_folder import (
    RunFolder,
    best_checkpoint,
    checkpoint_dir,
    no_folder_if_refused,
    resume_requested,
    run_checkpoint,
    trained_run,
)
from .threads import ThreadGovernor
from .training import (
    HierarchicalLearner,
    JointD3QNLearner,
    Learner,
    PASACLearner,
    load_latest_training_checkpoint,
    load_policy,
    load_training_checkpoint,
    make_buffer,
)
from .training.seed_batch_trainer import SeedBatchTrainer
from .training.seed_split import SeedView
from .training.trainer import Trainer
from .transforms import (
    DecisionClock,
    MOBILCriteria,
    MOBILSafetyMask,
    RSSLaneMask,
    SafetyShield,
    make_kddrl_transforms,
)

#: the learner of each learning ``algo.kind`` (:data:`kddrl_trl.conf.schema.ALGO_SCHEMAS`)
LEARNERS = {"hierarchical": HierarchicalLearner, "joint_d3qn": JointD3QNLearner, "pasac": PASACLearner}


def make_device(name: str) -> torch.device:
    """``auto``: CUDA when available, else the CPU; ``cuda`` (``cuda:N``) fails at once, clearly, without a CUDA
    device."""
    name = str(name)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise SystemExit(
            f"device={name} but no CUDA device is available here (torch {torch.__version__}, "
            "torch.cuda.is_available() is False): use device=auto or device=cpu"
        )
    return torch.device(name)


def make_job(cfg: DictConfig):
    """The typed job of a composed entry-point config (``OmegaConf.to_object``: types and ranges checked once,
    before any simulator starts). A refused config raises, naming the key, and removes the output folder Hydra
    already made for it (:func:`kddrl_trl.run_folder.no_folder_if_refused`): a bad value leaves no empty run folder.
    A job's top-level knobs are resolved here, once, and the parts receive the results: ``device``
    (:func:`make_device`, so ``device=cuda`` without a GPU stops at once; as ``job.torch_device``), ``compile``
    and ``cudagraphs`` (bools, :func:`kddrl_trl.compiling.resolve_compile` / ``resolve_cudagraphs``); and
    ``matmul_precision`` and ``flush_denormal`` are applied to this process (:func:`make_torch_settings`; process-wide:
    set by every job, so none inherits another's), and ``torch_threads`` (:func:`make_threads`, as ``job.threads``)."""
    with no_folder_if_refused():
        job = OmegaConf.to_object(cfg)
        unknown = unknown_keys(cfg, job)
        if unknown:
            raise ValueError(
                f"unknown config key(s) {', '.join(unknown)}: not in the schema (a '+' adds a key Hydra cannot check; "
                "check its spelling, or see --help / docs/usage.md for the keys)"
            )
        if hasattr(job, "device"):
            job.torch_device = make_device(job.device)
        if hasattr(job, "compile"):
            # the episodes it compiles for: a training job's training episodes, an evaluation's test episodes
            episodes = getattr(job, "episodes", getattr(job, "eval_episodes", None))
            job.compile = resolve_compile(job.compile, episodes)
        if hasattr(job, "cudagraphs"):
            job.cudagraphs = resolve_cudagraphs(job.cudagraphs, job.torch_device)
        if hasattr(job, "matmul_precision"):
            make_torch_settings(job).apply()
        if hasattr(job, "torch_threads"):
            job.threads = make_threads(job)
        return job


def make_threads(job: Job) -> ThreadGovernor:
    """The job's torch threads (``torch_threads``, :mod:`kddrl_trl.threads`), applied now and followed while it
    trains; a collection worker that runs beside the updates (``collector.sync=false``) counts as busy."""
    collector = getattr(job, "collector", None)
    overlapped = collector is not None and not collector.sync
    return ThreadGovernor(job.torch_threads, workers=int(overlapped))


def make_torch_settings(job: Job) -> TorchSettings:
    """The job's ``matmul_precision`` and ``flush_denormal``, which :func:`make_job` applies to the job's process
    and each worker process the job starts applies to its own (:func:`make_env_factories`,
    :func:`make_evaluator`): :class:`~kddrl_trl.process_settings.TorchSettings`."""
    return TorchSettings(job.matmul_precision, job.flush_denormal)


def make_run_dir(resume) -> tuple[Path, bool]:
    """The output folder Hydra made for this run and whether it resumes. The folder was chosen once, while the
    config was composed (:mod:`kddrl_trl.conf.resolvers`: the resumed run's or sweep's own folder, or a new one);
    a run resumes when its folder holds a checkpoint. A job of a resumed sweep (``-m ... resume=true``) whose
    folder holds none starts afresh: it never reached its first checkpoint."""

    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    resuming = run_checkpoint(run_dir) is not None
    if resume_requested(resume) and not resuming and hydra_cfg.mode != RunMode.MULTIRUN:
        raise SystemExit(f"resume={resume}: {run_dir} holds no checkpoint")
    return run_dir, resuming


def make_logger(cfg: LoggerConfig, run_dir: Path, exp_name: str = "logs") -> MultiLogger:
    """CSV logger always (``cfg.csv``); TensorBoard when installed (``tensorboard: auto``) or asked."""
    loggers = [CSVLogger(exp_name=exp_name, log_dir=str(run_dir))] if cfg.csv else []
    installed = importlib.util.find_spec("tensorboard") is not None
    tb = installed if str(cfg.tensorboard).lower() == "auto" else cfg.tensorboard
    if tb and not installed:
        logging.getLogger(__name__).warning("logger.tensorboard=true but tensorboard is not installed: CSV only")
    elif tb:
        loggers.append(TensorboardLogger(exp_name=exp_name, log_dir=str(run_dir)))
    return MultiLogger(loggers)


def make_transforms(
    algo: LearningAlgo | RuleAlgo, seed: int, highway: HighwayConfig, compile: bool = False, simulator: str = "sumo"
) -> Compose:
    """The env-side transforms of ``algo``, in this order: a learning algo's predictive-state transforms of
    ``algo.transforms`` (none with ``enabled: false``; ``weights: auto`` takes the GAN weights trained on the traffic of
    ``simulator``, :func:`kddrl_trl.generative.shipped_traffic`) and MOBIL's criteria (``mobil_criteria: true``,
    :class:`~kddrl_trl.transforms.MOBILCriteria`); MOBIL's safety mask where ``algo.mobil_safety_mask``
    (:class:`~kddrl_trl.transforms.MOBILSafetyMask`, any algo schema with the key); with ``algo.shield=rss`` the
    lane-change gap check of RSS (:class:`~kddrl_trl.transforms.RSSLaneMask`); a learning algo's
    :class:`DecisionClock` of ``algo.lc_period``; the car-following shield of ``algo.shield``
    (:class:`~kddrl_trl.transforms.SafetyShield`, every algo)."""
    stack = []
    learning = isinstance(algo, LearningAlgo)
    if learning:
        options = asdict(algo.transforms)
        mobil_criteria = options.pop("mobil_criteria")
        options["weights"] = shipped_traffic(options["weights"], simulator)
        if options.pop("enabled"):
            stack.append(make_kddrl_transforms(**options, seed=seed, num_lanes=highway.num_lanes, compile=compile))
        if mobil_criteria:
            stack.append(MOBILCriteria(num_lanes=highway.num_lanes))
    if getattr(algo, "mobil_safety_mask", False):  # any algo schema that has the option
        stack.append(MOBILSafetyMask(num_lanes=highway.num_lanes))
    shield = getattr(algo, "shield", "none")
    rss = RSSParams(horizon=highway.sensing_range)  # the rss layer's worst case: nothing seen beyond the sensing range
    if shield == "rss":  # the worst-case layer's lateral half: the lane-change gap check
        stack.append(RSSLaneMask(rss, length=highway.vehicle_length))
    if learning:
        stack.append(DecisionClock(algo.lc_period))
    if shield != "none":
        stack.append(
            SafetyShield(
                algo.shield,
                low=highway.accel_low,
                high=highway.accel_high,
                ttc=algo.shield_ttc,
                rss=rss,
                penalty=algo.shield_penalty,
                record=algo.shield_buffer,
            )
        )
    return Compose(*stack)


def make_env(
    env: EnvNode,
    algo: LearningAlgo | RuleAlgo,
    seed: int,
    compile: bool = False,
    fake: bool = False,
    gui: bool = False,
    road_seeds: Sequence[int] | None = None,
) -> EnvBase:
    """The env of ``env.simulator`` with ``env.num_roads`` roads on the composed highway config: ``SumoHighwayEnv``
    (``sumo``; ``FakeHighwayEnv`` with ``fake=True``) or ``HighwayEnvAdapter`` (``highwayenv``, the optional extra
    ``.[highway]``), with :func:`make_transforms` (built first: no simulator starts before every option is
    checked; a rule-based algo without a shield gets the bare env). ``road_seeds`` (a seed batch's env, SUMO or
    the fake env): one road per entry, each carrying the traffic of its seed (``num_roads`` is then their count)."""
    highway = env.highway()
    transforms = make_transforms(algo, seed, highway, compile, env.simulator)
    roads = env.num_roads if road_seeds is None else len(road_seeds)
    if road_seeds is not None and env.simulator != "sumo":
        raise ValueError(f"a seed batch's env is SUMO's (env.simulator=sumo), got env.simulator={env.simulator}")
    if fake:
        base = FakeHighwayEnv(highway, num_roads=roads, seed=seed, road_seeds=road_seeds)
    elif env.simulator == "highwayenv":
        base = HighwayEnvAdapter(highway, num_roads=env.num_roads, seed=seed, options=env.highwayenv)
    else:
        base = SumoHighwayEnv(highway, num_roads=roads, seed=seed, gui=gui, road_seeds=road_seeds)
    return TransformedEnv(base, transforms) if len(transforms.transforms) else base


def make_seed_batch_env(job: TrainJob, seeds: Sequence[int], fake: bool = False) -> list[WorkerEnv]:
    """The env factory of a seed batch, run in the learner process: one env of ``len(seeds) x env.num_roads``
    roads, seed-major, seed ``i`` 's roads carrying the traffic of its run alone with env seed ``seeds[i]``
    (:class:`~kddrl_trl.envs.sim.HighwaySim` ``road_seeds``; on resume each seed's seed plus its episodes done)."""
    roads = [int(s) for s in seeds for _ in range(job.env.num_roads)]
    make = partial(make_env, job.env, job.algo, compile=job.compile, fake=fake, road_seeds=roads)
    return [WorkerEnv(make, roads[0], seed_torch=False, settings=make_torch_settings(job))]


def make_seed_batch_test_env(jobs: Sequence[Job], fake: bool = False) -> EnvBase:
    """The env of a seed batch's final evaluations: ``jobs[i]`` 's test traffic (:func:`make_test_env` 's seed) on
    the ``env.num_roads`` roads of seed ``i``, seed-major, in one simulation."""
    job = jobs[0]
    roads = [test_seed(j.seed, j.eval_seed) for j in jobs for _ in range(job.env.num_roads)]
    return make_env(job.env, job.algo, seed=roads[0], compile=job.compile, fake=fake, road_seeds=roads)


def make_env_factories(job: TrainJob, seed: int, fake: bool = False) -> list[WorkerEnv]:
    """One :class:`~kddrl_trl.collectors.workers.WorkerEnv` per collection worker of ``job.collector``: worker
    ``i`` builds :func:`make_env` of the job's env, algo and ``compile`` with env seed
    :func:`~kddrl_trl.protocol.worker_seed` ``(seed, i)`` (``seed``: the run's env seed, ``job.seed`` plus the
    episodes already done on resume), seeds its process's torch generator with it and applies the job's
    :func:`make_torch_settings` there. A single worker of the ``process`` backend is the env of the learner process: its
    seed is ``seed`` and torch is left as the entry point seeded it (``collector.sync=false``: its one worker is a
    process of its own, seeded as any worker)."""
    workers = job.collector.workers
    in_process = workers == 1 and job.collector.backend == "process" and job.collector.sync
    make = partial(make_env, job.env, job.algo, compile=job.compile, fake=fake)
    settings = make_torch_settings(job)
    return [WorkerEnv(make, worker_seed(seed, i), seed_torch=not in_process, settings=settings) for i in range(workers)]


def make_learner(
    algo: LearningAlgo,
    compile: bool = False,
    device: torch.device | str | None = None,
    cudagraphs: bool = False,
    seeds: int | None = None,
) -> Learner:
    """The learner of ``algo.kind`` (:data:`LEARNERS`) built from ``algo.learner`` and ``algo.state_extras`` (every
    learner's states) on ``device`` (None: the CPU; ``compile``: its update functions, the learner's one compile
    site; ``cudagraphs``: CUDA-graph them). ``seeds=N``: N learners stacked in one (a hierarchical learner,
    :mod:`kddrl_trl.modules.seed_batch`), all with the initial weights of the one built (:func:`make_seed_learner`
    gives each seed its own)."""
    extra = {} if seeds is None else {"seeds": int(seeds)}
    return LEARNERS[algo.kind](
        **asdict(algo.learner),
        state_extras=tuple(algo.state_extras),
        compile=compile,
        device=device,
        cudagraphs=cudagraphs,
        **extra,
    )


def make_seed_learner(
    algo: LearningAlgo,
    seeds: Sequence[int],
    compile: bool = False,
    device: torch.device | str | None = None,
    cudagraphs: bool = False,
) -> Learner:
    """The batched learner of a seed batch: seed ``i`` starts with the initial weights its run alone starts with
    (the learner built after ``seed_everything(seeds[i])``, :func:`~kddrl_trl.modules.seed_batch.load_seeds`); the
    process is left seeded with ``seeds[0]``."""
    singles = []
    for seed in seeds:
        seed_everything(int(seed))
        singles.append(make_learner(algo))
    batched = make_learner(algo, compile=compile, device=device, cudagraphs=cudagraphs, seeds=len(seeds))
    load_seeds(batched, [s.to(batched.device) for s in singles])
    seed_everything(int(seeds[0]))
    return batched


def make_policy(algo: LearningAlgo | RuleAlgo, highway: HighwayConfig, learner: Learner | None = None):
    """The acting policy with exploration off: MOBIL + IDM with ``algo.idm`` / ``algo.mobil`` for a rule-based
    algo; the trained ``learner`` 's greedy policy for a learning algo."""
    if isinstance(algo, RuleAlgo):
        return IDMMobilPolicy(
            IDMParams(**asdict(algo.idm)),
            MOBILParams(**asdict(algo.mobil)),
            num_lanes=highway.num_lanes,
            lane_width=highway.lane_width,
        )
    if learner is None:
        raise ValueError(f"algo={algo.name} is a learning algo: its policy needs the trained learner")
    return learner.policy(explore=False).eval()


def make_buffers(
    train: TrainConfig, seed: int, device: torch.device | str | None = None
) -> tuple[TensorDictReplayBuffer, TensorDictReplayBuffer]:
    """Buffer L (frames: TD3, DDPG, a unified agent) and buffer H (macro-transitions, D3QN) with the ``train``
    sizes, on the learner's ``device`` (None: the CPU); both prioritized with ``train.prioritized``."""
    per = (train.priority_alpha, train.priority_beta) if train.prioritized else None
    return (
        make_buffer(train.buffer_cf, train.batch_size_cf, seed, device, prioritized=per),
        make_buffer(train.buffer_lc, train.batch_size_lc, seed + 1, device, prioritized=per),
    )


def make_collector(
    env,
    learner: Learner,
    buffers: tuple,
    train: TrainConfig,
    lc_reward: str = "frames",
    *,
    collector: CollectorConfig | None = None,
    rows: int | None = None,
    seeds: int | None = None,
) -> MultiTimescaleCollector:
    """``train.frames_per_env`` frames per road per iteration with the exploring policy, into ``buffers``
    (restricted to the keys the learner reads; buffer H only for a learner that ``learns_from_decisions``).
    ``env``: a batched env (the caller closes it), or the env factories of :func:`make_env_factories` (``rows``:
    ``env.num_roads``), run in this process or in ``collector.workers`` workers of ``collector.backend``
    (:meth:`MultiTimescaleCollector.from_env`). ``lc_reward`` (``algo.lc_reward``): ``frames`` sums the per-frame
    lane-change rewards of a macro-transition (Algorithm 1 line 35); ``decision`` counts the efficiency term the env
    writes (``keys.EFFICIENCY_TERM``) once per decision (§III.G,
    :class:`~kddrl_trl.collectors.MacroTransitionWriter`). ``seeds=N`` (a seed batch): ``buffers`` holds N buffers L
    and N buffers H, seed ``i`` 's filled from its rows (:class:`MultiTimescaleCollector`)."""
    if lc_reward not in LC_REWARDS:
        raise ValueError(f"make_collector: lc_reward must be one of {', '.join(LC_REWARDS)}, got {lc_reward!r}")
    collector = collector or CollectorConfig()
    frame_keys, nstep = learner.buffer_keys(), None
    if train.n_steps > 1:  # n-step returns in buffer L; the held lane-change action of the window's last frame
        nstep = NStepReturns(train.n_steps, learner.frame_gamma)
        frame_keys = [*frame_keys, K.STEPS_TO_NEXT_OBS, ("next", *K.LC_HELD)]
    return MultiTimescaleCollector.from_env(
        env,
        learner.policy(explore=True),
        frames_per_env=train.frames_per_env,
        rows=rows,
        backend=collector.backend,
        sync=collector.sync,
        frame_buffer=buffers[0],
        macro_buffer=buffers[1] if learner.learns_from_decisions else None,
        frame_keys=frame_keys,
        frame_transform=nstep,
        macro_keys=[*learner.buffer_keys(), ("next", *K.LC_MACRO_FRAMES)],
        writer=MacroTransitionWriter(efficiency_key=K.EFFICIENCY_TERM if lc_reward == "decision" else None),
        seeds=seeds,
    )


def make_seed_batch(job: TrainJob, folder: Path, fake: bool = False) -> SeedBatchTrainer:
    """The trainer of the seed batch ``job.seeds`` in ``folder``: the batched learner (:func:`make_seed_learner`)
    and, per seed, a :class:`~kddrl_trl.training.Trainer` on its :class:`~kddrl_trl.training.seed_split.SeedView`
    with the buffers, logger and periodic evaluator its run alone has (``fake``: none), writing into
    ``folder/<scenario>__<algo>__<seed>/`` (a sweep's job names; a finished seed's folder gets no evaluator)."""
    jobs = job.seed_jobs()
    seeds = [j.seed for j in jobs]
    learner = make_seed_learner(
        job.algo, seeds, compile=job.compile, device=job.torch_device, cudagraphs=job.cudagraphs
    )
    single = make_learner(job.algo)  # each seed's policies: its weights in a learner of its own
    validation = None if fake else make_seed_batch_validation(jobs)
    books = []
    for i, seed_job in enumerate(jobs):
        run = RunFolder(Path(folder) / f"{job.env.scenario}__{job.algo.name}__{seed_job.seed}")
        view = SeedView(learner, i, single, counts=None)
        book = Trainer(
            view,
            make_buffers(job.train, seed_job.seed, learner.device),
            job.train,
            run.path,
            make_logger(job.logger, run.path),
            episodes=job.episodes,
            progress=False,
            evaluator=None if validation is None or run.is_finished() else validation.evaluator(i),
            highway=job.env.highway(),
        )
        view.counts = lambda b=book: (b.counters["lc_updates"], b.counters["cf_updates"])
        books.append(book)
    return SeedBatchTrainer(
        learner, books, job.train, folder, progress=job.progress, threads=job.threads, validation=validation
    )


def make_seed_batch_validation(jobs: Sequence[TrainJob]) -> SeedBatchValidation | None:
    """The periodic validations of a seed batch (None with ``train.eval_every=0``): ``train.eval_episodes`` greedy
    episodes per seed on ``jobs[i]`` 's validation traffic (:func:`make_evaluator` 's seed), on its K roads of one
    env of N x K roads in a worker process; each seed's own evaluator (:func:`make_evaluator`) for the validations a
    resumed batch starts again."""
    job = jobs[0]
    if job.train.eval_every == 0:
        return None
    roads = [validation_seed(j.seed) for j in jobs for _ in range(job.env.num_roads)]
    make = partial(make_env, job.env, job.algo, compile=False, road_seeds=roads)
    shared = PeriodicEvaluator(
        WorkerEnv(make, roads[0], seed_torch=False, settings=make_torch_settings(job)),
        job.train.eval_episodes,
        roads[0],
        job.train.best_metric,
        groups=len(jobs),
    )
    return SeedBatchValidation(shared, lambda i: make_evaluator(jobs[i]))


def make_seed_batch_collector(env, batch: SeedBatchTrainer, job: TrainJob) -> MultiTimescaleCollector:
    """:func:`make_collector` of a seed batch: ``env`` (:func:`make_seed_batch_env`, or a batched env) of N x K rows,
    seed ``i`` 's into its trainer's buffers."""
    books = batch.books
    return make_collector(
        env,
        batch.learner,
        ([b.buffer_cf for b in books], [b.buffer_lc for b in books]),
        job.train,
        job.algo.lc_reward,
        collector=job.collector,
        rows=len(books) * job.env.num_roads,
        seeds=len(books),
    )


def make_evaluator(job: TrainJob):
    """The periodic evaluation of :class:`~kddrl_trl.training.Trainer` (None with ``train.eval_every=0``):
    ``train.eval_episodes`` greedy episodes on the validation seed of :mod:`kddrl_trl.protocol`, in an env
    of the job's traffic and the algo's transforms run by a worker process (eager: it acts a few times per run),
    under the job's :func:`make_torch_settings`."""
    if job.train.eval_every == 0:
        return None
    seed = validation_seed(job.seed)
    make = partial(make_env, job.env, job.algo, compile=False)
    return PeriodicEvaluator(
        WorkerEnv(make, seed, seed_torch=False, settings=make_torch_settings(job)),
        job.train.eval_episodes,
        seed,
        job.train.best_metric,
    )


def make_trained_learner(
    run: Path, checkpoint: str = "latest", device: torch.device | str | None = None, shield: str | None = None
) -> tuple[LearningAlgo, Learner, Path, DictConfig]:
    """(algo, learner on ``device`` with the weights of its ``latest`` or ``best`` checkpoint, that checkpoint,
    the run's saved config) of a training run folder. The learner only acts: it is not compiled. Checkpoints are
    read onto the CPU and then copied to the learner's device, so a run trained on either loads on either.
    ``shield`` (not None) replaces the run's ``algo.shield`` (its penalty, a training signal, then 0)."""
    saved = OmegaConf.load(RunFolder(trained_run(run)).config)  # a shipped policy's folder reads the same way
    algo = algo_from_node(saved.algo)
    if shield is not None and isinstance(algo, LearningAlgo):
        kept = shield != "none"  # the penalty and the buffer's choice are training signals of a shield
        algo = replace(
            algo,
            shield=shield,
            shield_penalty=algo.shield_penalty if kept else 0.0,
            shield_buffer=algo.shield_buffer if kept else "executed",
        )
    if not isinstance(algo, LearningAlgo):
        raise ValueError(
            f"run={run} is algo={algo.name} ({algo.kind}): nothing was trained; evaluate it with "
            f"python -m kddrl_trl.train algo={algo.name} +scenario=..."
        )
    shipped = trained_run(run) / POLICY_FILE
    if shipped.is_file():  # a shipped policy: its networks only (kddrl_trl.policies)
        learner = make_learner(algo, compile=False, device=device)
        learner.load_state_dict(load_policy(shipped)["modules"])
        return algo, learner, shipped, saved
    if checkpoint == "latest":  # the newest that loads (a damaged one falls back to the previous, with a warning)
        path, payload = load_latest_training_checkpoint(run)
    else:
        path = best_checkpoint(run)
        if not path.is_file():
            raise FileNotFoundError(
                f"run={run}: no {checkpoint} checkpoint in {checkpoint_dir(run)} (train.eval_every=0 writes no best.pt)"
            )
        payload = load_training_checkpoint(path)
    learner = make_learner(algo, compile=False, device=device)
    learner.load_full_state_dict(payload["learner"])
    return algo, learner, path, saved


def make_test_env(job: Job, algo: LearningAlgo | RuleAlgo, env_cfg) -> EnvBase:
    """The env of a final evaluation: ``env_cfg`` 's traffic (an ``env`` node) with ``algo`` 's transforms, from the
    test seed of ``job`` (:func:`kddrl_trl.protocol.test_seed`: never a training or validation seed)."""
    return make_env(env_cfg, algo, seed=test_seed(job.seed, job.eval_seed), compile=job.compile, gui=job.gui)
