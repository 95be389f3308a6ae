"""The evaluation protocol: which seeds train, which select a checkpoint, which test (paper §IV.C-E).

A run with ``seed=s`` trains for ``episodes`` episodes on env seeds ``s, s+1, ...`` (a resumed run restarts
its env at ``s + episodes done``, :mod:`kddrl_trl.train`), so its training traffic comes from seeds in
``[s, s + episodes)``. Evaluation traffic must come from elsewhere:

* **validation** (periodic evaluation during training, ``train.eval_every``, and the ``best`` checkpoint):
  env seed ``s + VALIDATION_OFFSET``, the same episodes at every evaluation so that they compare;
* **test** (the final evaluation of ``kddrl_trl.train`` and ``kddrl_trl.evaluate``): env seed
  ``s + TEST_OFFSET`` unless ``eval_seed`` is given, never the validation episodes (no selection bias).

With ``collector.workers=N`` (N env processes, :class:`~kddrl_trl.collectors.workers.WorkerEnv`) worker ``i``
starts its env at ``worker_seed(b, i) = b + i * WORKER_OFFSET`` where ``b`` is the run's env seed (``s``, or
``s + episodes done`` on resume), and seeds its torch generator (exploration draws) with the same number. Worker 0 is
the single-process run's env; runs of nearby seeds (0-4 of a sweep) never share a worker's traffic; at most
:data:`MAX_WORKERS` workers keep every worker's seeds below the validation seed.

**Choosing options** (a preset, a safety option, a hyperparameter) uses the validation traffic only: compare the
candidates' ``validation.csv`` or evaluate them with ``python -m kddrl_trl.evaluate run=<dir> eval_seed=<s + 500000>``.
The test traffic gives the final tables and nothing else; an option chosen on it is confirmed on fresh seeds
before it is reported (studies/paper/README.md).

Both seeds are recorded in every ``summary.json``; :func:`check_disjoint` refuses a seed that would replay
training traffic.
"""

from __future__ import annotations

VALIDATION_OFFSET = 500_000
TEST_OFFSET = 1_000_000
#: distance between the env seeds of two collection workers of one run
WORKER_OFFSET = 10_000
#: the most collection workers of one run (worker seeds stay below ``seed + VALIDATION_OFFSET``)
MAX_WORKERS = VALIDATION_OFFSET // WORKER_OFFSET - 1


def worker_seed(seed: int, worker: int) -> int:
    """The env seed (and torch seed) of collection worker ``worker`` of a run whose env starts at ``seed``."""
    if not 0 <= int(worker) < MAX_WORKERS:
        raise ValueError(f"worker must be in [0, {MAX_WORKERS}), got {worker!r}")
    return int(seed) + int(worker) * WORKER_OFFSET


def training_seeds(seed: int, episodes: int, worker: int = 0) -> range:
    """The env seeds collection worker ``worker`` of a run of ``episodes`` training episodes may draw its traffic
    from."""
    start = worker_seed(seed, worker)
    return range(start, start + max(int(episodes), 1))


def test_seed(seed: int, eval_seed: int | None = None) -> int:
    """The env seed of the final evaluation: ``eval_seed`` if given, else ``seed + TEST_OFFSET``."""
    return int(seed) + TEST_OFFSET if eval_seed is None else int(eval_seed)


def validation_seed(seed: int) -> int:
    """The env seed of the periodic evaluations during training."""
    return int(seed) + VALIDATION_OFFSET


def check_disjoint(name: str, value: int, seed: int, episodes: int, workers: int = 1) -> None:
    """Raise if env seed ``value`` (option ``name``) lies in the training seeds of (``seed``, ``episodes``) of any
    of ``workers`` collection workers."""
    for worker in range(int(workers)):
        train = training_seeds(seed, episodes, worker)
        if value not in train:
            continue
        who = f" (collection worker {worker})" if worker else ""
        raise ValueError(
            f"{name}={value} lies in the training seeds [{train.start}, {train.stop}) of seed={seed}{who} "
            f"with episodes={episodes}: evaluation would replay training traffic (leave {name} unset "
            f"for seed + {TEST_OFFSET})"
        )


def protocol(seed: int, episodes: int, eval_seed: int | None, eval_episodes: int, workers: int = 1) -> dict:
    """The seeds of a training run, checked and as recorded in ``summary.json`` (``worker_seeds``: the env seed
    each collection worker started from, only with more than one worker)."""
    test = test_seed(seed, eval_seed)
    check_disjoint("eval_seed", test, seed, episodes, workers)
    train = training_seeds(seed, episodes)
    out = {
        "train_seeds": [train.start, train.stop - 1],
        "validation_seed": validation_seed(seed),
        "eval_seed": test,
        "eval_episodes": int(eval_episodes),
    }
    if workers > 1:
        out["worker_seeds"] = [worker_seed(seed, i) for i in range(int(workers))]
    return out
