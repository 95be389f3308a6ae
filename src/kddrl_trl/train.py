"""Main entry point: ``python -m kddrl_trl.train [+scenario=congested|braking] [algo=...] [key=value ...]``.

Wires the parts of :mod:`kddrl_trl.factories` and holds no algorithm:

- learning algos (``kddrl`` by default, ``d3qn_td3``, ``d3qn_td3_lg``, ``kddrl_same_clock``, ``ni``, ``peng``,
  ``d3qn_unified``, ``pasac_unified``): train for ``episodes`` episodes (:class:`~kddrl_trl.training.Trainer`,
  checkpoints every ``train.checkpoint_every`` episodes, periodic validation every ``train.eval_every``,
  ``resume=true`` continues), then evaluate ``eval_episodes`` episodes with exploration off on a fresh env;
- rule-based algos (``algo=idm_mobil``): evaluate ``eval_episodes`` episodes.

The evaluation traffic never repeats training traffic (:mod:`kddrl_trl.protocol`). Outputs go to
``runs/<scenario>__<algo>__<seed>__<time>/`` (a sweep, ``-m``: ``runs/multirun__<time>/<scenario>__<algo>__<seed>``;
``-m ... resume=true`` continues the newest sweep job by job, skipping finished jobs): ``config.yaml``,
``train_episodes.csv``, ``validation.csv``, ``training_curves.png``, ``checkpoints/``, ``eval_episodes.csv``,
``summary.json``, TorchRL CSV logs. With ``eval_scenarios=[...]`` (e.g. a run trained on ``+scenario=mixed``) the final
evaluation runs once per listed scenario, each into ``<run>/final__<scenario>/`` (``summary.json`` with ``trained_on``,
``eval_episodes.csv``, logs); the run folder's ``summary.json`` then holds the training summary and names them.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import hydra
import numpy as np
from omegaconf import DictConfig, OmegaConf

from . import conf as _conf  # noqa: F401  (registers the typed schemas and the scenarios with Hydra)
from .compiling import SHORT_RUN_EPISODES, fresh_compiler
from .conf.schema import LearningAlgo, TrainJob
from .eval.final import FinalEvaluation, seed_batch_evaluations
from .eval.final import final_evaluation as run_final_evaluation
from .eval.metrics import paper_reference
from .factories import (
    make_buffers,
    make_collector,
    make_env_factories,
    make_evaluator,
    make_job,
    make_learner,
    make_logger,
    make_policy,
    make_run_dir,
    make_seed_batch,
    make_seed_batch_collector,
    make_seed_batch_env,
    make_seed_batch_test_env,
    make_test_env,
)
from .loggers import trim_logs
from .process_settings import seed_everything
from .protocol import protocol
from .provenance import code_commit, provenance
from .run_folder import RunFolder, config_differences
from .training import Trainer, plot_training_curves

log = logging.getLogger(__name__)


def train(job: TrainJob, run: RunFolder, logger, resuming: bool):
    """Trains the learner of ``job.algo`` (continuing ``run`` 's latest checkpoint when ``resuming``);
    returns it, the summary of its training and the trainer, whose validation of the last episode may still run
    beside the final evaluation (:func:`finish_validations`)."""
    learner = make_learner(job.algo, compile=job.compile, device=job.torch_device, cudagraphs=job.cudagraphs)
    buffers = make_buffers(job.train, job.seed, learner.device)
    trainer = Trainer(
        learner,
        buffers,
        job.train,
        run.path,
        logger,
        episodes=job.episodes,
        progress=job.progress,
        evaluator=make_evaluator(job),
        threads=job.threads,
        highway=job.env.highway(),
    )
    done = trainer.load(run.path) if resuming else 0
    if done:
        log.info("resuming %s", run.path)
        trim_logs(run.path, last_step=done - 1, eval_last_step=trainer.validated_through())
    # a resumed run meets new traffic: the envs (one per collection worker) start from seed + episodes already done
    envs = make_env_factories(job, seed=job.seed + done)
    collector = make_collector(
        envs, learner, buffers, job.train, job.algo.lc_reward, collector=job.collector, rows=job.env.num_roads
    )
    trainer.run(collector, finish=False)
    try:
        write_training(trainer, run, job)
    except BaseException:
        trainer.close()
        raise
    return learner, training_summary(trainer), trainer


def training_summary(trainer: Trainer) -> dict:
    """The ``training`` part of a run's summary: the trainer's counters, its episodes and the means of its last 100."""
    tail = trainer.history[-100:]
    last100 = {
        k: float(np.mean([h[k] for h in tail])) for k in ("return_lc", "return_cf", "mean_speed_kmh", "collision")
    }
    return {**trainer.counters, "episodes": len(trainer.history), "last100": last100}


def write_training(trainer: Trainer, run: RunFolder, job: TrainJob) -> None:
    """A trained run's ``train_episodes.csv`` and ``training_curves.png``."""
    run.write_table(run.train_episodes, trainer.history)
    plot_training_curves(trainer.history, run.curves, title=f"{job.algo.name} on {job.env.scenario}, seed {job.seed}")


def train_seed_batch(job: TrainJob, cfg: DictConfig, run: RunFolder, resuming: bool, started: float) -> list[dict]:
    """A seed batch (``seeds=[...]``, :mod:`kddrl_trl.training.seed_batch_trainer`): each seed trains into its own
    folder of ``run`` (config, records, checkpoints, validations, as its run alone writes them, the summary naming
    the batch), then its final evaluation runs on its own test traffic; returns the seeds' summaries. A seed whose
    summary is written is done: a resumed batch writes only the others' evaluations (it evaluates every seed again,
    all N on one simulation, when a batch was stopped between two seeds' summaries)."""
    jobs = job.seed_jobs()
    seeds = [j.seed for j in jobs]
    batch = make_seed_batch(job, run.path)
    books = batch.books
    runs = [RunFolder(b.run_dir) for b in books]
    for seed_job, seed_run in zip(jobs, runs):
        if not seed_run.config.is_file():
            seed_cfg = OmegaConf.to_container(cfg, resolve=True)
            seed_run.write_config(OmegaConf.to_yaml({**seed_cfg, "seed": seed_job.seed, "seeds": None}))
    if not resuming:
        batch.record(seeds=seeds, folders=[r.path.name for r in runs])
    done = batch.load() if resuming else [0] * len(seeds)
    for book, seed_run, n in zip(books, runs, done):
        if n:
            trim_logs(seed_run.path, last_step=n - 1, eval_last_step=book.validated_through())
    if any(n < job.episodes for n in done):
        envs = make_seed_batch_env(job, [s + n for s, n in zip(seeds, done)])
        batch.run(make_seed_batch_collector(envs, batch, job))
    try:
        todo = [i for i, r in enumerate(runs) if not r.is_finished()]
        if todo:  # every seed at once, each on its own test traffic (a resumed batch writes those not yet written)
            requests = []
            for i, (seed_job, seed_run, book) in enumerate(zip(jobs, runs, books)):
                extra = {"training": training_summary(book), "seed_batch": {"seeds": seeds, "index": i}}
                requests.append(
                    {
                        "job": seed_job,
                        "logger": book.logger,
                        "out_dir": seed_run.path,
                        "title": evaluation_title(seed_job),
                        "reference": paper_reference(job.env.scenario, job.algo.name),
                        "fields": run_fields(seed_job, seed_run, started, extra),
                    }
                )
            env = make_seed_batch_test_env(jobs)
            evaluations = seed_batch_evaluations(
                env, make_policy(job.algo, job.env, batch.learner), job.algo.name, requests
            )
            for i in todo:
                write_training(books[i], runs[i], jobs[i])
                finish_validations(books[i], runs[i])
                evaluations[i].write()
    finally:
        batch.close()
    batch.record(finished=True)
    return [r.read_summary() for r in runs]


def finish_validations(trainer: Trainer | None, run: RunFolder) -> None:
    """Waits for the trainer's last validation and writes every validation to ``validation.csv`` (before the
    ``summary.json`` that marks the run finished)."""
    if trainer is not None and trainer.finish():
        run.write_table(run.validation, trainer.validations)


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> dict:
    code_commit()  # the commit of the code loaded now, whatever is checked out when the run ends
    job: TrainJob = make_job(cfg)  # typed, ranges checked before any simulator starts; refused: no folder left
    fresh_compiler()  # a launcher's reused worker holds earlier jobs' graphs
    run_dir, resuming = make_run_dir(job.resume)
    run = RunFolder(run_dir)
    if run.config.is_file():  # a resumed run or sweep job: the same config, or refuse
        different = config_differences(
            OmegaConf.to_container(OmegaConf.load(run.config)), OmegaConf.to_container(cfg, resolve=True)
        )
        if different:
            raise SystemExit(
                f"{run_dir} holds a run of another config ({'; '.join(different[:5])}): in a sweep over "
                "these keys, add them to hydra.sweep.subdir"
            )
    if run.is_finished():  # a job of a resumed sweep that ended
        log.info("%s is finished (%s): skipped", run_dir, run.SUMMARY)
        return run.read_summary()
    started = time.perf_counter()
    seed_everything(job.seed)
    if not resuming:
        run.write_config(OmegaConf.to_yaml(cfg, resolve=True))
    if job.seeds is not None:
        summaries = train_seed_batch(job, cfg, run, resuming, started)
        folders = [s["run_dir"] for s in summaries]
        print("\n".join(f"seed {seed}: {folder}" for seed, folder in zip(job.seeds, folders)))
        print("\n".join(next_steps(job, run_dir, learning=True, one_run=folders[0])))
        return {"seeds": list(job.seeds), "runs": folders}
    logger = make_logger(job.logger, run_dir)

    extra, learner, trainer = {}, None, None
    if isinstance(job.algo, LearningAlgo):
        learner, extra["training"], trainer = train(job, run, logger, resuming)
    try:
        summary = evaluate_run(job, learner, trainer, logger, run, started, extra)
    finally:
        if trainer is not None:
            trainer.close()
    print("\n".join(next_steps(job, run.path, learning=learner is not None)))
    return summary


def next_steps(job: TrainJob, run_dir, learning: bool, one_run=None) -> list[str]:
    """What a user may run next on this run (a seed batch: ``one_run``, one of its seeds' folders, to evaluate, and
    the batch's folder to report), and, for a short training, that its numbers are a wiring check."""
    lines = []
    if learning and job.episodes < SHORT_RUN_EPISODES:
        lines.append(
            f"note: {job.episodes} training episodes make a wiring check, not a result (the paper, and this job's "
            "default, train 1000)"
        )
    lines.append("next:")
    if learning:
        lines.append(
            f"  python -m kddrl_trl.evaluate run={one_run or run_dir} +scenario=braking video=true  # other traffic, "
            "filmed"
        )
    lines.append(f"  python -m kddrl_trl.report {run_dir} out={run_dir}/report  # its tables with 95 % CIs, figures")
    return lines


def evaluate_run(
    job: TrainJob, learner, trainer: Trainer | None, logger, run: RunFolder, started: float, extra
) -> dict:
    """The final evaluation of a run (one per scenario of ``job.eval_scenarios``), beside the trainer's last
    validation; ``validation.csv`` is written once that ends, and the run's summary last (:meth:`RunFolder.finish`)."""
    seeds = protocol(job.seed, job.episodes, job.eval_seed, job.eval_episodes, job.collector.workers)
    if not job.eval_scenarios:  # the final evaluation on the training traffic, into the run folder
        result = final_evaluation(job, learner, logger, run.path, **run_fields(job, run, started, extra))
        finish_validations(trainer, run)
        return result.write()
    # one final evaluation per scenario (a run trained on +scenario=mixed, evaluated on baseline and on braking)
    finals = [f"final__{s}" for s in job.eval_scenarios]
    for scenario, folder in zip(job.eval_scenarios, finals):
        final_evaluation(
            replace(job, env=job.env.with_scenario(scenario)),
            learner,
            make_logger(job.logger, run.path / folder),
            run.path / folder,
            seed=job.seed,
            protocol=seeds,
            trained_on=job.env.scenario,
            final=True,
        ).write()
    finish_validations(trainer, run)
    summary = {
        "scenario": job.env.scenario,
        "algo": job.algo.name,
        "seed": job.seed,
        "final_evaluations": finals,
        "protocol": seeds,
        "compile": job.compile,
        "torch_threads": job.threads.record(),
        "run_dir": str(run.path),
        "wall_s": time.perf_counter() - started,
        **extra,
        **provenance(),
    }
    return run.finish(summary)


def run_fields(job: TrainJob, run: RunFolder, started: float, extra: dict) -> dict:
    """The summary fields of a run's final evaluation into its own folder: its seed, protocol, folder, start."""
    seeds = protocol(job.seed, job.episodes, job.eval_seed, job.eval_episodes, job.collector.workers)
    return dict(seed=job.seed, protocol=seeds, run_dir=str(run.path), started=started, **extra)


def evaluation_title(job: TrainJob, trained_on: str | None = None) -> str:
    """The heading of a final evaluation's printed table."""
    trained_on = trained_on or job.env.scenario
    title = job.algo.name + ("" if trained_on == job.env.scenario else f" trained on {trained_on}")
    return f"{title} on {job.env.scenario}, seed {job.seed}: evaluation, exploration off"


def final_evaluation(job: TrainJob, learner, logger, out_dir, **fields) -> FinalEvaluation:
    """The greedy policy of ``job.algo`` on ``job.env`` 's traffic, test seed, for ``out_dir``, not yet written
    (:func:`kddrl_trl.eval.final.final_evaluation`)."""
    trained_on = fields.get("trained_on", job.env.scenario)
    return run_final_evaluation(
        job,
        make_test_env(job, job.algo, job.env),
        make_policy(job.algo, job.env, learner),
        job.algo.name,
        logger,
        out_dir,
        title=evaluation_title(job, trained_on),
        reference=paper_reference(job.env.scenario, job.algo.name) if trained_on == job.env.scenario else None,
        **fields,
    )


if __name__ == "__main__":
    main()
