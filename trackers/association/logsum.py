"""log sum exp for the associators: scipy.special.logsumexp's algorithm for real arrays, step for step in NumPy.

scipy's function (1.15+) separates the largest term for precision, log(sum exp a) = a_max + log(m) + log1p(s / m)
with m the number of maxima and s the sum of the other terms' exp(a - a_max), and falls back to log(sum exp a)
where that is not finite; it also spends about 0.2 ms per call on array-API dispatch, which the associators paid
two to four times per scan. `logsumexp` here runs the same NumPy operations in the same order, so its results are
scipy's bit for bit (tests/test_logsum.py compares them on random arrays with ties, infinities and NaNs).
"""

from __future__ import annotations

import numpy as np


def logsumexp(a, axis: int | None = None, keepdims: bool = False):
    """log(sum(exp(a), axis)) of a real array (float64; axis None: every axis), as scipy.special.logsumexp(a, axis,
    keepdims=keepdims): an array, or a float64 scalar for a full reduction."""
    a = np.atleast_1d(np.asarray(a, dtype=np.float64))
    axes = tuple(range(a.ndim)) if axis is None else axis
    if a.size == 0:
        shape = np.asarray(a.shape)
        shape[axes] = 1
        out = np.full(tuple(shape), -np.inf)
    else:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            out_inf = np.log(np.sum(np.exp(a), axis=axes, keepdims=True))  # the direct sum, for infinite results
            a_max = np.max(a, axis=axes, keepdims=True)
            top = a == a_max
            rest = a.copy()
            rest[top] = -np.inf  # the maxima are separated out of the main sum
            m = np.sum(top.astype(np.float64), axis=axes, keepdims=True, dtype=np.float64)
            s = np.sum(np.exp(rest - a_max), axis=axes, keepdims=True, dtype=np.float64)
            s = np.where(s == 0, s, s / m)  # s >= 0 (or NaN) and m >= 0: scipy's sign fix-ups for negative sums
            out = np.log1p(s) + np.log(m) + a_max  # (complex input or weights b) change nothing here
        out = np.where(np.isfinite(out), out, out_inf)
    out = out if keepdims else np.squeeze(out, axis=axes)
    return out[()] if out.ndim == 0 else out
