"""``Trainer``: Algorithm 1 of the paper as a collection / update loop over TorchRL parts.

Per collection batch of ``frames_per_env`` frames from each of the B environments (one TorchRL
``Collector`` iteration, :class:`~kddrl_trl.collectors.MultiTimescaleCollector`):

1. every frame goes to buffer L, every closed macro-transition to buffer H (lines 25, 37);
2. one TD3 update per collected frame (lines 38-43) once ``warmup_frames`` frames are in; one D3QN update
   per decision taken (lines 27-29) once buffer H holds ``batch_size_lc`` macro-transitions. The counts per
   frame / per decision are the paper's; they are run after each batch instead of between two frames, so
   the acting policy lags by at most ``frames_per_env`` frames (the usual collector trade-off). After the updates
   the acting policies take the learner's weights and exploration state (ε, σ; TorchRL's weight sync, which
   reaches the collector's worker processes with ``collector.workers`` > 1; with ``collector.sync=false`` the
   worker collects the next batch during the updates, acting one batch behind:
   :class:`~kddrl_trl.collectors.OverlappedCollector`). Any
   :class:`~kddrl_trl.training.Learner` trains here: its ``update_frame`` is the buffer-L update (TD3, DDPG, or
   a unified agent's only one), its ``update_decision`` the buffer-H one (only ``learns_from_decisions``);
3. finished episodes are logged (``train/`` and ``time/``), the progress bar moves, and every
   ``checkpoint_every`` episodes a checkpoint is written (:mod:`kddrl_trl.training.checkpoint`);
4. every ``eval_every`` episodes (0: never) the greedy policy drives ``eval_episodes`` validation episodes
   (:class:`~kddrl_trl.eval.periodic.PeriodicEvaluator`, fixed seeds disjoint from training) in a worker process,
   on a copy of its weights, while the training goes on; each is logged under ``eval/`` at the episode it started
   at, and the best score so far keeps the learner as it was then as ``checkpoints/best.pt`` beside ``latest``.
   A checkpoint does not wait for them: it lists those under way with the learner each was given, and a run
   resumed from it starts them again on those weights.
"""

from __future__ import annotations

import copy
import logging
import math
import time
import warnings
from collections import deque
from pathlib import Path

import numpy as np
import torch
from torchrl.data import LazyTensorStorage, PrioritizedSampler, TensorDictReplayBuffer

from .. import keys as K
from ..collectors import MultiTimescaleCollector
from ..envs.episode_metrics import EpisodeTracker
from .checkpoint import (
    CheckpointError,
    load_latest_training_checkpoint,
    save_best_checkpoint,
    save_training_checkpoint,
)
from .learner import Learner
from .priority_trees import PortablePrioritizedSampler

log = logging.getLogger(__name__)

#: per-episode fields logged under ``train/``
EPISODE_FIELDS = (
    "return_lc",
    "return_cf",
    "mean_speed_kmh",
    "mean_accel",
    "mean_abs_accel",
    "lane_changes",
    "frames",
    "collision",
    "shield_rate",
)


#: ε of prioritized replay: ``P(i) ∝ (|δ_i| + ε)^α``, no transition's probability is zero
PRIORITY_EPS = 1e-6


