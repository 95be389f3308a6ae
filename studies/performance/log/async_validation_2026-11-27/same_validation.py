"""The periodic validation of one checkpoint's weights, by whichever ``PeriodicEvaluator`` the code on PYTHONPATH
has (the older one steps a ``ParallelEnv`` worker from this process; the newer one runs env and policy in its own
worker): ``python same_validation.py RUN OUT.csv OVERRIDE...`` (the run's own overrides, which compose its job).
Two codes, the same checkpoint: identical CSVs mean the validation itself did not change."""

import sys
from functools import partial

import pandas as pd
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf

from kddrl_trl.eval.periodic import PeriodicEvaluator
from kddrl_trl.eval.protocol import validation_seed
from kddrl_trl.factories import make_env, make_job, make_trained_learner

if __name__ == "__main__":
    run, out = sys.argv[1], sys.argv[2]
    with initialize_config_module(config_module="kddrl_trl.conf", version_base="1.3"):
        job = make_job(compose(config_name="config", overrides=sys.argv[3:]))
    assert OmegaConf.to_container(OmegaConf.load(f"{run}/config.yaml"))["train"] == vars(job.train), "not the run's job"
    _, learner, path, _ = make_trained_learner(run)
    seed = validation_seed(job.seed)
    evaluator = PeriodicEvaluator(
        partial(make_env, job.env, job.algo, seed=seed, compile=False), job.train.eval_episodes, seed
    )
    try:
        episodes, summary = evaluator(learner.policy(explore=False))
    finally:
        evaluator.close()
    pd.DataFrame(episodes).to_csv(out, index=False)
    print(path, summary["mean_speed_kmh"], summary["score"])
