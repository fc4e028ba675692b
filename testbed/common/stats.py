"""Confidence intervals and tests the reports share: Wilson intervals for proportions (P_D per bin, lost-track
rates), Student-t intervals for means over runs or seeds, and the paired statistics for methods run on the same
draws (common random numbers: run i of method A and run i of method B share their truth and noise).

    wilson(k, n, confidence=0.95) -> (lo, hi)        arrays of k successes in n trials (NaN where n == 0)
    mean_ci(values, confidence=0.95) -> (n, mean, sd, lo, hi)
    mcnemar(a, b) -> McNemar(b, c, p)                 exact McNemar test of paired bool outcomes (e.g. lost runs)
    paired_t(a, b, confidence=0.95) -> Interval       Student-t interval of the mean paired difference a - b
    paired_bootstrap(a, b, seed, stat=...) -> Interval  percentile bootstrap over the pairs (runs resampled jointly)

Names of the tests for table headers and captions: MCNEMAR, PAIRED_T, PAIRED_BOOTSTRAP.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats


def wilson(k, n, confidence: float = 0.95):
    """Wilson score interval (lo, hi) of a binomial proportion k / n; k, n scalars (floats out) or arrays of one
    shape (0 <= k <= n); NaN where n == 0. ValueError on k outside [0, n]."""
    if np.ndim(k) == 0 and np.ndim(n) == 0:
        lo, hi = wilson(np.array([k]), np.array([n]), confidence)
        return float(lo[0]), float(hi[0])
    k, n = np.asarray(k, dtype=np.float64), np.asarray(n, dtype=np.float64)
    if np.any(k < 0) or np.any(k > n):
        raise ValueError(f"wilson needs 0 <= k <= n, got k={k.tolist()}, n={n.tolist()}")
    z = float(stats.norm.ppf(0.5 + confidence / 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        p = k / n
        den = 1.0 + z * z / n
        mid = (p + z * z / (2 * n)) / den
        half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
        lo, hi = np.where(n > 0, mid - half, np.nan), np.where(n > 0, mid + half, np.nan)
    lo, hi = np.where(k == 0, 0.0, lo), np.where(k == n, 1.0, hi)  # exact there; rounding gave 1 - 1e-16 at 30/30
    return np.where(n > 0, np.clip(lo, 0.0, 1.0), np.nan), np.where(n > 0, np.clip(hi, 0.0, 1.0), np.nan)


def mean_ci(values, confidence: float = 0.95) -> tuple[int, float, float, float, float]:
    """(n, mean, sd, lo, hi) of the finite values: the Student-t interval of the mean (NaN sd and interval
    for n < 2)."""
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    n = len(x)
    if n == 0:
        return 0, math.nan, math.nan, math.nan, math.nan
    mean = float(np.mean(x))
    if n < 2:
        return 1, mean, math.nan, math.nan, math.nan
    sd = float(np.std(x, ddof=1))
    half = float(stats.t.ppf(0.5 + confidence / 2, n - 1)) * sd / math.sqrt(n)
    return n, mean, sd, mean - half, mean + half


MCNEMAR = "McNemar exact"
PAIRED_T = "paired t 95 % CI"
PAIRED_BOOTSTRAP = "paired bootstrap 95 % CI"


@dataclass(frozen=True)
class McNemar:
    """Exact McNemar test of two paired bool outcomes over the same n runs: b runs where only the first is True,
    c where only the second is; p = two-sided binomial p of b in b + c trials at 1/2 (1 when b + c = 0)."""

    b: int
    c: int
    n: int
    p: float

    def significant(self, alpha: float = 0.05) -> bool:
        """p < alpha: the two rates differ on these runs."""
        return self.p < alpha

    def __str__(self) -> str:
        return f"b = {self.b}, c = {self.c}, p = {self.p:.2g}"


def mcnemar(a, b) -> McNemar:
    """Exact (binomial) McNemar test of paired bool outcomes a, b, each (n,) over the same runs (e.g. "run lost"
    for two filters on the same draws). Only the discordant pairs count: b = #(a and not b), c = #(b and not a);
    under equal rates b ~ Binomial(b + c, 1/2), p = min(1, 2 P(X <= min(b, c))) (two-sided)."""
    a, b_ = np.asarray(a, dtype=bool), np.asarray(b, dtype=bool)
    if a.shape != b_.shape or a.ndim != 1:
        raise ValueError(f"mcnemar needs two equal 1-D bool arrays, got shapes {a.shape} and {b_.shape}")
    nb, nc = int(np.sum(a & ~b_)), int(np.sum(~a & b_))
    p = 1.0 if nb + nc == 0 else float(min(1.0, 2.0 * stats.binom.cdf(min(nb, nc), nb + nc, 0.5)))
    return McNemar(nb, nc, int(a.size), p)


@dataclass(frozen=True)
class Interval:
    """A paired comparison: est with its 95 % (or `confidence`) interval [lo, hi] over n pairs (NaN interval for
    n < 2); test names the method (PAIRED_T or PAIRED_BOOTSTRAP). est, lo, hi are floats, or arrays (k,) of a
    vector statistic (paired_bootstrap with a stat of k values; then below / above / excludes ask it of every
    entry)."""

    est: float
    lo: float
    hi: float
    n: int
    test: str

    @property
    def below(self) -> bool:
        """The whole interval below 0 (False when it is NaN)."""
        return bool(np.all(np.asarray(self.hi) < 0.0))

    @property
    def above(self) -> bool:
        """The whole interval above 0 (False when it is NaN)."""
        return bool(np.all(np.asarray(self.lo) > 0.0))

    def excludes(self, value: float) -> bool:
        """The interval lies entirely on one side of `value` (False when it is NaN)."""
        return bool(np.all((np.asarray(self.lo) > value) | (np.asarray(self.hi) < value)))

    def __iter__(self):
        return iter((self.est, self.lo, self.hi))


def _pairs(a, b) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim < 1 or a.shape[0] == 0:
        raise ValueError(f"paired statistics need two equal non-empty arrays (pairs first), got {a.shape} and "
                         f"{b.shape}")
    return a, b


def paired_t(a, b, confidence: float = 0.95) -> Interval:
    """Student-t interval of the mean paired difference a - b; a, b (n,) per-run values of two methods on the
    same runs (pairs with a non-finite value left out): mean(d) +- t_{n-1} sd(d) / sqrt(n)."""
    a, b = _pairs(a, b)
    if a.ndim != 1:
        raise ValueError(f"paired_t needs 1-D arrays, got {a.shape}")
    n, mean, _, lo, hi = mean_ci(a - b, confidence)
    return Interval(mean, lo, hi, n, PAIRED_T)


def _mean_difference(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    return np.mean(A - B, axis=1)


def paired_bootstrap(a, b, seed, stat=_mean_difference, n_boot: int = 2000, confidence: float = 0.95) -> Interval:
    """Percentile bootstrap interval of a paired statistic. a, b (n, ...): per-run values of two methods on the
    same runs (row i of a and row i of b share their draw); the rows are resampled jointly, n_boot times, with
    the generator np.random.default_rng(seed) (an int, SeedSequence or Generator). stat(A, B) maps arrays
    (m, n, ...) to (m,): one value per resample, over the n runs of axis 1 (default: the mean difference of A - B;
    e.g. RMSE(A) / RMSE(B) for per-run mean squared errors), or to (m, k) for k statistics on the same resamples
    (then est, lo, hi are arrays (k,)). est is stat on the runs as drawn."""
    a, b = _pairs(a, b)
    est = np.asarray(stat(a[None], b[None]), dtype=np.float64)[0]
    n = a.shape[0]
    scalar = lambda v: float(v) if np.ndim(v) == 0 else v  # noqa: E731
    if n < 2:
        return Interval(scalar(est), scalar(est * math.nan), scalar(est * math.nan), n, PAIRED_BOOTSTRAP)
    idx = np.random.default_rng(seed).integers(0, n, size=(n_boot, n))
    boot = np.asarray(stat(a[idx], b[idx]), dtype=np.float64)
    tail = 50.0 * (1.0 - confidence)
    lo, hi = np.percentile(boot, [tail, 100.0 - tail], axis=0)
    return Interval(scalar(est), scalar(lo), scalar(hi), n, PAIRED_BOOTSTRAP)