def make_buffer(
    capacity: int,
    batch_size: int,
    seed: int,
    device: torch.device | str | None = None,
    prioritized: tuple[float, float] | None = None,
) -> TensorDictReplayBuffer:
    """A TorchRL replay buffer in memory (``LazyTensorStorage``) on ``device`` (None: the CPU): a CUDA learner's
    buffers live on its GPU, so the collector's frames cross once per batch and the sampled minibatches are already
    where the update runs. Uniform sampling (the paper), or with ``prioritized = (alpha, beta)`` TorchRL's
    ``PrioritizedSampler`` (Schaul et al., 2016; ``train.prioritized``; on any torch build:
    :class:`~kddrl_trl.training.priority_trees.PortablePrioritizedSampler`): ``P(i) ∝ (|δ_i| + ε)^α``,
    new transitions at the largest priority so far, samples carrying their importance weights
    (``keys.PRIORITY_WEIGHT``) and priorities updated from ``keys.PRIORITY`` (:meth:`Trainer._updates`)."""
    device = torch.device(device or "cpu")
    gen = torch.Generator(device).manual_seed(int(seed))  # the sampler draws its indices on the storage's device
    storage = LazyTensorStorage(int(capacity), device=device)
    if prioritized is None:
        return TensorDictReplayBuffer(storage=storage, batch_size=int(batch_size), generator=gen)
    alpha, beta = prioritized
    sampler = PortablePrioritizedSampler(int(capacity), float(alpha), float(beta), eps=PRIORITY_EPS)
    return TensorDictReplayBuffer(
        storage=storage, sampler=sampler, priority_key=K.PRIORITY, batch_size=int(batch_size), generator=gen
    )


def is_prioritized(buffer: TensorDictReplayBuffer) -> bool:
    """Whether ``buffer`` samples by priority (:func:`make_buffer` with ``prioritized``)."""
    return isinstance(buffer.sampler, PrioritizedSampler)


def load_buffer(buffer: TensorDictReplayBuffer, state: dict) -> None:
    """Loads a buffer's ``state_dict`` (read onto the CPU) back onto the buffer's own device (TorchRL's
    ``LazyTensorStorage.load_state_dict`` keeps the tensors where they were read)."""
    buffer.load_state_dict(state)
    storage = buffer.storage
    if storage.initialized and storage._storage.device != torch.device(storage.device):
        storage._storage = storage._storage.to(storage.device)


#: most minibatches :func:`minibatches` draws in one storage read (bounds its memory: 64 x 128 rows of buffer L)
MINIBATCHES_PER_DRAW = 64


def minibatch_draws(buffer: TensorDictReplayBuffer, n: int):
    """The storage reads behind :func:`minibatches` on a uniform ``buffer``: ``[m, batch_size]`` samples, ``m`` up to
    ``MINIBATCHES_PER_DRAW``, ``n`` minibatches in all, in update order (a seed batch stacks its seeds' reads
    draw by draw, :func:`~kddrl_trl.training.seed_batch_trainer.seed_minibatches`)."""
    size = buffer.batch_size
    while n > 0:
        m = min(n, MINIBATCHES_PER_DRAW)
        with warnings.catch_warnings():  # TorchRL warns that the size differs from the buffer's batch_size: meant
            warnings.filterwarnings("ignore", "Got conflicting batch_sizes", UserWarning)
            draw = buffer.sample(m * size)
        yield draw.reshape(m, size)
        n -= m


def minibatches(buffer: TensorDictReplayBuffer, n: int):
    """The ``n`` minibatches (of ``buffer.batch_size`` rows) of ``n`` consecutive updates on ``buffer``.

    A uniform buffer does not change between the updates of one collection batch, so its ``n`` minibatches are
    drawn as one sample of up to ``MINIBATCHES_PER_DRAW`` x ``batch_size`` rows and split into views
    (:func:`minibatch_draws`): the same indices, from the same generator stream, as ``n`` calls of
    ``buffer.sample()`` (``tests/training/test_trainer_minibatches.py``), at a fraction of the cost per minibatch
    (``benchmarks/replay_sampling.py`` measures it: arm ``uniform_grouped``). A prioritized buffer is sampled once per
    update, since each update rewrites the priorities the next draw reads."""
    if is_prioritized(buffer):
        for _ in range(n):
            yield buffer.sample()
        return
    for draw in minibatch_draws(buffer, n):
        yield from draw.unbind(0)


