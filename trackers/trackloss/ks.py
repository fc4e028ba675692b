"""Two-sided Kolmogorov-Smirnov critical values and the KS distance of integer samples (paper 002 §IV).

    critical_value(n, alpha)              exact d_n(alpha): P{D_n >= d_n} = alpha for a continuous F (5)
    asymptotic_critical_value(n, alpha)   d(alpha) / sqrt(n), Kolmogorov's limit (6)-(7)
    kolmogorov_tail(d)                    alpha = P{sqrt(n) D_n >= d} as n -> inf, the series of (6)
    ks_distance_counts(counts, cdf)       D = max_m |S_n(m) - F(m)| for integer samples (4)

The exact values are scipy's `kstwo` quantiles (Marsaglia-Tsang-Wang / Durbin), which are the paper's
"continuous recursion" values: d_500(0.05) = 0.06039 (paper 0.0604), d_200 = 0.0952, d_50 = 0.1884. Both
kinds are conservative when F is discrete (paper 002 §IV-D, Conover 1972): P{D_n >= d_n} <= alpha.
Values are cached per (n, alpha); every function accepts arrays of n.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.special import kolmogi


@functools.lru_cache(maxsize=4096)
def _exact(n: int, alpha: float) -> float:
    from scipy.stats import kstwo  # here, not at the top: scipy.stats takes longer to import than the rest of a
    # `testbed check` (it is needed only once a track-loss test asks for a critical value; cached per (n, alpha))

    return float(kstwo.isf(alpha, n))  # paper 002 §IV-C (5): P{D_n >= d_n(alpha)} = alpha, exact


def _check(n, alpha: float) -> np.ndarray:
    n = np.asarray(n)
    if not np.issubdtype(n.dtype, np.integer) or np.any(n < 1):
        raise ValueError(f"n must be integers >= 1, got {n!r}")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha!r}")
    return n


def critical_value(n, alpha: float = 0.05):
    """Exact two-sided critical value d_n(alpha) (float for an int n, (k,) array for (k,) ints)."""
    if type(n) is int and n >= 1 and 0.0 < alpha < 1.0:
        return _exact(n, float(alpha))  # the per-scan fast path
    n = _check(n, alpha)
    out = np.array([_exact(int(k), float(alpha)) for k in n.ravel()]).reshape(n.shape)
    return float(out) if out.ndim == 0 else out


def asymptotic_critical_value(n, alpha: float = 0.05):
    """d_{n, n->inf}(alpha) = d(alpha) / sqrt(n) (paper 002 (7): 1.3581 / sqrt(n) at alpha = 0.05)."""
    n = _check(n, alpha)
    out = float(kolmogi(alpha)) / np.sqrt(n)  # paper 002 (6)-(7): d(alpha) from alpha = P{sqrt(n) D_n >= d}
    return float(out) if np.ndim(out) == 0 else out


def kolmogorov_tail(d, terms: int = 100):
    """alpha(d) = 2 sum_{j>=1} (-1)^(j-1) exp(-2 j^2 d^2), the limit of P{sqrt(n) D_n >= d} (paper 002 (6),
    printed as 1 - 2 sum ..., the cdf [R]). Summed directly; equals scipy.special.kolmogorov(d)."""
    d = np.asarray(d, dtype=np.float64)
    j = np.arange(1, terms + 1).reshape((-1,) + (1,) * d.ndim)
    out = 2.0 * np.sum((-1.0) ** (j - 1) * np.exp(-2.0 * j * j * d * d), axis=0)  # paper 002 (6) [R]
    return float(out) if out.ndim == 0 else out


def ks_distance_counts(counts: np.ndarray, cdf: np.ndarray) -> float:
    """Two-sided KS distance D = sup_x |S_n(x) - F(x)| (paper 002 (4)) of integer samples `counts` (n,) >= 0
    against a cdf given at m = 0, 1, ..., len(cdf) - 1 (needs len(cdf) > max(counts)). Both are right-continuous
    steps with jumps at integers, so the sup is the max over m = 0..max(counts) [R]."""
    counts = np.asarray(counts)
    if counts.size == 0:
        raise ValueError("no samples")
    sample = np.cumsum(np.bincount(counts)) / counts.size  # S_n(m), m = 0..max(counts)
    if len(cdf) < sample.size:
        raise ValueError(f"cdf has {len(cdf)} values; need m = 0..{sample.size - 1}")
    return float(np.max(np.abs(sample - cdf[: sample.size])))  # paper 002 (4) at m = 0..max(counts) [R]


def ks_distances_counts(counts: np.ndarray, cdf: np.ndarray) -> np.ndarray:
    """ks_distance_counts of T samples at once: counts (T, n) integers >= 0 against cdfs (T, M) given at
    m = 0..M-1 (M > counts.max()); (T,) distances, each the max over m = 0..max(counts[t]) (paper 002 (4)) [R]."""
    counts, cdf = np.asarray(counts), np.asarray(cdf, dtype=np.float64)
    T, n = counts.shape
    M = cdf.shape[1]
    hist = np.bincount((np.arange(T)[:, None] * M + counts).ravel(), minlength=T * M).reshape(T, M)
    seen = np.arange(M)[None, :] <= counts.max(axis=1)[:, None]
    return np.max(np.where(seen, np.abs(np.cumsum(hist, axis=1) / n - cdf), -np.inf), axis=1)  # paper 002 (4)
