"""``evaluate_policy``: run a policy on a batched highway env until a number of whole episodes have finished."""

from __future__ import annotations

from typing import Callable

import torch
from torchrl.envs.transforms import Compose, TransformedEnv
from tqdm.auto import tqdm

from ..envs.episode_metrics import IN_KEYS, OPTIONAL_KEYS, EpisodeTracker
from ..envs.specs import HighwayEnvBase


def unwrap_env(env):
    """The innermost env of ``env`` (through ``TransformedEnv`` s), e.g. the ``SumoHighwayEnv``; a batched env
    (``ParallelEnv``) is returned as it is: it forwards unknown names to its workers, so it is not asked for any."""
    while isinstance(env, TransformedEnv):
        env = env.base_env
    return env


def restart_noise(env) -> None:
    """Restarts the noise streams of ``env`` 's transforms (each member with a ``reseed``: the generative
    predictors', :class:`~kddrl_trl.transforms.frozen_predictor.FrozenPredictorTransform`) from their own seeds, through the
    ``TransformedEnv`` layers of this process (a ``ParallelEnv`` 's workers keep theirs). TorchRL's
    ``TransformedEnv.set_seed`` seeds only the base env, and those streams run on over resets."""

    def members(transform):
        if isinstance(transform, Compose):
            for t in transform.transforms:
                yield from members(t)
        else:
            yield transform

    while isinstance(env, TransformedEnv):  # not into a batched env's workers: it forwards unknown names there
        for t in members(env.transform):
            if callable(getattr(type(t), "reseed", None)):  # on the class: a module forwards unknown names
                t.reseed()
        env = env.base_env


@torch.no_grad()
def evaluate_policy(
    env,
    policy: Callable,
    episodes: int,
    seed: int,
    progress: bool = True,
    on_episode: Callable[[dict], None] | None = None,
    trace: Callable | None = None,
) -> list[dict]:
    """Seed ``env`` with ``seed`` (its transforms' noise restarted too, :func:`restart_noise`: the same seed gives
    the same episodes on every call, as every periodic validation needs), reset it and step it with ``policy``
    until the first ``episodes`` episodes *to start* have all finished; return their
    :class:`~kddrl_trl.eval.EpisodeTracker` metrics in start order (``ep["start"]`` = 0, 1, ...). ``on_episode``
    is called with each of them as it finishes.

    ``env``: any env writing the raw keys and episode events of ``kddrl_trl.keys`` (``SumoHighwayEnv``,
    ``FakeHighwayEnv``, bare or inside a ``TransformedEnv``, of any batch size); done rows are reset as TorchRL's
    ``step_and_maybe_reset`` does. Counting by start order (not by completion) keeps the sample unbiased: with
    K roads running at once, the first episodes to finish are the short ones. ``trace`` (e.g. a
    :class:`~kddrl_trl.eval.trace.TraceRecorder`) is called with every step's TensorDict.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"evaluate_policy: episodes must be an integer >= 1, got {episodes!r}")
    env.set_seed(int(seed))
    restart_noise(env)
    td = env.reset()
    base = unwrap_env(env)
    tracker = EpisodeTracker(base.config if isinstance(base, HighwayEnvBase) else None)
    wanted: dict[int, dict] = {}
    pending = []  # frames since the last done: the tracker runs once per frame that ends an episode
    bar = tqdm(total=episodes, desc="episodes", disable=not progress, unit="ep")
    while len(wanted) < episodes:
        full, td = env.step_and_maybe_reset(policy(td))
        if trace is not None:
            trace(full)
        pending.append(full.select(*IN_KEYS, *OPTIONAL_KEYS, strict=False).reshape(-1))
        if not pending[-1].get(("next", "done")).any():
            continue
        frames, pending = torch.stack(pending, 1), []
        for ep in tracker(frames):
            if ep["start"] >= episodes:
                continue
            wanted[ep["start"]] = ep
            bar.update(1)
            if on_episode is not None:
                on_episode(ep)
            bar.set_postfix(
                speed_kmh=f"{sum(e['mean_speed_kmh'] for e in wanted.values()) / len(wanted):.1f}",
                collisions=sum(e["collision"] for e in wanted.values()),
            )
    bar.close()
    return [wanted[i] for i in range(episodes)]