def _under_way(path: Path, payload: dict, episodes: int) -> list[tuple[int, dict]]:
    """The periodic evaluations a checkpoint lists as under way, each with the learner it was given:
    ``validating`` and ``validating_learners`` pair up. A checkpoint without the learners (written by code whose
    checkpoints waited for every earlier evaluation) may list only its own episode's, whose learner is its own;
    anything else is refused, naming the file."""
    steps = [int(s) for s in payload.get("validating", [])]
    learners = payload.get("validating_learners")
    if learners is None:
        if steps not in ([], [episodes]):
            raise CheckpointError(
                f"{path}: lists periodic evaluations under way at episodes {steps} without the learners they were "
                f"given; only its own episode's ({episodes}) can be started again"
            )
        return [(s, payload["learner"]) for s in steps]
    if len(learners) != len(steps) or sorted(steps) != steps or any(s > episodes for s in steps):
        raise CheckpointError(
            f"{path}: 'validating' {steps} and 'validating_learners' ({len(learners)}) do not pair up as evaluations "
            f"started by episode {episodes}"
        )
    return list(zip(steps, learners, strict=True))


class Trainer:
    """Trains a :class:`~kddrl_trl.training.Learner` for ``episodes`` episodes (:meth:`run`, on a
    :class:`~kddrl_trl.collectors.MultiTimescaleCollector` whose env carries the predictive-state transforms and
    a :class:`~kddrl_trl.transforms.DecisionClock`, and which fills ``buffers``).

    ``buffers``: (buffer L of frames, buffer H of macro-transitions). ``cfg``: the typed ``train`` node
    (:class:`~kddrl_trl.conf.schema.TrainConfig`, ranges checked there). ``logger`` has
    ``log_scalar(name, value, step)``. :meth:`load` restores a run directory's latest checkpoint before
    :meth:`run` continues it. ``evaluator`` (e.g. :class:`~kddrl_trl.eval.periodic.PeriodicEvaluator`) maps the
    greedy policy to (episodes, summary with a ``"score"``); it runs every ``cfg.eval_every`` episodes. All parts
    come from :mod:`kddrl_trl.factories`.
    """

    def __init__(
        self,
        learner: Learner,
        buffers: tuple[TensorDictReplayBuffer, TensorDictReplayBuffer],
        cfg,
        run_dir: str | Path,
        logger,
        *,
        episodes: int,
        progress: bool = True,
        evaluator=None,
        threads=None,
        highway=None,
    ):
        self.learner, self.cfg, self.episodes, self.evaluator = learner, cfg, int(episodes), evaluator
        self.threads = threads  # a ThreadGovernor (kddrl_trl.threads): told of every batch, it follows the machine
        self.validations: list[dict] = []  # per periodic evaluation: episodes trained, summary
        self.buffer_cf, self.buffer_lc = buffers
        self.run_dir, self.logger, self.progress = Path(run_dir), logger, progress
        self.tracker = EpisodeTracker(highway)
        self.history: list[dict] = []
        # elapsed_s: training wall time; update_s: its share spent in the learner's updates (losses read included,
        # so a GPU learner's queued work is counted where it is waited for). A seed of a batch counts the batch's
        # shared wall time in both: a seed's share of the compute is them over the batch's size
        self.counters = {
            "frames": 0,
            "decisions": 0,
            "cf_updates": 0,
            "lc_updates": 0,
            "elapsed_s": 0.0,
            "update_s": 0.0,
        }
        self.collector: MultiTimescaleCollector | None = None
        self._bar, self._started = None, None  # (start(): the progress bar, the clock of elapsed_s)
        #: periodic evaluations under way: (episodes trained, future, the learner's state then), in start order
        self.pending: deque = deque()
        #: a loaded checkpoint's evaluations under way when it was written: (episodes, the learner they were given)
        self.unfinished: list[tuple[int, dict]] = []

    # ------------------------------------------------------------------------------ checkpoints
    def state(self) -> dict:
        # the environments restart on resume, so unfinished macro-transitions are not kept
        state = {
            "learner": self.learner.full_state_dict(),
            "counters": dict(self.counters),
            "history": list(self.history),
            "validations": list(self.validations),
            # the evaluations under way, each with the learner it was given (a resumed run starts them again)
            "validating": [step for step, _, _ in self.pending],
            "validating_learners": [learner for _, _, learner in self.pending],
        }
        if self.cfg.keep_buffers:
            state["buffer_cf"] = self.buffer_cf.state_dict()
            state["buffer_lc"] = self.buffer_lc.state_dict()
        return state

    def load(self, run_dir: str | Path) -> int:
        """Restore the latest checkpoint of ``run_dir`` that loads (a damaged newest one falls back to the previous,
        with a warning); returns the number of episodes it had finished."""
        return self.load_payload(*load_latest_training_checkpoint(run_dir))

    def load_payload(self, path: Path, payload: dict) -> int:
        """Restores the checkpoint ``payload`` read from ``path`` (:meth:`load`); returns its episodes."""
        self.learner.load_full_state_dict(payload["learner"])
        self.counters.update(payload["counters"])
        self.history = list(payload["history"])
        self.validations = list(payload.get("validations", []))
        self.unfinished = _under_way(path, payload, len(self.history))
        if "buffer_cf" in payload:
            load_buffer(self.buffer_cf, payload["buffer_cf"])
            load_buffer(self.buffer_lc, payload["buffer_lc"])
        self.tracker.finished = len(self.history)
        log.info(
            "resumed %s: %d episodes, %d frames, buffers %d / %d",
            path,
            len(self.history),
            self.counters["frames"],
            len(self.buffer_cf),
            len(self.buffer_lc),
        )
        return len(self.history)

    def checkpoint(self, final: bool = False) -> Path:
        """Writes a checkpoint without waiting for the periodic evaluations under way (``final``: once all are
        recorded): it records those that have finished and lists the others with the learner each was given, so a
        run resumed from it starts them again on those weights (:meth:`run`)."""
        self.record_validations(before=math.inf if final else 0)
        return save_training_checkpoint(self.run_dir, len(self.history), self.state())

    def _next_multiple(self, every: int) -> int:
        """Episode count at which the next multiple of ``every`` is reached (``every`` 0: never)."""
        return (len(self.history) // every + 1) * every if every > 0 else math.inf

    def validate(self, future=None) -> None:
        """Starts one periodic evaluation of the greedy policy as it is now, at the number of episodes trained: the
        evaluator's worker drives it while the training goes on (:meth:`record_validations` takes its result), and
        the learner's state is kept beside it for ``checkpoints/best.pt`` and the checkpoints. ``future``: one
        started by the caller instead (a seed batch's validation of all its seeds,
        :mod:`kddrl_trl.eval.seed_validation`), whose result the evaluator reads."""
        if future is None:
            future = self.evaluator.submit(self.learner.policy(explore=False))
        self.pending.append((len(self.history), future, copy.deepcopy(self.learner.full_state_dict())))
        self._next_eval = self._next_multiple(self.cfg.eval_every)

    def validation_due(self) -> bool:
        """Whether ``eval_every`` episodes have passed since the last validation (never without an evaluator)."""
        return len(self.history) >= self._next_eval

    def _restart(self, step: int, state: dict) -> None:
        """Starts again the evaluation a checkpoint listed as under way at ``step``, of the learner it was given
        (``state``); the learner is its own again after the start (the evaluator has taken its copy)."""
        own = copy.deepcopy(self.learner.full_state_dict())
        self.learner.load_full_state_dict(state)
        try:
            future = self.evaluator.submit(self.learner.policy(explore=False))
        finally:
            self.learner.load_full_state_dict(own)
        self.pending.append((step, future, state))

    def record_validations(self, before: float = 0) -> None:
        """Records the periodic evaluations that have finished, in the order they started, and waits for those
        started before ``before`` episodes (``math.inf``: all): each is logged under ``eval/`` at the number of
        episodes it was started at, and a new best score writes ``checkpoints/best.pt`` with the learner as it was
        then."""
        while self.pending:
            step, future, state = self.pending[0]
            if not (future.done() or step < before):
                return
            self.pending.popleft()
            _, summary = self.evaluator.result(future)
            for key in (
                "score",
                "mean_speed_kmh",
                "mean_accel",
                "lane_changes",
                "return_lc",
                "return_cf",
                "collision_rate",
            ):
                self.logger.log_scalar(f"eval/{key}", float(summary[key]), step=step)
            best = max((v["score"] for v in self.validations), default=-math.inf)
            record = {"episodes_trained": step, **{k: v for k, v in summary.items() if not isinstance(v, dict)}}
            self.validations.append(record)
            if summary["score"] > best:
                save_best_checkpoint(self.run_dir, {"learner": state, "validation": record})

    def validated_through(self) -> int:
        """The number of episodes of the last recorded periodic evaluation (-1: none): a resumed run keeps the
        ``eval/`` log rows up to it (:func:`kddrl_trl.loggers.trim_logs`)."""
        return max((v["episodes_trained"] for v in self.validations), default=-1)

    # ------------------------------------------------------------------------------------ loop
    def _record(self, outs: list[dict[str, torch.Tensor]], losses: dict[str, list[float]], counter: str) -> None:
        """Reads the losses of the run of ``counter`` updates just made (``outs``: one dict of 0-d tensors on the
        learner's device per update; a GPU learner's updates are not waited for one by one) at once into
        ``losses``; a loss that is not finite stops the training, naming its update."""
        first = self.counters[counter] - len(outs) + 1  # the number of the first update of the run
        for k in dict.fromkeys(k for out in outs for k in out):
            made = [(first + i, out[k]) for i, out in enumerate(outs) if k in out]
            read = torch.stack([torch.as_tensor(v) for _, v in made]).tolist()  # (a float from a learner of yours too)
            bad = next((j for j, v in enumerate(read) if not math.isfinite(v)), None)
            if bad is not None:
                raise FloatingPointError(
                    f"{k} = {read[bad]} at {counter} update {made[bad][0]} ({self.counters['cf_updates']} buffer-L / "
                    f"{self.counters['lc_updates']} buffer-H updates, {len(self.history)} episodes): training "
                    f"diverged. The last checkpoint in {self.run_dir / 'checkpoints'} is from before; lower the "
                    "learning rates (algo.learner.*) and resume=true, or start again"
                )
            losses.setdefault(k, []).extend(read)

    def _update(
        self, buffer: TensorDictReplayBuffer, n: int, update, losses: dict[str, list[float]], counter: str
    ) -> None:
        """``n`` updates (``update``: the learner's ``update_frame`` / ``update_decision``), each on its own minibatch
        of ``buffer`` (:func:`minibatches`); a prioritized buffer takes each minibatch's new ``|δ|`` as its
        priorities before the next is drawn. Their losses are read after the last (:meth:`_record`)."""
        prioritized = is_prioritized(buffer)
        outs = []
        for batch in minibatches(buffer, n):
            outs.append(update(batch))
            if prioritized:
                buffer.update_tensordict_priority(batch)
            self.counters[counter] += 1
        if outs:
            self._record(outs, losses, counter)

    def _updates(self, frames: int, decisions: int, losses: dict[str, list[float]]) -> None:
        c, learner = self.cfg, self.learner
        if self.counters["frames"] >= c.warmup_frames and len(self.buffer_cf) >= c.batch_size_cf:
            self._update(self.buffer_cf, frames * c.updates_per_frame, learner.update_frame, losses, "cf_updates")
        if learner.learns_from_decisions and len(self.buffer_lc) >= c.batch_size_lc:
            self._update(
                self.buffer_lc, decisions * c.updates_per_decision, learner.update_decision, losses, "lc_updates"
            )

    def _anneal_beta(self) -> None:
        """Prioritized replay's importance-sampling exponent: ``train.priority_beta`` annealed linearly to 1 over
        the training episodes (Schaul et al., 2016), in both buffers."""
        beta0 = self.cfg.priority_beta
        beta = beta0 + (1.0 - beta0) * min(1.0, len(self.history) / max(self.episodes, 1))
        for buffer in (self.buffer_cf, self.buffer_lc):
            if is_prioritized(buffer):
                buffer.sampler.beta = beta

    def _log_episode(self, ep: dict, losses: dict[str, list[float]], started: float) -> None:
        step = ep["index"]
        for key in EPISODE_FIELDS:
            self.logger.log_scalar(f"train/{key}", float(ep[key]), step=step)
        for key, value in self.learner.exploration().items():
            self.logger.log_scalar(f"train/{key}", value, step=step)
        for key, values in losses.items():
            if values:
                self.logger.log_scalar(f"train/{key}", float(np.mean(values)), step=step)
        elapsed = self.counters["elapsed_s"] + time.perf_counter() - started
        self.logger.log_scalar("time/elapsed_s", elapsed, step=step)
        self.logger.log_scalar("time/frames", self.counters["frames"], step=step)
        self.logger.log_scalar("time/frames_per_s", self.counters["frames"] / max(elapsed, 1e-9), step=step)
        self.logger.log_scalar("time/cf_updates", self.counters["cf_updates"], step=step)

    def run(self, collector: MultiTimescaleCollector, finish: bool = True) -> list[dict]:
        """Train on the batches of ``collector`` until ``episodes`` episodes have finished (counting those of a
        resumed run); return the training-episode history. A run resumed from the checkpoint of its last episode
        trains no further: its learner stays the one that checkpoint holds (a validation it lists as under way is
        run again). The collector is shut down: an env passed in to it stays open, the envs it built (its
        workers') are closed.

        ``finish``: the periodic evaluations are all recorded before the last checkpoint, and the evaluator is
        stopped (:meth:`finish`). ``finish=False`` leaves the validation started at the last episode running, listed
        in the last checkpoint as under way (a run resumed from it starts it again): the caller runs its final
        evaluation beside it, then calls :meth:`finish`, which records it in that checkpoint. On an error the
        evaluator is stopped either way."""
        from tqdm.auto import tqdm

        target = self.episodes
        bar = tqdm(
            total=target, initial=min(len(self.history), target), desc="train", unit="ep", disable=not self.progress
        )
        self.collector = collector
        try:
            self.start(collector, bar)
            if len(self.history) >= target:  # resumed after its training ended (killed in the final evaluation)
                if finish:  # records the validation its checkpoint listed as under way, started again above
                    self.finish()
                return self.history
            for batch in self.collector:
                if self.threads is not None:
                    self.threads.tick()
                frames = batch.frames.numel()
                decisions = int(batch.frames.get(self.collector.writer.decide_key).sum())
                self.count(frames, decisions)
                self.learner.explore_step(decisions, frames)
                self._anneal_beta()
                updating = time.perf_counter()
                self._updates(frames, decisions, self.losses)
                self.counters["update_s"] += time.perf_counter() - updating
                self.collector.update_policy_weights_()
                if self.book(batch.frames, finish):
                    break
        except BaseException:
            finish = True  # nothing is left running
            raise
        finally:
            bar.close()
            self.stop()
            self.collector.shutdown(close_env=False)
            if finish:
                self.close()
        return self.history

    def start(self, collector, bar=None) -> None:
        """Before the first batch of :meth:`run` (or of a seed batch, :mod:`~kddrl_trl.training.seed_batch_trainer`,
        which drives this trainer's bookkeeping with ``collector`` its own): the next checkpoint and validation
        episodes, the window of the progress bar's figures, the loss lists, the clock, and the validations a loaded
        checkpoint listed as under way started again on the weights each was given. ``bar``: a tqdm bar this
        trainer moves per episode (None: none)."""
        self.collector, self._bar = collector, bar
        self._next_ckpt = self._next_multiple(self.cfg.checkpoint_every)
        self._next_eval = self._next_multiple(self.cfg.eval_every if self.evaluator is not None else 0)
        self._recent = deque(self.history[-50:], maxlen=50)
        self.losses: dict[str, list[float]] = {"loss_qvalue": [], "loss_actor": [], "loss_lc": []}
        self._started = time.perf_counter()
        if self.evaluator is not None:
            for step, state in self.unfinished:  # in the order they started, each on the weights it was given
                self._restart(step, state)
            self.unfinished = []

    def count(self, frames: int, decisions: int) -> None:
        """Counts a batch's ``frames`` and lane-change ``decisions`` (this trainer's, a seed's in a seed batch)."""
        self.counters["frames"] += frames
        self.counters["decisions"] += decisions

    def book(self, frames, finish: bool = True, checkpoint: bool | None = None, validate: bool = True) -> bool:
        """After a batch's updates: the episodes finished in ``frames`` ``[B, T]`` (this trainer's rows) are recorded
        and logged, the validations that finished are recorded, a validation starts every ``eval_every`` episodes
        (``validate=False``: none, a seed batch starts its seeds' together), and a checkpoint is written every
        ``checkpoint_every`` episodes and at the last (``checkpoint``: True or False overrides the cadence but for
        the last, a seed batch's shared checkpoints). Returns whether the training has reached its episodes
        (``finish`` as in :meth:`run`)."""
        target, bar, recent = self.episodes, self._bar, self._recent
        for ep in self.tracker(frames):
            if len(self.history) >= target:
                break
            self.history.append(ep)
            recent.append(ep)
            self._log_episode(ep, self.losses, self._started)
            self.losses = {k: [] for k in self.losses}
            if bar is not None:
                bar.update(1)
                bar.set_postfix(
                    R_lc=f"{np.mean([e['return_lc'] for e in recent]):.1f}",
                    R_cf=f"{np.mean([e['return_cf'] for e in recent]):.1f}",
                    kmh=f"{np.mean([e['mean_speed_kmh'] for e in recent]):.1f}",
                    coll=f"{100 * np.mean([e['collision'] for e in recent]):.0f}%",
                )
        self.record_validations()  # those finished during this batch, logged as soon as they are
        if validate and self.validation_due():
            self.validate()
        done = len(self.history) >= target
        if done or (self.checkpoint_due() if checkpoint is None else checkpoint):
            self.write_checkpoint(final=finish and done)
        return done

    def write_checkpoint(self, final: bool = False) -> Path:
        """The checkpoint of :meth:`book` (:meth:`checkpoint`), its wall time counted in ``elapsed_s`` up to it."""
        self.stop()
        self._started = time.perf_counter()
        path = self.checkpoint(final=final)
        self._next_ckpt = self._next_multiple(self.cfg.checkpoint_every)
        return path

    def checkpoint_due(self) -> bool:
        """Whether ``checkpoint_every`` episodes have passed since the last checkpoint."""
        return len(self.history) >= self._next_ckpt

    def stop(self) -> None:
        """Adds the wall time since the clock last started to ``elapsed_s`` and stops the clock."""
        if self._started is not None:
            self.counters["elapsed_s"] += time.perf_counter() - self._started
            self._started = None

    def finish(self) -> list[dict]:
        """Waits for the periodic evaluations still under way and records them (:meth:`record_validations`), then
        stops the evaluator; returns every validation record. What :meth:`run` does at its end, for a caller of
        ``run(..., finish=False)``: a finished run's last checkpoint, which listed those evaluations as under way,
        is written again with them recorded, as ``run(...)`` would have left it."""
        try:
            if self.pending and len(self.history) >= self.episodes:
                self.checkpoint(final=True)
            else:
                self.record_validations(before=math.inf)
        finally:
            self.close()
        return self.validations

    def close(self) -> None:
        """Stops the evaluator; a validation still under way is not recorded. Safe to call again."""
        if self.evaluator is not None:
            self.evaluator.close()
