"""Paper 000's windowed Kolmogorov-Smirnov integral test: flag measurements that do not come from the track.

The samples are non-negative scalars, here the Euclidean norms of the filter's innovations ||z_k - z_hat_k||
(paper 000 §IV: "the measurements referred to in the KS tests ... are actually the innovations"; §V: distances
are "radial" norms; reconstructed: the norm is taken in measurement space, integration starts at 0). A reference
sample known to be clean (paper 000 §V-C: 20,000 measurements from an earlier trip) gives F_0; each window of n
consecutive samples (window w covers samples w .. w+n-1, sliding by one) gives an empirical cdf S_n, and

    D_n = int_0^inf (F_0(x) - S_n(x)) dx                                   (paper 000 §III-D eq. (32))

is large when a window holds a sample far beyond the reference. For samples >= 0 it equals
mean(window) - mean(reference) exactly (int_0^inf (1 - F) dx = E[X]), so one wrong sample of size d raises D_n by
(d - mu_0) / n in each of the n windows that hold it: the paper's "hump", n windows wide.

    empirical_cdf(sample, x)                 -> (len(x),)     S_n(x) of eq. (31)
    ks_integral(window, reference)           -> float         D_n of eq. (32), integrated exactly
    ks_sup(window, reference)                -> float         the standard sup_x |S_n - F_0| of eq. (33)
    sliding_windows(x, n)                    -> (K-n+1, n)    windows of x sliding by one
    windowed(x, reference, n, metric)        -> (K-n+1,)      a metric over every window
    clean_threshold(reference, n, k_sigma)   -> float         mean + k_sigma std of D_n over clean windows [D]
    flag_samples(window_flags, n)            -> (K,) bool     samples every window of which is flagged [D]

Shapes: samples 1-D float64. The threshold rule and `flag_samples` are ours ([D]): the paper sets the threshold
"by inspection" and flags windows only.
"""

from __future__ import annotations

from typing import Callable

import numpy as np


def _samples(name: str, x, min_size: int = 1) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1 or a.size < min_size:
        raise ValueError(f"{name}: expected a 1-D sample of at least {min_size} values, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: contains NaN or inf")
    if (a < 0.0).any():
        raise ValueError(f"{name}: the integral test of paper 000 eq. (32) integrates from 0 and needs samples "
                         f">= 0 (e.g. innovation norms), got min {a.min()}")
    return a


def empirical_cdf(sample: np.ndarray, x: np.ndarray) -> np.ndarray:
    """S_n(x) = #{sample <= x} / n at the points x (any shape), right-continuous (paper 000 eq. (31))."""
    s = np.sort(np.asarray(sample, dtype=np.float64).ravel())
    return np.searchsorted(s, np.asarray(x, dtype=np.float64), side="right") / s.size  # paper 000 eq. (31)


def ks_integral(window: np.ndarray, reference: np.ndarray) -> float:
    """D_n = int_0^inf (F_0(x) - S_n(x)) dx with F_0, S_n the empirical cdfs of `reference` and `window`
    (paper 000 eq. (32)); signed, in the samples' unit. Integrated exactly: both cdfs are step functions, constant
    between the merged sample points, and equal to 1 beyond the largest."""
    w, ref = _samples("window", window), _samples("reference", reference)
    knots = np.unique(np.concatenate([[0.0], w, ref]))  # breakpoints of F_0 - S_n on [0, max]
    diff = empirical_cdf(ref, knots[:-1]) - empirical_cdf(w, knots[:-1])  # constant on [knot_i, knot_i+1)
    return float(np.sum(diff * np.diff(knots)))  # paper 000 eq. (32): area between the cdfs


def _sorted_reference(ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sorted reference, its distinct values u, F_0(u)): the reference cdf prepared once for many windows."""
    srt = np.sort(ref)
    u = np.unique(srt)
    return srt, u, np.searchsorted(srt, u, side="right") / srt.size


def _sup(window: np.ndarray, srt: np.ndarray, u: np.ndarray, F_u: np.ndarray) -> float:
    ws = np.sort(window)
    at_ref = np.abs(np.searchsorted(ws, u, side="right") / ws.size - F_u).max()
    at_win = np.abs(np.searchsorted(ws, ws, side="right") / ws.size - np.searchsorted(srt, ws, side="right") / srt.size)
    return float(max(at_ref, at_win.max()))  # paper 000 eq. (33) at every jump point of either cdf


def ks_sup(window: np.ndarray, reference: np.ndarray) -> float:
    """D_n = sup_x |S_n(x) - F_0(x)| (paper 000 eq. (33)), exact: the difference of two right-continuous step
    functions is constant between merged sample points, so its sup is attained at one of them."""
    w, ref = _samples("window", window), _samples("reference", reference)
    return _sup(w, *_sorted_reference(ref))


def sliding_windows(x: np.ndarray, n: int) -> np.ndarray:
    """(K - n + 1, n) read-only view: row w holds x[w : w + n] (paper 000 §V-C: window 1 = samples 1-10, ...)."""
    a = np.asarray(x, dtype=np.float64)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= a.size:
        raise ValueError(f"n: expected a window size in [1, {a.size}], got {n!r}")
    return np.lib.stride_tricks.sliding_window_view(a, int(n))


METRICS: dict[str, Callable[[np.ndarray, np.ndarray], float]] = {"integral": ks_integral, "sup": ks_sup}


def windowed(x: np.ndarray, reference: np.ndarray, n: int, metric: str = "integral") -> np.ndarray:
    """(K - n + 1,) the metric ('integral': eq. (32), 'sup': eq. (33)) of every window of n consecutive samples
    of x against the reference sample."""
    if metric not in METRICS:
        raise ValueError(f"metric: unknown {metric!r}; valid: {', '.join(METRICS)}")
    x, ref = _samples("x", x, n), _samples("reference", reference)
    if metric == "integral":
        return sliding_windows(x, n).mean(axis=1) - ref.mean()  # == eq. (32) for samples >= 0 (tested)
    prepared = _sorted_reference(ref)
    return np.array([_sup(w, *prepared) for w in sliding_windows(x, n)])


def clean_threshold(reference: np.ndarray, n: int, k_sigma: float = 3.0) -> float:
    """D_thr = mean + k_sigma std of D_n over the sliding windows of the clean reference stream itself [D]
    (the paper sets it "by inspection of D_n values in areas where there are known to be only true
    measurements", paper 000 §IV). The reference must be in time order (its windows are consecutive samples)."""
    ref = _samples("reference", reference, n + 1)
    d = windowed(ref, ref, n)
    return float(d.mean() + k_sigma * d.std())


def flag_samples(window_flags: np.ndarray, n: int) -> np.ndarray:
    """(K,) bool: sample k is flagged when every window holding it (windows max(0, k-n+1) .. min(k, W-1) of the
    W = K - n + 1) is flagged [D]. One wrong sample among clean ones raises exactly its own n windows, so this
    isolates it; two wrong samples closer than n also flag the clean samples between them."""
    f = np.asarray(window_flags)
    if f.dtype != np.bool_ or f.ndim != 1:
        raise ValueError(f"window_flags: expected a 1-D bool array, got {f.dtype} {f.shape}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n: expected an int >= 1, got {n!r}")
    W = f.size
    K = W + int(n) - 1
    clean_before = np.concatenate([[0], np.cumsum(~f)])  # number of unflagged windows before index i
    k = np.arange(K)
    lo, hi = np.maximum(0, k - n + 1), np.minimum(k, W - 1)
    return (clean_before[hi + 1] - clean_before[lo]) == 0
