"""The evaluation protocol: which seeds train, which select a checkpoint, which test (paper §IV.C-E).

A run with ``seed=s`` trains for ``episodes`` episodes on env seeds ``s, s+1, ...`` (a resumed run restarts
its env at ``s + episodes done``, :mod:`kddrl_trl.train`), so its training traffic comes from seeds in
``[s, s + episodes)``. Evaluation traffic must come from elsewhere:

* **validation** (periodic evaluation during training, ``train.eval_every``, and the ``best`` checkpoint):
  env seed ``s + VALIDATION_OFFSET``, the same episodes at every evaluation so that they compare;
* **test** (the final evaluation of ``kddrl_trl.train`` and ``kddrl_trl.evaluate``): env seed
  ``s + TEST_OFFSET`` unless ``eval_seed`` is given, never the validation episodes (no selection bias).

Both seeds are recorded in every ``summary.json``; :func:`check_disjoint` refuses a seed that would replay
training traffic.
"""
from __future__ import annotations

VALIDATION_OFFSET = 500_000
TEST_OFFSET = 1_000_000


def training_seeds(seed: int, episodes: int) -> range:
    """The env seeds a run of ``episodes`` training episodes may draw its traffic from."""
    return range(int(seed), int(seed) + max(int(episodes), 1))


def test_seed(seed: int, eval_seed: int | None = None) -> int:
    """The env seed of the final evaluation: ``eval_seed`` if given, else ``seed + TEST_OFFSET``."""
    return int(seed) + TEST_OFFSET if eval_seed is None else int(eval_seed)


def validation_seed(seed: int) -> int:
    """The env seed of the periodic evaluations during training."""
    return int(seed) + VALIDATION_OFFSET


def check_disjoint(name: str, value: int, seed: int, episodes: int) -> None:
    """Raise if env seed ``value`` (option ``name``) lies in the training seeds of (``seed``, ``episodes``)."""
    train = training_seeds(seed, episodes)
    if value in train:
        raise ValueError(f"{name}={value} lies in the training seeds [{train.start}, {train.stop}) of seed={seed} "
                         f"with episodes={episodes}: evaluation would replay training traffic (leave {name} unset "
                         f"for seed + {TEST_OFFSET})")


def protocol(seed: int, episodes: int, eval_seed: int | None, eval_episodes: int) -> dict:
    """The seeds of a training run, checked and as recorded in ``summary.json``."""
    test = test_seed(seed, eval_seed)
    check_disjoint("eval_seed", test, seed, episodes)
    train = training_seeds(seed, episodes)
    return {"train_seeds": [train.start, train.stop - 1], "validation_seed": validation_seed(seed),
            "eval_seed": test, "eval_episodes": int(eval_episodes)}
