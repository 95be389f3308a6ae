"""Returns of two reference policies on the study's test traffic, the floor a learning system must clear:
standing still (lane kept, -5 m/s² until stopped) and uniformly random commands (RandomDrivingPolicy).
    python studies/paper/reference_policies.py [episodes] [scenario]  ->  studies/paper/reference_policies.json
Same env, seed convention (seed 0's test traffic, seed + 1,000,000) and episode metrics as the study's runs."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf
from tensordict.nn import TensorDictModuleBase

from kddrl_trl.baselines.random_policy import RandomDrivingPolicy
from kddrl_trl.eval import evaluate_policy
from kddrl_trl.factories import make_env
from kddrl_trl.keys import CF_ACTION, LC_ACTION
from kddrl_trl.protocol import test_seed


class StandStill(TensorDictModuleBase):
    in_keys: list = []
    out_keys = [LC_ACTION, CF_ACTION]

    def forward(self, td):
        td.set(LC_ACTION, F.one_hot(torch.ones(td.batch_size, dtype=torch.long), 3).float())  # keep the lane
        td.set(CF_ACTION, torch.full((*td.batch_size, 1), -5.0))
        return td


def main(episodes: int = 200, scenario: str = "baseline") -> dict:
    with initialize_config_module("kddrl_trl.conf", version_base="1.3"):
        cfg = compose("config", overrides=[f"+scenario={scenario}", "algo=idm_mobil", "progress=false"])
    job = OmegaConf.to_object(cfg)
    out = {}
    for name, policy in (
        ("stand_still", StandStill()),
        ("random", RandomDrivingPolicy(generator=torch.Generator().manual_seed(0))),
    ):
        env = make_env(job.env, job.algo, 0)
        try:
            eps = evaluate_policy(env, policy, episodes, test_seed(0, None), progress=False)
        finally:
            env.close()
        out[name] = {
            k: float(np.mean([e[k] for e in eps]))
            for k in ("return_lc", "return_cf", "mean_speed_kmh", "collision", "frames", "lane_changes")
        }
        out[name]["episodes"] = episodes
        print(name, json.dumps(out[name]))
    path = Path(__file__).with_name("reference_policies.json")
    path.write_text(json.dumps({"scenario": scenario, "eval_seed": test_seed(0, None), **out}, indent=2) + "\n")
    return out


if __name__ == "__main__":
    main(*(int(a) if i == 0 else a for i, a in enumerate(sys.argv[1:])))
