"""``python -m kddrl_trl.evaluate run=<training run dir> [+scenario=congested|braking] [eval_episodes=N]
[checkpoint=latest|best]``.

Loads the trained learner of a run (its ``config.yaml`` and latest or best checkpoint), evaluates it with exploration
off on the requested traffic with the same code as the final evaluation of ``kddrl_trl.train``
(:func:`kddrl_trl.eval.final.final_evaluation`), and writes ``summary.json`` and ``eval_episodes.csv`` into
``<run>/eval__<scenario>__<seed>__<time>/``. Wires the parts of :mod:`kddrl_trl.factories` only.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from . import conf as _conf  # noqa: F401  (registers the typed schemas and the scenarios with Hydra)
from .compiling import fresh_compiler
from .conf.schema import EvaluateJob
from .eval.final import final_evaluation
from .eval.metrics import paper_reference
from .factories import make_job, make_logger, make_policy, make_test_env, make_trained_learner
from .process_settings import seed_everything
from .protocol import check_disjoint, test_seed
from .provenance import code_commit
from .run_folder import no_folder_if_refused, trained_run


@hydra.main(version_base="1.3", config_path="conf", config_name="evaluate")
def main(cfg: DictConfig) -> dict:
    # a refused or failed evaluation leaves no folder: one line naming the key, the run or the file
    with no_folder_if_refused(outputs=True):
        return _evaluate(cfg)


def _evaluate(cfg: DictConfig) -> dict:
    code_commit()  # the commit of the code loaded now, whatever is checked out when the evaluation ends
    trained_run(cfg.run)  # before anything else is resolved: a missing run is the one line printed
    job: EvaluateJob = make_job(cfg)  # typed, ranges checked before any simulator starts
    fresh_compiler()  # a launcher's reused worker holds earlier jobs' graphs
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    algo, learner, ckpt, saved = make_trained_learner(Path(job.run), job.checkpoint, job.torch_device, job.shield)
    env_seed, trained_on = test_seed(job.seed, job.eval_seed), str(saved.env.scenario)
    check_disjoint("eval_seed", env_seed, int(saved.seed), int(saved.episodes))  # the run's own training traffic
    seed_everything(job.seed)
    result = final_evaluation(
        job,
        make_test_env(job, algo, job.env),
        make_policy(algo, job.env, learner),
        algo.name,
        make_logger(job.logger, out_dir),
        out_dir,
        title=f"{algo.name} trained on {trained_on}, evaluated on {job.env.scenario}, "
        f"seed {job.seed}, exploration off ({ckpt.name})"
        + (
            f", shield {job.shield} (trained with {saved.algo.get('shield', 'none')})" if job.shield is not None else ""
        ),
        trained_on=trained_on,
        # the paper's figures where they compare: a policy on the traffic it was trained on
        reference=paper_reference(job.env.scenario, algo.name) if trained_on == job.env.scenario else None,
        checkpoint=str(ckpt),
        seed=job.seed,
        eval_seed=env_seed,
    )
    return result.write()


if __name__ == "__main__":
    main()
