"""Statistics over seeds: the seed (one trained policy) is the unit of evidence (docs/design.md, "Evidence").

Every interval of the reports comes from here, so that no two sections disagree (the verdict's tests are these
functions too, :mod:`kddrl_trl.reporting.verdict`):

* the mean of one system's per-seed values (or of paired differences): Student's t interval and one-sample test
  (``scipy.stats.ttest_1samp``);
* the difference of two systems' means: Welch's t-test and its interval (``scipy.stats.ttest_ind``, unequal
  variances), or the paired t-test (``scipy.stats.ttest_rel``) where the plan pairs seeds;
* the ratio of two systems' means: Welch's interval of the log-ratio (the delta method), which stays positive;
* a rate pooled over every episode of a row (a description of those trained policies, not an interval for the
  method): the exact Clopper-Pearson interval (``scipy.stats.binomtest``);
* Holm's step-down adjustment over a family (``statsmodels.stats.multitest.multipletests``).

A collision rate is a per-seed value like any other (each seed's rate is one observation). With 5 seeds a
percentile bootstrap covers far less than its nominal level, so none is used. With one seed there is no interval
(None); with no spread at all, the interval is the value itself and the test's p-value is 1 (no evidence either
way), never 0.
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np

CONFIDENCE = 0.95


def _finite(values, what: str) -> np.ndarray:
    x = np.asarray(values, dtype=float)
    if x.size == 0 or not np.isfinite(x).all():
        raise ValueError(f"{what}: need finite values, got {x.tolist()}")
    return x


def mean_test(values, null: float = 0.0, confidence: float = CONFIDENCE) -> dict:
    """``{"mean", "ci_low", "ci_high", "p", "n"}`` of ``values`` (one per seed, or paired differences): Student's t
    interval of the mean and the two-sided one-sample t-test of H0: mean = ``null``."""
    from scipy.stats import ttest_1samp

    x = _finite(values, "mean_test")
    mean = float(x.mean())
    if x.size < 2:
        return {"mean": mean, "ci_low": None, "ci_high": None, "p": None, "n": int(x.size)}
    if np.ptp(x) == 0:
        return {"mean": mean, "ci_low": mean, "ci_high": mean, "p": 1.0, "n": int(x.size)}
    res = ttest_1samp(x, null)
    ci = res.confidence_interval(confidence)
    return {"mean": mean, "ci_low": float(ci.low), "ci_high": float(ci.high), "p": float(res.pvalue), "n": int(x.size)}


def mean_ci(values, confidence: float = CONFIDENCE, within: tuple[float, float] | None = None) -> dict:
    """``{"mean", "ci_low", "ci_high", "n"}`` of ``values`` (one per seed): Student's t interval of the mean, cut to
    ``within`` (the values' possible range, e.g. [0, 1] for a rate) when given."""
    out = {k: v for k, v in mean_test(values, confidence=confidence).items() if k != "p"}
    if within is not None and out["ci_low"] is not None:
        out["ci_low"], out["ci_high"] = max(out["ci_low"], within[0]), min(out["ci_high"], within[1])
    return out


def difference_test(values, reference, null: float = 0.0, paired: bool = False, confidence: float = CONFIDENCE):
    """Mean of ``values`` minus mean of ``reference`` (per-seed values; ``paired``: the same seeds in the same
    order) with the test of H0: difference = ``null`` (two-sided; Welch's, or the paired t-test) and the
    interval of the difference at ``confidence`` -> ``{"mean", "ci_low", "ci_high", "p", "test", "n"}``.
    No spread on either side: the interval is the difference itself and p is 1."""
    from scipy.stats import ttest_ind, ttest_rel

    x, y = _finite(values, "difference_test"), _finite(reference, "difference_test")
    if paired and x.size != y.size:
        raise ValueError(f"difference_test: paired values need the same seeds, got {x.size} and {y.size}")
    value = float(x.mean() - y.mean())
    out = {"mean": value, "ci_low": None, "ci_high": None, "p": None, "test": "paired" if paired else "welch"}
    out["n"] = [int(x.size), int(y.size)]
    if min(x.size, y.size) < 2:
        return out
    sides = (np.ptp(x), np.ptp(y))
    spread = np.ptp(x - y) if paired else max(sides)
    if spread == 0:
        return {**out, "ci_low": value, "ci_high": value, "p": 1.0}
    with warnings.catch_warnings():
        if not paired and min(sides) == 0:
            # a side without spread (no collision at any seed) has variance 0 exactly; shifted by a null, scipy's
            # rounding of its mean reads as "nearly identical data", a warning about a value known exactly
            warnings.filterwarnings("ignore", "Precision loss", RuntimeWarning)
        res = ttest_rel(x - null, y) if paired else ttest_ind(x - null, y, equal_var=False)
    ci = res.confidence_interval(confidence)
    return {**out, "ci_low": float(ci.low) + null, "ci_high": float(ci.high) + null, "p": float(res.pvalue)}


def difference_ci(values, reference, confidence: float = CONFIDENCE) -> dict:
    """Mean of ``values`` minus mean of ``reference`` (independent seeds) with Welch's interval and p-value
    (:func:`difference_test`), and the probability of improvement ``P(X > Y)`` over all pairs of seeds (ties count
    one half)."""
    x, y = _finite(values, "difference_ci"), _finite(reference, "difference_ci")
    pairs = x[:, None] - y[None, :]
    return {
        **difference_test(x, y, confidence=confidence),
        "p_greater": float(((pairs > 0) + 0.5 * (pairs == 0)).mean()),
    }


def ratio_ci(values, reference, confidence: float = CONFIDENCE) -> dict:
    """Mean of ``values`` divided by the mean of ``reference`` (independent seeds; e.g. a policy's mean speed over
    the rule baseline's, as the safety goal "speed >= 1.05 x IDM+MOBIL's" reads): Welch's interval of the log of
    the ratio (delta method: var ≈ s_x² / (n_x m_x²) + s_y² / (n_y m_y²), Welch-Satterthwaite degrees of freedom),
    taken back by exp. Both means must be > 0."""
    from scipy.stats import t

    x, y = _finite(values, "ratio_ci"), _finite(reference, "ratio_ci")
    if not (x.mean() > 0 and (y > 0).all()):
        raise ValueError(f"ratio_ci: the means must be > 0, got {x.tolist()} over {y.tolist()}")
    ratio = float(x.mean() / y.mean())
    out = {"mean": ratio, "ci_low": None, "ci_high": None}
    if min(x.size, y.size) < 2:
        return out
    vx, vy = x.var(ddof=1) / (x.size * x.mean() ** 2), y.var(ddof=1) / (y.size * y.mean() ** 2)
    if vx + vy == 0:
        return {**out, "ci_low": ratio, "ci_high": ratio}
    df = (vx + vy) ** 2 / (vx**2 / (x.size - 1) + vy**2 / (y.size - 1))
    half = float(t.ppf(0.5 + confidence / 2, df)) * math.sqrt(vx + vy)
    return {**out, "ci_low": ratio * math.exp(-half), "ci_high": ratio * math.exp(half)}


def clopper_pearson(k: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Exact binomial interval of a rate of ``k`` events in ``n`` trials (``scipy.stats.binomtest``)."""
    from scipy.stats import binomtest

    if n <= 0 or not 0 <= k <= n:
        raise ValueError(f"clopper_pearson: need 0 <= k <= n and n > 0, got k={k}, n={n}")
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=confidence, method="exact")
    return float(ci.low), float(ci.high)


def holm(pvalues) -> list[float]:
    """Holm-Bonferroni adjusted p-values in the input's order (``statsmodels``' ``multipletests``)."""
    from statsmodels.stats.multitest import multipletests

    p = np.asarray(pvalues, dtype=float)
    return [] if p.size == 0 else multipletests(p, method="holm")[1].tolist()


def t_power(effect: float, sd: float, n: int, alpha: float, paired: bool) -> float:
    """Power of the two-sided t-test at ``alpha`` with ``n`` seeds per system against a true difference ``effect``
    (``paired``: the one-sample test of the differences, ``sd`` theirs; else the two-sample test at the common
    ``sd``, Welch's read as the equal-variance test): P(|T| > t_crit) for T noncentral t. It is integrated over the
    χ² of the spread, T = (Z + δ) / sqrt(V / df), because the noncentral t's own tail (scipy's ``nct``, behind
    statsmodels' power classes) returns NaN far out at small n, and a NaN read as power 1 overstates it there."""
    from scipy.stats import chi2, norm, t

    df = n - 1 if paired else 2 * n - 2
    if df < 1:
        return float("nan")
    if sd <= 0:
        return 1.0 if effect != 0 else alpha
    delta = abs(effect) / sd * math.sqrt(n if paired else n / 2)
    crit = float(t.ppf(1 - alpha / 2, df))
    # Gauss-Legendre over the χ²'s quantile u in (0, 1), where the integrand is bounded and smooth (within 1e-6 of
    # adaptive quadrature from n = 2 to 1000)
    u, w = _legendre()
    scale = crit * np.sqrt(chi2.ppf((u + 1) / 2, df) / df)
    total = np.dot(w / 2, norm.cdf(delta - scale) + norm.cdf(-delta - scale))
    # rounded to 1e-12, far below the rule's accuracy: the dot product's last bits depend on the CPU's vector width
    # (an AVX-512 and an AMX machine part at 1e-17), and a report must regenerate byte-identical on either
    return float(min(1.0, round(float(total), 12)))


@functools.cache
def _legendre(nodes: int = 512) -> tuple[np.ndarray, np.ndarray]:
    return np.polynomial.legendre.leggauss(nodes)


def seeds_for_power(effect: float, sd: float, alpha: float, paired: bool, power: float = 0.8) -> float:
    """The smallest number of seeds per system at which :func:`t_power` reaches ``power`` (at least 2). ``inf`` when
    there is no spread to measure against, or past 10**7 seeds."""
    if sd <= 0 or effect == 0:
        return math.inf

    def enough(n: int) -> bool:
        return t_power(effect, sd, n, alpha, paired) >= power

    low, high = 1, 2
    while not enough(high):
        low, high = high, high * 2
        if high > 10**7:
            return math.inf
    while high - low > 1:  # the power grows with n: the smallest n that is enough
        mid = (low + high) // 2
        low, high = (low, mid) if enough(mid) else (mid, high)
    return float(high)


def permutation_p(values, reference, paired: bool, resamples: int = 99_999, seed: int = 0) -> float | None:
    """Two-sided permutation p-value of H0: no difference between ``values`` and ``reference``
    (``scipy.stats.permutation_test``), a sensitivity check beside the t-tests that assumes no normality.

    * ``paired``: the signs of the per-seed differences flipped, every arrangement (2^n, exact at n = 10) and the
      mean difference as the statistic;
    * else the seeds' labels reassigned at random ``resamples`` times (``seed`` fixes them, so that a report
      regenerates identically), Welch's t as the statistic (the spreads differ by system).

    None with fewer than two seeds a side, or no spread at all."""
    from scipy.stats import permutation_test

    x, y = _finite(values, "permutation_p"), _finite(reference, "permutation_p")
    if min(x.size, y.size) < 2 or (np.ptp(x - y) if paired else max(np.ptp(x), np.ptp(y))) == 0:
        return None
    if paired:
        if x.size != y.size:
            raise ValueError(f"permutation_p: paired values need the same seeds, got {x.size} and {y.size}")

        def mean_difference(a, b, axis):
            return np.mean(a - b, axis=axis)

        res = permutation_test(
            (x, y), mean_difference, permutation_type="samples", n_resamples=2**x.size, vectorized=True
        )
        return float(res.pvalue)

    def welch(a, b, axis):
        va, vb = np.var(a, axis=axis, ddof=1) / a.shape[axis], np.var(b, axis=axis, ddof=1) / b.shape[axis]
        return (np.mean(a, axis=axis) - np.mean(b, axis=axis)) / np.sqrt(va + vb)

    res = permutation_test((x, y), welch, n_resamples=resamples, vectorized=True, rng=np.random.default_rng(seed))
    return float(res.pvalue)


def noisy_reference_test(values, reference, target: float, runs: int, paired: bool) -> float | None:
    """Two-sided p-value of H0: our true difference equals the true difference behind ``target``, read as one
    study's estimate from ``runs`` seeds per system with our spread (so the paper's single-run Δ is no exact
    constant): (ours − target) / sqrt(se_ours² + se_target²), se_target² = (s_x² + s_y²) / runs (``paired``: the
    differences' s² / runs), Welch-Satterthwaite degrees of freedom (``paired``: n − 1). None without spread."""
    from scipy.stats import t

    x, y = _finite(values, "noisy_reference_test"), _finite(reference, "noisy_reference_test")
    if min(x.size, y.size) < 2:
        return None
    gap = float(x.mean() - y.mean() - target)
    if paired:
        var = float(np.var(x - y, ddof=1)) * (1 / x.size + 1 / runs)
        df = x.size - 1.0
    else:
        cx, cy = x.var(ddof=1) * (1 / x.size + 1 / runs), y.var(ddof=1) * (1 / y.size + 1 / runs)
        var = float(cx + cy)
        df = var**2 / (cx**2 / (x.size - 1) + cy**2 / (y.size - 1)) if var > 0 else 0.0
    if var <= 0:
        return None
    return float(2 * t.sf(abs(gap) / math.sqrt(var), df))
