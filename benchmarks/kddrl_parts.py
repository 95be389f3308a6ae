"""What the learner and collection benchmarks share: KDDRL's learner and transform options as training reads them
(``conf/algo/kddrl.yaml``, ``conf/config.yaml``), the collection env, replay batches with every key the learner reads,
and the timing of update functions on them (:func:`time_updates`). Used by ``update_speed``, ``update_floor``,
``gpu_update``, ``collect_speed`` and the investigations that build on them."""

from __future__ import annotations

import time
from pathlib import Path

import torch
from omegaconf import OmegaConf
from tensordict import TensorDictBase
from torchrl.envs import Compose, TransformedEnv

from kddrl_trl import keys as K
from kddrl_trl.collectors import MultiTimescaleCollector
from kddrl_trl.compiling import resolve_compile
from kddrl_trl.envs import FakeHighwayEnv, SumoHighwayEnv
from kddrl_trl.factories import make_transforms
from kddrl_trl.training import HierarchicalLearner, make_buffer
from kddrl_trl.transforms import (
    DecisionClock,
    make_kddrl_transforms,
)

CONF = Path(__file__).resolve().parents[1] / "src" / "kddrl_trl" / "conf" / "algo" / "kddrl.yaml"
#: where each benchmark writes its ``<name>.json``
RESULTS = Path(__file__).resolve().parent / "results"
FRAMES_PER_ENV = 20  # frames per env row per collected batch of the collection benchmarks


def learner_kwargs(compile: bool | str) -> tuple[dict, int]:
    """The learner options of ``conf/algo/kddrl.yaml`` (with ``compile`` set) and its ``lc_period``."""
    cfg = OmegaConf.to_container(OmegaConf.load(CONF), resolve=True)
    return {**cfg["learner"], "compile": compile}, int(cfg["lc_period"])


def arm_learner(n: int | None, compiled: bool, device: torch.device = torch.device("cpu")) -> HierarchicalLearner:
    """The default KDDRL learner, alone (``n`` None) or as ``n`` seeds, eager or compiled (on CUDA compiled and
    CUDA-graphed), on ``device``."""
    kw = {**learner_kwargs(compiled)[0], "device": device, "cudagraphs": compiled and device.type == "cuda"}
    return HierarchicalLearner(**kw) if n is None else HierarchicalLearner(**kw, seeds=n)


def buffer_keys() -> list:
    """The keys a buffer entry keeps for the KDDRL learner of ``conf/algo/kddrl.yaml`` (a superset of the other
    learners' keys): what :func:`sample_batches` is asked for."""
    return HierarchicalLearner(**learner_kwargs(False)[0]).buffer_keys()


def batch_sizes() -> tuple[int, int]:
    """The minibatch sizes of training (``train.batch_size_cf`` / ``train.batch_size_lc`` of conf/config.yaml)."""
    train = OmegaConf.load(CONF.parents[1] / "config.yaml")["train"]
    return int(train["batch_size_cf"]), int(train["batch_size_lc"])


def training_job(overrides: tuple[str, ...] = ()):
    """The typed job of ``python -m kddrl_trl.train`` with ``overrides`` (the schema's objects, composed by Hydra as
    the entry point composes them; none of the job's process settings applied)."""
    from hydra import compose, initialize_config_module

    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        return OmegaConf.to_object(compose(config_name="config", overrides=list(overrides)))


def collect_env(k: int, compile: bool | str | None = None, *, seed: int) -> TransformedEnv:
    """The env of (b): ``SumoHighwayEnv`` with ``k`` roads + the default job's env-side stack, built as training
    builds it (:func:`kddrl_trl.factories.make_transforms`: the KDDRL transforms, the decision clock), with
    ``compile`` of ``conf/config.yaml`` or ``compile`` when given."""
    job = training_job()
    use = resolve_compile(job.compile if compile is None else compile)
    return TransformedEnv(
        SumoHighwayEnv("baseline", num_roads=k, seed=seed), make_transforms(job.algo, seed, job.env.highway(), use)
    )


def sample_batches(n_frames: int, seed: int, keys: list, batch_size_cf: int | None = None):
    """Frames and macro-transitions with every key the learner reads (from the fake env: only shapes and
    plausible values matter for timing); TD3 minibatches of ``batch_size_cf`` (None: training's)."""
    env = TransformedEnv(
        FakeHighwayEnv(num_roads=8, seed=seed), Compose(make_kddrl_transforms(seed=seed), DecisionClock(20))
    )
    learner = HierarchicalLearner(**learner_kwargs(False)[0])
    rb_cf = make_buffer(10 * n_frames, batch_size_cf or batch_sizes()[0], seed)
    rb_lc = make_buffer(10 * n_frames, batch_sizes()[1], seed)
    mtc = MultiTimescaleCollector.from_env(
        env, learner.policy(), frames_per_env=50, frame_buffer=rb_cf, macro_buffer=rb_lc, frame_keys=keys
    )
    for _ in mtc:
        if len(rb_cf) >= n_frames and len(rb_lc) >= batch_sizes()[1]:
            break
    mtc.shutdown()
    return rb_cf, rb_lc


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def stacked(buffer, n: int | None, count: int) -> list:
    """``count`` minibatches: single ones (``n`` None) or ``n`` independent samples stacked on a seed dimension."""
    if n is None:
        return [buffer.sample() for _ in range(count)]
    return [torch.stack([buffer.sample() for _ in range(n)]) for _ in range(count)]


def unprioritized(batches: list) -> list:
    """``batches`` without the ``keys.PRIORITY`` an update wrote into them (a TensorDict's, in place)."""
    for b in batches:
        if isinstance(b, TensorDictBase) and K.PRIORITY in b.keys():
            del b[K.PRIORITY]
    return batches


def time_updates(
    update_cf, update_lc, cf_batches, lc_batches, lc_period: int, device: torch.device = torch.device("cpu")
) -> tuple[float, float, float]:
    """Seconds per TD3 update, per D3QN update, and per frame (TD3 + D3QN / lc_period), each pass on batches as
    fresh samples come (:func:`unprioritized`)."""
    n = len(cf_batches)
    for b in unprioritized(cf_batches)[:10]:
        update_cf(b)
    for b in unprioritized(lc_batches)[:5]:
        update_lc(b)
    unprioritized(cf_batches)
    unprioritized(lc_batches)
    sync(device)
    t0 = time.perf_counter()
    for b in cf_batches:
        update_cf(b)
    sync(device)
    t_cf = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    for b in lc_batches:
        update_lc(b)
    sync(device)
    t_lc = (time.perf_counter() - t0) / len(lc_batches)
    return t_cf, t_lc, t_cf + t_lc / lc_period
