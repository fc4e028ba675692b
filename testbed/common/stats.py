"""Confidence intervals the reports share: Wilson intervals for proportions (P_D per bin, lost-track rates)
and Student-t intervals for means over runs or seeds.

    wilson(k, n, confidence=0.95) -> (lo, hi)        arrays of k successes in n trials (NaN where n == 0)
    mean_ci(values, confidence=0.95) -> (n, mean, sd, lo, hi)
"""
from __future__ import annotations

import math

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
    return np.clip(lo, 0.0, 1.0), np.clip(hi, 0.0, 1.0)


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
