"""Ellipsoidal gating and Gaussian log-likelihoods, batched over tracks (thesis §4.1).

Shapes: T tracks, M measurements, m measurement components.
    z_hat (T, m) predicted measurements, S (T, m, m) innovation covariances, Z (M, m) measurements,
    nu (T, M, m) innovations, d2 / log-likelihoods / gate flags (T, M).
"""

from __future__ import annotations

import numpy as np
from scipy.special import gammainc

from roadtrack.trackers.errors import FilterError

_LOG_2PI = float(np.log(2.0 * np.pi))


def innovations(z_hat: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """nu[t, j] = Z[j] - z_hat[t]: z_hat (T, m), Z (M, m) -> (T, M, m)."""
    return Z[None, :, :] - z_hat[:, None, :]  # §4.1 / (4.15) innovation z - H x_pred [R]


def _cholesky_batch(S: np.ndarray) -> np.ndarray:
    if not np.isfinite(S).all():
        bad = np.flatnonzero(~np.isfinite(S).reshape(len(S), -1).all(axis=1))
        raise FilterError(f"innovation covariance S of track index {int(bad[0])} is not finite")
    try:
        return np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        bad = [t for t in range(len(S)) if np.linalg.eigvalsh(S[t])[0] <= 0.0]
        raise FilterError(f"innovation covariance S of track index {bad[0] if bad else '?'} "
                          f"is not positive definite") from None


def mahalanobis2_and_log_gaussian(nu: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both d2 and log N(nu; 0, S) from one Cholesky factorisation: nu (T, M, m), S (T, m, m) per track or
    (T, M, m, m) per (track, measurement) pair (measurements with their own covariances) -> 2 x (T, M)."""
    T, M, m = nu.shape
    if S.shape == (T, M, m, m):
        return _pairs(nu, S)
    if S.shape != (T, m, m):
        raise ValueError(f"S must be ({T}, {m}, {m}) or ({T}, {M}, {m}, {m}) for nu {nu.shape}, got {S.shape}")
    L = _cholesky_batch(S)
    y = np.linalg.solve(L, np.swapaxes(nu, 1, 2))  # (T, m, M) whitened innovations L^-1 nu
    d2 = np.einsum("tim,tim->tm", y, y)  # (4.38) d2 = nu^T S^-1 nu (S^-1 for the printed S^T [R])
    log_det = 2.0 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
    log_n = -0.5 * d2 - 0.5 * (m * _LOG_2PI + log_det)[:, None]  # log N(nu; 0, S) of (4.10)
    return d2, log_n


def _pairs(nu: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`mahalanobis2_and_log_gaussian` with one S per pair, S (T, M, m, m): closed form for m = 2 (the 2x2
    inverse), else one Cholesky factor per pair."""
    T, M, m = nu.shape
    if m != 2:
        d2, log_n = mahalanobis2_and_log_gaussian(nu.reshape(T * M, 1, m), S.reshape(T * M, m, m))
        return d2.reshape(T, M), log_n.reshape(T, M)
    a, b, c = S[..., 0, 0], 0.5 * (S[..., 0, 1] + S[..., 1, 0]), S[..., 1, 1]
    det = a * c - b * b
    bad = ~(np.isfinite(det) & (a > 0.0) & (det > 0.0))
    if bad.any():
        t = int(np.argwhere(bad)[0][0])
        raise FilterError(f"innovation covariance S of track index {t} is not "
                          f"{'finite' if not np.isfinite(S[t]).all() else 'positive definite'}")
    x, y = nu[..., 0], nu[..., 1]
    d2 = (c * x * x - 2.0 * b * x * y + a * y * y) / det  # (4.38) d2 = nu^T S^-1 nu, 2x2 inverse
    return d2, -0.5 * d2 - 0.5 * (2.0 * _LOG_2PI + np.log(det))  # log N(nu; 0, S) of (4.10)


def mahalanobis2(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distances nu^T S^-1 nu: nu (T, M, m), S (T, m, m) -> (T, M)."""
    return mahalanobis2_and_log_gaussian(nu, S)[0]


def log_gaussian(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """log N(nu; 0, S): nu (T, M, m), S (T, m, m) -> (T, M)."""
    return mahalanobis2_and_log_gaussian(nu, S)[1]


def gate(d2: np.ndarray, alpha: float) -> np.ndarray:
    """Validation flags d2 <= alpha (T, M) bool."""
    return d2 <= alpha  # (4.38) validation gate


def gate_probability(alpha: float, m: int) -> float:
    """P_G = F_chi2_m(alpha), the probability that a target's measurement falls in the gate.

    gate_probability(16, 2) = 1 - exp(-8) = 0.99966."""
    return float(gammainc(0.5 * m, 0.5 * alpha))  # §4.1: P_G = chi-square CDF, regularised lower gamma
