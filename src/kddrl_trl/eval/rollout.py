"""Run a policy on a batched highway env until a number of whole episodes have finished."""
from __future__ import annotations

from typing import Callable

import torch
from tqdm.auto import tqdm


def unwrap_env(env):
    """The innermost env of ``env`` (through ``TransformedEnv`` s), e.g. the ``SumoHighwayEnv``."""
    while hasattr(env, "base_env"):
        env = env.base_env
    return env


@torch.no_grad()
def run_episodes(env, policy: Callable, num_episodes: int, progress: bool = True,
                 on_episode: Callable[[dict], None] | None = None) -> list[dict]:
    """Step ``env`` (a ``SumoHighwayEnv``, possibly inside a ``TransformedEnv``) with ``policy`` until the
    first ``num_episodes`` episodes *to start* have all finished; return their metrics in start order.

    Counting by start order (not by completion) keeps the sample unbiased: with K roads running at once,
    the first episodes to finish are the short ones.
    """
    if num_episodes < 1:
        raise ValueError(f"num_episodes must be >= 1, got {num_episodes}")
    base = unwrap_env(env)
    seen = len(base.episodes)
    wanted: dict[int, dict] = {}
    td = env.reset()  # every road starts a new episode; those cut short by this reset are not recorded
    first = base.sim.episodes_started - base.num_roads
    bar = tqdm(total=num_episodes, desc="episodes", disable=not progress, unit="ep")
    while len(wanted) < num_episodes:
        td = policy(td)
        _, td = env.step_and_maybe_reset(td)
        for ep in base.episodes[seen:]:
            if first <= ep["index"] < first + num_episodes:
                wanted[ep["index"]] = ep
                bar.update(1)
                if on_episode is not None:
                    on_episode(ep)
                bar.set_postfix(speed_kmh=f"{sum(e['mean_speed_kmh'] for e in wanted.values()) / len(wanted):.1f}",
                                collisions=sum(e["collision"] for e in wanted.values()))
        seen = len(base.episodes)
    bar.close()
    return [wanted[i] for i in sorted(wanted)]
