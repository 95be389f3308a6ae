"""The final evaluation of a run, for ``train`` and ``evaluate``: the greedy policy on the test traffic, its episodes
logged under ``test/``, its traces and videos (:func:`final_evaluation`), and, when the caller has written everything
else, its records (:meth:`FinalEvaluation.write`): ``eval_episodes.csv``, then ``summary.json``, which is written
last and marks the run (or the evaluation) finished (:meth:`kddrl_trl.run_folder.RunFolder.finish`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from torchrl.envs import EnvBase

from ..atomic_files import write_json_atomic
from ..compiling import compile_counts, compile_seconds
from ..envs.episode_metrics import METRIC_FIELDS
from ..protocol import test_seed
from ..provenance import provenance
from ..run_folder import RunFolder
from .metrics import format_summary, summarize
from .rollout import evaluate_policy, unwrap_env
from .trace import TraceRecorder


def evaluate(env: EnvBase, policy, job, logger, out_dir: Path | None = None, algo: str = "") -> tuple[list[dict], dict]:
    """``job.eval_episodes`` episodes of ``policy`` (in start order, :func:`kddrl_trl.eval.evaluate_policy`) on
    the test seed of :mod:`kddrl_trl.protocol`, logged under ``test/``, and the env's counters; closes
    ``env``. With ``job.video``, ``job.video_episodes`` of them are recorded into ``out_dir``: ``traces/*.json``
    (:class:`~kddrl_trl.eval.trace.TraceRecorder`) and ``videos/*.mp4`` (:func:`~kddrl_trl.eval.render.write_video`).
    """
    recorder = None
    if job.video:
        h = job.env
        recorder = TraceRecorder(
            job.video_episodes,
            collisions_only=job.video_select == "collisions",
            scenario=h.scenario,
            algo=algo,
            seed=job.seed,
            num_lanes=h.num_lanes,
            lane_width=h.lane_width,
            section_length=h.section_length,
            step_length=h.step_length,
        )

    try:
        episodes = evaluate_policy(
            env,
            policy,
            job.eval_episodes,
            test_seed(job.seed, job.eval_seed),
            progress=job.progress,
            on_episode=lambda ep: log_test_episode(logger, ep),
            trace=recorder,
        )
        stats = dict(unwrap_env(env).stats)
    finally:
        env.close()
    if recorder is not None:
        from .render import write_video  # matplotlib and ffmpeg, only for a run that records videos

        for i, trace in enumerate(recorder.chosen()):
            name = f"{job.env.scenario}__{algo}__{job.seed}__ep{i}_{trace['lane_changes']}lc_{trace['outcome']}"
            write_json_atomic(out_dir / "traces" / f"{name}.json", trace)
            write_video(trace, out_dir / "videos" / f"{name}.mp4")
    return episodes, stats


def log_test_episode(logger, ep: dict) -> None:
    """A test episode's metrics under ``test/``, at its start number."""
    for key in (*METRIC_FIELDS, "shield_rate"):
        logger.log_scalar(f"test/{key}", float(ep[key]), step=ep["start"])


@dataclass
class FinalEvaluation:
    """A final evaluation that has run and is not yet written: its ``episodes`` and what its summary will hold."""

    out_dir: Path
    episodes: list[dict]
    title: str
    reference: dict | None = None
    fields: dict = field(default_factory=dict)

    def write(self) -> dict:
        """The evaluation's records into ``out_dir`` (:func:`write_results`); the run's last writes."""
        return write_results(self.out_dir, self.episodes, self.title, self.reference, **self.fields)


def final_evaluation(
    job,
    env: EnvBase,
    policy,
    algo: str,
    logger,
    out_dir: Path,
    *,
    title: str,
    reference: dict | None = None,
    **fields,
) -> FinalEvaluation:
    """The final evaluation of ``train`` and ``evaluate``: ``policy`` (the greedy policy of the algo named ``algo``) on
    ``env`` (the test traffic: :func:`kddrl_trl.factories.make_test_env`), evaluated (:func:`evaluate`). Nothing of it
    is written but its traces and videos: the caller writes its own files first (``train``: the validations), then
    :meth:`FinalEvaluation.write` (the summary with the scenario, algo, env counters, flow and ``fields``)."""
    episodes, stats = evaluate(env, policy, job, logger, out_dir, algo)
    return FinalEvaluation(Path(out_dir), episodes, title, reference, _summary_fields(job, algo, stats, fields))


def _summary_fields(job, algo: str, stats: dict, fields: dict) -> dict:
    """What a final evaluation's summary holds besides its episodes' summary."""
    summary_fields = dict(
        scenario=job.env.scenario, algo=algo, env_stats=stats, flow_vph=job.env.flow, compile=job.compile, **fields
    )
    if getattr(job, "threads", None) is not None:  # the torch threads it ran on, and why (kddrl_trl.threads)
        summary_fields["torch_threads"] = job.threads.record()
    return summary_fields


def seed_batch_evaluations(env: EnvBase, policy, algo: str, seeds: list[dict]) -> list[FinalEvaluation]:
    """The final evaluations of a seed batch's N seeds at once. ``seeds[i]``: seed ``i`` 's ``job``, ``logger``,
    ``out_dir``, ``title``, ``reference`` and summary ``fields`` (as :func:`final_evaluation` takes them). ``env``
    holds N x K roads, seed-major, seed ``i`` 's on its own test traffic (``road_seeds`` from
    :func:`~kddrl_trl.protocol.test_seed`: the traffic its run alone is tested on), ``policy`` is the batch's
    greedy policy on all rows; each seed's episodes are counted in start order on its own rows
    (:func:`evaluate_policy` ``groups``) and logged under ``test/`` in its logger. ``env_stats``: the batch env's
    counters (every seed's roads; ``seed_batch_env``). Closes ``env``. No video: a seed's folder is filmed by
    ``kddrl_trl.evaluate run=<seed folder> video=true``."""
    job = seeds[0]["job"]
    try:
        per_seed = evaluate_policy(
            env,
            policy,
            job.eval_episodes,
            test_seed(job.seed, job.eval_seed),
            progress=job.progress,
            on_episode=lambda ep, i: log_test_episode(seeds[i]["logger"], ep),
            groups=len(seeds),
        )
        stats = {**unwrap_env(env).stats, "seed_batch_env": True}
    finally:
        env.close()
    return [
        FinalEvaluation(
            Path(s["out_dir"]),
            episodes,
            s["title"],
            s["reference"],
            _summary_fields(s["job"], algo, stats, s["fields"]),
        )
        for s, episodes in zip(seeds, per_seed, strict=True)
    ]


def write_results(
    out_dir: Path,
    episodes: list[dict],
    title: str,
    reference: dict | None = None,
    started: float | None = None,
    **fields,
) -> dict:
    """Summary of the evaluation ``episodes`` plus ``fields``: written to ``summary.json`` (the episodes to
    ``eval_episodes.csv``) in ``out_dir`` (:meth:`~kddrl_trl.run_folder.RunFolder.finish`) and printed under
    ``title``. ``started`` (a run's start, ``time.perf_counter()``) adds ``wall_s``, the run's whole time, its
    evaluation included; ``compile_s`` is the time this process spent compiling
    (:func:`kddrl_trl.compiling.compile_seconds`), ``compile_counts`` what it compiled and what the compile caches
    served (:func:`kddrl_trl.compiling.compile_counts`)."""
    summary = {**summarize(episodes), **fields, **provenance()}
    if started is not None:
        summary["wall_s"] = time.perf_counter() - started
    summary["compile_s"], summary["compile_counts"] = compile_seconds(), compile_counts()
    RunFolder(out_dir).finish(summary, episodes)
    print(f"\n{title}")
    print(format_summary(summary, reference))
    print(f"results in {out_dir}")
    for line in made(Path(out_dir)):
        print(line)
    return summary


#: what a run folder holds for a reader, in the order :func:`made` names it
MADE = (
    ("videos/*.mp4", "video"),
    ("traces/*.json", "trace"),
    ("training_curves.png", "training curves"),
    ("validation.csv", "validations"),
    ("eval_episodes.csv", "test episodes"),
)


def made(out_dir: Path) -> list[str]:
    """One line per file of :data:`MADE` in ``out_dir`` (its videos, traces, curves, records), with its path."""
    return [f"  {what}: {f}" for pattern, what in MADE for f in sorted(out_dir.glob(pattern))]
