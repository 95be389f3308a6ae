"""Reference rollouts of ``SumoHighwayEnv`` for ``tests/envs/test_env_reference.py``: a fixed action sequence, every
output key of every frame (reset and step outputs, both rewards, done flags), flattened into numpy arrays.

Run as a script to regenerate ``tests/envs/env_reference.npz`` (it was produced from main's code at commit
9dfdc7d, before the observation building was vectorised; regenerate only when the env's behaviour is meant to
change)::

    PYTHONPATH=src python tests/envs/env_reference.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

FIXTURE = Path(__file__).resolve().parent / "env_reference.npz"
# (scenario, K, frames, seed, overrides): baseline and braking (its leader queries), congested (dense traffic,
# many neighbours); max_steps short so that truncations and partial resets happen too
CASES = [
    ("baseline", 3, 300, 0, {"max_steps": 120}),
    ("braking", 2, 300, 1, {}),
    ("congested", 4, 200, 2, {"max_steps": 150}),
]


def actions(k: int, frames: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Lane-change commands [frames, K] (mostly keep) and accelerations [frames, K] in m/s²."""
    rng = np.random.default_rng(seed)
    lc = rng.choice(3, size=(frames, k), p=[0.05, 0.9, 0.05])
    acc = rng.uniform(-3.0, 2.5, size=(frames, k)).astype(np.float32)
    return lc, acc


def rollout(scenario: str, k: int, frames: int, seed: int, overrides: dict) -> dict[str, np.ndarray]:
    """Every leaf of ``env.rollout`` (reset observation under the root, step outputs under ``next``) by
    ``"/"``-joined key name."""
    from kddrl_trl import keys as K
    from kddrl_trl.envs import SumoHighwayEnv

    lc, acc = actions(k, frames, seed)
    t = iter(range(frames))

    def policy(td):
        i = next(t)
        td.set(K.LC_ACTION, torch.nn.functional.one_hot(torch.as_tensor(lc[i]), 3).float())
        td.set(K.CF_ACTION, torch.as_tensor(acc[i]).unsqueeze(-1))
        return td

    env = SumoHighwayEnv(scenario, num_roads=k, seed=seed, **overrides)
    try:
        td = env.rollout(frames, policy, break_when_any_done=False)
    finally:
        env.close()
    check_root(td)
    return flatten(td)


def flatten(td) -> dict[str, np.ndarray]:
    """Step outputs (``next/...``, ``[K, T, ...]``) in full; the root keys (the observation each action was taken
    on, ``[K, T, ...]``) only on the frames where a reset produced them (the first frame of each road and every
    frame after a done: ``reset_rows``), since elsewhere they repeat the previous ``next`` entry (checked by
    :func:`check_root`). Keeps the fixture small."""
    done = td.get(("next", "done")).squeeze(-1).numpy()
    reset_rows = np.zeros_like(done)
    reset_rows[:, 0] = True
    reset_rows[:, 1:] = done[:, :-1]
    out = {"reset_rows": reset_rows}
    for key in td.keys(True, True):
        name = "/".join((key,) if isinstance(key, str) else key)
        arr = td.get(key).numpy()
        out[name] = arr if name.startswith("next/") else arr[reset_rows]
    return out


def check_root(td) -> None:
    """Outside ``reset_rows`` every root key equals the previous frame's ``next`` entry."""
    done = td.get(("next", "done")).squeeze(-1).numpy()
    carried = ~done[:, :-1]
    for key in td.get("next").keys(True, True):
        if key not in td.keys(True, True):  # rewards: step outputs only
            continue
        root, nxt = td.get(key).numpy(), td.get(("next", *((key,) if isinstance(key, str) else key))).numpy()
        np.testing.assert_array_equal(root[:, 1:][carried], nxt[:, :-1][carried], err_msg=str(key))


def reference() -> dict[str, np.ndarray]:
    arrays = {}
    for scenario, k, frames, seed, overrides in CASES:
        for name, arr in rollout(scenario, k, frames, seed, overrides).items():
            arrays[f"{scenario}:{name}"] = arr
    return arrays


if __name__ == "__main__":
    FIXTURE.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(FIXTURE, **reference())
    print(f"written {FIXTURE} ({FIXTURE.stat().st_size} bytes)")
