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
    groups: int | None = None,
) -> list[dict] | list[list[dict]]:
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

    ``groups=N`` (a seed batch's env of N x K rows, seed-major): each seed's K rows are counted apart, as an env of
    their own would count them, until every seed has its ``episodes``; returns one list per seed, and
    ``on_episode`` is then called as ``on_episode(ep, i)`` for seed ``i``.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"evaluate_policy: episodes must be an integer >= 1, got {episodes!r}")
    env.set_seed(int(seed))
    restart_noise(env)
    td = env.reset()
    base = unwrap_env(env)
    n = 1 if groups is None else int(groups)
    rows = td.batch_size.numel() // n
    config = base.config if isinstance(base, HighwayEnvBase) else None
    trackers = [EpisodeTracker(config) for _ in range(n)]
    wanted: list[dict[int, dict]] = [{} for _ in range(n)]
    pending = []  # frames since the last done: the trackers run once per frame that ends an episode
    bar = tqdm(total=episodes * n, desc="episodes", disable=not progress, unit="ep")
    while any(len(w) < episodes for w in wanted):
        full, td = env.step_and_maybe_reset(policy(td))
        if trace is not None:
            trace(full)
        pending.append(full.select(*IN_KEYS, *OPTIONAL_KEYS, strict=False).reshape(-1))
        if not pending[-1].get(("next", "done")).any():
            continue
        frames, pending = torch.stack(pending, 1), []
        for i, (tracker, own) in enumerate(zip(trackers, wanted)):
            for ep in tracker(frames if n == 1 else frames[i * rows : (i + 1) * rows]):
                if ep["start"] >= episodes:
                    continue
                own[ep["start"]] = ep
                bar.update(1)
                if on_episode is not None:
                    on_episode(ep) if groups is None else on_episode(ep, i)
        if progress:
            done = [e for w in wanted for e in w.values()]
            bar.set_postfix(
                speed_kmh=f"{sum(e['mean_speed_kmh'] for e in done) / max(len(done), 1):.1f}",
                collisions=sum(e["collision"] for e in done),
            )
    bar.close()
    out = [[w[i] for i in range(episodes)] for w in wanted]
    return out[0] if groups is None else out
