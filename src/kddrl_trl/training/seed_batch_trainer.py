"""``SeedBatchTrainer``: Algorithm 1 for N seeds at once, one batched learner
(:mod:`kddrl_trl.modules.seed_batch`) acting on one env of N x K roads, seed-major (seed ``i`` 's K roads carry the
traffic of its run alone, :class:`~kddrl_trl.envs.sim.HighwaySim` ``road_seeds``).

Each seed keeps what its run alone keeps, in a :class:`~kddrl_trl.training.Trainer` of its own (its run folder,
buffers L and H, episode tracker, logs, counters, periodic validations, checkpoints), whose learner is the seed's
view of the batch (:class:`~kddrl_trl.training.seed_split.SeedView`); this loop drives their bookkeeping
(:meth:`Trainer.start`, :meth:`Trainer.count`, :meth:`Trainer.book`) and runs the updates for all of them at once:

- per collection batch each seed counts its own frames and decisions; its ε anneals by its own decisions;
- TD3: one update per frame of a seed's rows, all training seeds in one stacked step (every seed that has not
  finished has collected the same frames, so they start and step together); D3QN: one update per decision of the
  seed's own, as many stacked steps as the seed with the most decisions needs, the others sitting out the steps
  beyond theirs (``active``: their networks, targets and optimiser states are kept as they were);
- each seed's minibatch is sampled from its own buffers with its own generator, as its run alone samples them, and
  the N minibatches are stacked ``[N, B]`` (:func:`seed_minibatches`); a seed that sits a step out is given another
  seed's minibatch, whose result it never keeps;
- a seed that reaches its episodes writes its last checkpoint and stops learning; its roads drive on, unread;
- periodic validations are shared too (:mod:`kddrl_trl.eval.seed_validation`): when every seed still training is
  due one (``eval_every``), the batch's greedy policy drives N x K validation roads at once, each seed on its own
  validation traffic, and each due seed records its share at its own episode count (a seed ahead of the others
  validates a few episodes later than its run alone would; a finished seed's last, of its frozen weights, once
  none trains any more);
- checkpoints are shared cuts: when every seed still training is due one, all write theirs after the same batch,
  and ``seed_batch.json`` then names the episode count of each (written last). A resumed batch loads each unfinished
  seed from the checkpoint of the last complete cut, and each finished seed from its last, so the seeds resume
  together: same frames, same TD3 step (refused, naming the folders, otherwise).
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
import torch

from ..atomic_files import write_json_atomic
from ..run_folder import RunFolder, checkpoint_candidates
from .checkpoint import CheckpointError, load_latest_training_checkpoint, load_training_checkpoint
from .trainer import MINIBATCHES_PER_DRAW, Trainer, minibatch_draws

log = logging.getLogger(__name__)

#: the record of a seed batch, in its folder: its seeds, their run folders, its last shared checkpoint, finished
SEED_BATCH = RunFolder.SEED_BATCH


def read_seed_batch(folder: str | Path) -> dict | None:
    """The ``seed_batch.json`` of ``folder`` (None where it has none; one that does not parse raises, naming it)."""
    path = Path(folder) / SEED_BATCH
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise CheckpointError(f"{path}: cannot be read ({err})") from err


def seed_minibatches(buffers, counts: list[int]):
    """The ``max(counts)`` stacked minibatches ``[N, batch_size]`` of a seed batch's updates: at step ``j``, row
    ``i`` is the ``j``-th of :func:`~kddrl_trl.training.trainer.minibatches` ``(buffers[i], counts[i])`` (the same
    indices from seed ``i`` 's own generator as its run alone) where ``j < counts[i]``, and another seed's minibatch
    where seed ``i`` sits the step out. The seeds' storage reads line up (each draws ``MINIBATCHES_PER_DRAW`` at a
    time from step 0), so each read of theirs is stacked once and split by step, not stacked step by step. Uniform
    buffers only (a seed batch refuses ``train.prioritized``)."""
    draws = [minibatch_draws(buf, n) for buf, n in zip(buffers, counts)]
    for start in range(0, max(counts, default=0), MINIBATCHES_PER_DRAW):
        own = [next(d) if n > start else None for d, n in zip(draws, counts)]
        m = max(x.shape[0] for x in own if x is not None)
        full = next(x for x in own if x is not None and x.shape[0] == m)
        rows = [full if x is None else x if x.shape[0] == m else torch.cat([x, full[x.shape[0] :]]) for x in own]
        yield from torch.stack(rows, dim=1).unbind(0)


class SeedBatchTrainer:
    """Trains the N seeds of ``learner`` (a learner built with ``seeds=N``), seed ``i`` 's bookkeeping in
    ``books[i]`` (a :class:`Trainer` on a :class:`~kddrl_trl.training.seed_split.SeedView` of seed ``i``, with its
    own buffers, run folder, logger and evaluator), for ``books[i].episodes`` episodes each (module docstring).
    ``folder``: the batch's folder (``seed_batch.json``). ``threads``: a ThreadGovernor told of every batch."""

    def __init__(
        self, learner, books: list[Trainer], cfg, folder: str | Path, *, progress=True, threads=None, validation=None
    ):
        if len(books) != learner.seeds:
            raise ValueError(f"SeedBatchTrainer: {len(books)} seeds' trainers for a learner of {learner.seeds}")
        self.learner, self.books, self.cfg, self.folder = learner, list(books), cfg, Path(folder)
        self.progress, self.threads = progress, threads
        #: the seeds' periodic validations (:class:`~kddrl_trl.eval.seed_validation.SeedBatchValidation`; None:
        #: none), each book's evaluator its seed's view of it
        self.validation = validation

    def close(self) -> None:
        """Stops every seed's evaluator and the batch's validation worker. Safe to call again."""
        for book in self.books:
            book.close()
        if self.validation is not None:
            self.validation.close()

    def _validate(self, still: list[Trainer]) -> None:
        """The batch's validation: when every seed still training is due one (or none trains any more), the
        batch's greedy policy is validated once and each due seed takes its share, at its own episode count."""
        due = [i for i, b in enumerate(self.books) if b.evaluator is not None and b.validation_due()]
        if not due or (still and not all(b.validation_due() for b in still)):
            return
        future = self.validation.submit(self.learner.policy(explore=False))
        for i in due:
            self.books[i].validate(self.validation.share(future, i))

    # ------------------------------------------------------------------------------ checkpoints
    def record(self, **fields) -> None:
        """Updates ``seed_batch.json`` with ``fields`` (atomically)."""
        record = read_seed_batch(self.folder) or {}
        write_json_atomic(self.folder / SEED_BATCH, {**record, **fields})

    def load(self) -> list[int]:
        """Restores each seed from its run folder (module docstring: the last shared cut for the seeds still
        training); returns each seed's episodes done (0: starts afresh)."""
        cut = (read_seed_batch(self.folder) or {}).get("checkpoint", {})
        loaded: list[tuple[Trainer, Path, dict]] = []
        for book in self.books:
            if not checkpoint_candidates(book.run_dir):
                continue
            path, payload = load_latest_training_checkpoint(book.run_dir)
            if len(payload["history"]) < book.episodes:  # still training: the cut's checkpoint, if the cut has one
                episodes = cut.get(book.run_dir.name)
                if episodes is None:
                    continue  # killed before the batch's first shared checkpoint: it starts afresh with the others
                path = book.run_dir / "checkpoints" / f"ep{int(episodes):06d}.pt"
                payload = load_training_checkpoint(path)
            loaded.append((book, path, payload))
        # the finished seeds first: the shared tensors (the TD3 step, the counters) are then those of the others
        loaded.sort(key=lambda x: len(x[2]["history"]) < x[0].episodes)
        training = {str(p): x["counters"]["frames"] for b, p, x in loaded if len(x["history"]) < b.episodes}
        fresh = [b for b in self.books if all(b is not x[0] for x in loaded)]
        if len(set(training.values())) > 1 or (training and fresh):
            raise CheckpointError(
                f"{self.folder}: the seeds still training do not resume from one cut (frames: {training}; afresh: "
                f"{[str(b.run_dir) for b in fresh]}); resume them one by one (resume=<seed folder>) or start again"
            )
        for book, path, payload in loaded:
            book.load_payload(path, payload)
        return [len(b.history) for b in self.books]

    def _checkpoint(self, books: list[Trainer]) -> None:
        """A shared cut: each of ``books`` writes its checkpoint, then ``seed_batch.json`` names them."""
        for book in books:
            book.write_checkpoint()
        cut = {b.run_dir.name: len(b.history) for b in books}
        self.record(checkpoint=cut)

    # ------------------------------------------------------------------------------------ loop
    def _update(self, buffers, counts: list[int], update, counter: str) -> None:
        """``max(counts)`` stacked updates; seed ``i`` takes the first ``counts[i]`` of them, each on a minibatch of
        its own buffer (:func:`seed_minibatches`), and reads its losses (:meth:`Trainer._record`)."""
        outs, masks = [], []
        for j, batch in enumerate(seed_minibatches(buffers, counts)):
            act = [j < n for n in counts]
            outs.append(update(batch, None if all(act) else torch.tensor(act)))
            masks.append(act)
        for i, book in enumerate(self.books):
            mine = [{k: v[i] for k, v in out.items()} for out, act in zip(outs, masks) if act[i]]
            if mine:
                book.counters[counter] += len(mine)
                book._record(mine, book.losses, counter)

    def _updates(self, frames: int, decisions: list[int], training: list[bool]) -> None:
        c, books = self.cfg, self.books
        ready = [
            t and b.counters["frames"] >= c.warmup_frames and len(b.buffer_cf) >= c.batch_size_cf
            for t, b in zip(training, books)
        ]
        if any(ready):
            counts = [frames * c.updates_per_frame if r else 0 for r in ready]
            self._update([b.buffer_cf for b in books], counts, self.learner.update_frame, "cf_updates")
        ready = [t and len(b.buffer_lc) >= c.batch_size_lc for t, b in zip(training, books)]
        if any(ready) and any(d for d, r in zip(decisions, ready) if r):
            counts = [d * c.updates_per_decision if r else 0 for d, r in zip(decisions, ready)]
            self._update([b.buffer_lc for b in books], counts, self.learner.update_decision, "lc_updates")

    def run(self, collector) -> list[list[dict]]:
        """Trains until every seed has its episodes; returns each seed's training-episode history. The seeds'
        validations of their last episode may still run (each trainer's :meth:`Trainer.finish` records them, as
        after ``Trainer.run(..., finish=False)``); on an error every evaluator is stopped. The collector is shut
        down (an env passed in to it stays open)."""
        from tqdm.auto import tqdm

        books, n = self.books, len(self.books)
        total = sum(b.episodes for b in books)
        done = sum(min(len(b.history), b.episodes) for b in books)
        bar = tqdm(total=total, initial=done, desc=f"train {n} seeds", unit="ep", disable=not self.progress)
        try:
            for book in books:
                book.start(collector)
                if len(book.history) >= book.episodes:
                    book.stop()
            for batch in collector:
                if all(len(b.history) >= b.episodes for b in books):
                    break
                if self.threads is not None:
                    self.threads.tick()
                rows = batch.frames.shape[0] // n
                frames = [batch.frames[i * rows : (i + 1) * rows] for i in range(n)]
                training = [len(b.history) < b.episodes for b in books]
                key = collector.writer.decide_key
                decisions = [int(f.get(key).sum()) if t else 0 for f, t in zip(frames, training)]
                per_seed = frames[0].numel()
                for book, t, d in zip(books, training, decisions):
                    if t:
                        book.count(per_seed, d)
                self.learner.explore_step(decisions, per_seed)
                updating = time.perf_counter()
                self._updates(per_seed, decisions, training)
                spent = time.perf_counter() - updating
                collector.update_policy_weights_()
                before = sum(len(b.history) for b in books)
                for book, f, t in zip(books, frames, training):
                    if not t:
                        continue
                    book.counters["update_s"] += spent
                    if book.book(f, finish=False, checkpoint=False, validate=False):
                        book.stop()  # its training time ends with its last episode
                bar.update(sum(len(b.history) for b in books) - before)
                recent = [e["mean_speed_kmh"] for b in books for e in b.history[-50:]]
                bar.set_postfix(
                    seeds_done=sum(len(b.history) >= b.episodes for b in books),
                    kmh=f"{np.mean(recent):.1f}" if recent else "-",
                )
                still = [b for b in books if len(b.history) < b.episodes]
                if self.validation is not None:
                    self._validate(still)
                if still and all(b.checkpoint_due() for b in still):
                    self._checkpoint(still)
                if not still:
                    break
        except BaseException:
            self.close()
            raise
        finally:
            bar.close()
            for book in books:
                book.stop()
            collector.shutdown(close_env=False)
        return [b.history for b in books]
