"""Confidence intervals over seeds: the seed (run) is the unit of evidence (docs/design.md, "Evidence").

Percentile bootstrap (``scipy.stats.bootstrap``) of the across-seed mean, and of the difference (or the ratio) of
two systems' means (independent seeds, each resampled on its own). Fixed ``random_state``: the same records give the
same report. With one seed there is no interval (None); with identical values the interval is that value.
"""

from __future__ import annotations

import numpy as np

CONFIDENCE = 0.95
RESAMPLES = 10_000


def _bootstrap(samples: tuple, statistic, confidence: float, resamples: int) -> tuple[float, float]:
    from scipy.stats import bootstrap

    res = bootstrap(
        samples,
        statistic,
        confidence_level=confidence,
        n_resamples=resamples,
        method="percentile",
        vectorized=True,
        random_state=np.random.default_rng(0),
        axis=-1,
    )
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def mean_ci(values, confidence: float = CONFIDENCE, resamples: int = RESAMPLES) -> dict:
    """``{"mean", "ci_low", "ci_high", "n"}`` of ``values`` (one per seed)."""
    x = np.asarray(values, dtype=float)
    if x.size == 0 or not np.isfinite(x).all():
        raise ValueError(f"mean_ci: need finite values, got {x.tolist()}")
    mean = float(x.mean())
    if x.size < 2:
        return {"mean": mean, "ci_low": None, "ci_high": None, "n": int(x.size)}
    if np.ptp(x) == 0:
        return {"mean": mean, "ci_low": mean, "ci_high": mean, "n": int(x.size)}
    low, high = _bootstrap((x,), lambda s, axis=-1: s.mean(axis=axis), confidence, resamples)
    return {"mean": mean, "ci_low": low, "ci_high": high, "n": int(x.size)}


def _two_systems(values, reference, statistic, confidence: float, resamples: int) -> dict:
    """``statistic(x, y)`` of two systems' per-seed values (independent seeds, each resampled on its own) with its
    bootstrap interval, and the probability of improvement ``P(X > Y)`` over all pairs of seeds (ties count one
    half)."""
    x, y = np.asarray(values, dtype=float), np.asarray(reference, dtype=float)
    value = float(statistic(x, y))
    pairs = x[:, None] - y[None, :]
    p_greater = float(((pairs > 0) + 0.5 * (pairs == 0)).mean())
    if min(x.size, y.size) < 2:
        return {"mean": value, "ci_low": None, "ci_high": None, "p_greater": p_greater}
    if np.ptp(x) == 0 and np.ptp(y) == 0:
        return {"mean": value, "ci_low": value, "ci_high": value, "p_greater": p_greater}
    low, high = _bootstrap((x, y), statistic, confidence, resamples)
    return {"mean": value, "ci_low": low, "ci_high": high, "p_greater": p_greater}


def difference_ci(values, reference, confidence: float = CONFIDENCE, resamples: int = RESAMPLES) -> dict:
    """Mean of ``values`` minus mean of ``reference`` (independent seeds) with its bootstrap interval, and the
    probability of improvement ``P(X > Y)`` over all pairs of seeds (ties count one half)."""
    return _two_systems(
        values, reference, lambda a, b, axis=-1: a.mean(axis=axis) - b.mean(axis=axis), confidence, resamples
    )


def ratio_ci(values, reference, confidence: float = CONFIDENCE, resamples: int = RESAMPLES) -> dict:
    """Mean of ``values`` divided by the mean of ``reference`` (independent seeds; e.g. a policy's mean speed over
    the rule baseline's, as the safety goal "speed >= 1.05 x IDM+MOBIL's" reads) with its bootstrap interval."""
    y = np.asarray(reference, dtype=float)
    if y.size == 0 or not (np.isfinite(y).all() and (y > 0).all()):
        raise ValueError(f"ratio_ci: the reference values must be finite and > 0, got {y.tolist()}")
    return _two_systems(values, y, lambda a, b, axis=-1: a.mean(axis=axis) / b.mean(axis=axis), confidence, resamples)
