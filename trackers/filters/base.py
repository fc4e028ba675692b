"""The filter contract and the PDA-form helpers every filter shares.

A filter is a frozen dataclass constructed from keyword parameters, with four stateless methods:

    predict(s, dt)                 -> FilterState         prior at the next scan
    predicted_measurement(s_pred)  -> (z_hat (m,), S (m, m))
    update(s_pred, nu, beta, beta0)-> FilterState         PDA-form update (thesis §4.2/§4.3)
    initiate(z, v_max)             -> FilterState         new track from one measurement (§7.2)
    initiate_two_point(z_prev, z, dt) -> FilterState      new track from two measurements (§7.2)

`update` takes the innovations nu (M, m) of the measurements a track may use, their association
weights beta (M,) and the miss weight beta0, with beta0 + sum(beta) = 1. Hard association (NN, GNN)
is beta = [1], beta0 = 0; PDA and JPDA pass soft weights. An SVSF-family filter implements the same
method: it sets e_{z,k|k-1} to the combined innovation (2.27), computes its own gain, combines the
covariance with `pda_covariance` (4.16)-(4.17) and stores e_{z,k|k} (3.65) in `FilterState.e_post`.
An IMM filter returns a `FilterState` subclass whose x, P are the combined output and whose extra
fields carry the mode-matched states; the tracker only reads x and P and passes states back.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from trackers.errors import FilterError
from trackers.state import FilterState


@runtime_checkable
class Filter(Protocol):
    def predict(self, s: FilterState, dt: float) -> FilterState: ...

    def predicted_measurement(self, s_pred: FilterState) -> tuple[np.ndarray, np.ndarray]: ...

    def update(self, s_pred: FilterState, nu: np.ndarray, beta: np.ndarray, beta0: float) -> FilterState: ...

    def initiate(self, z: np.ndarray, v_max: float) -> FilterState: ...

    def initiate_two_point(self, z_prev: np.ndarray, z: np.ndarray, dt: float) -> FilterState: ...


def symmetrise(P: np.ndarray) -> np.ndarray:
    """(P + P^T) / 2."""
    return 0.5 * (P + P.T)


def check_covariance(P: np.ndarray, what: str) -> np.ndarray:
    """Return P if finite, else raise FilterError naming `what`."""
    if not np.isfinite(P).all():
        raise FilterError(f"{what} is not finite")
    return P


def cholesky(S: np.ndarray, what: str) -> np.ndarray:
    """Lower Cholesky factor of S, or FilterError (one line) if S is non-finite or not positive definite."""
    check_covariance(S, what)
    try:
        return np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise FilterError(f"{what} is not positive definite (eigenvalues {np.linalg.eigvalsh(S)})") from None


def check_weights(nu: np.ndarray, beta: np.ndarray, beta0: float, m: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Validate PDA-form update inputs: nu (M, m), beta (M,) >= 0, beta0 in [0, 1], beta0 + sum(beta) = 1."""
    nu = np.asarray(nu, dtype=np.float64)
    beta = np.asarray(beta, dtype=np.float64)
    beta0 = float(beta0)
    if nu.size == 0:
        nu = nu.reshape(0, m)
    if nu.ndim != 2 or nu.shape[1] != m or beta.shape != (nu.shape[0],):
        raise ValueError(f"update needs nu (M, {m}) and beta (M,), got nu {nu.shape} and beta {beta.shape}")
    if not (np.isfinite(nu).all() and np.isfinite(beta).all() and np.isfinite(beta0)):
        raise ValueError("update got non-finite innovations or weights")
    if beta0 < 0.0 or beta0 > 1.0 or np.any(beta < 0.0) or abs(beta0 + beta.sum() - 1.0) > 1e-9:
        raise ValueError(f"update weights must be >= 0 and sum to 1: beta0={beta0}, sum(beta)={beta.sum()}")
    return nu, beta, beta0


def combined_innovation(nu: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Combined innovation sum_i beta_i nu_i (m,)."""
    return beta @ nu  # (4.15) combined innovation


def pda_covariance(P_pred: np.ndarray, P_star: np.ndarray, K: np.ndarray, nu: np.ndarray, beta: np.ndarray,
                   beta0: float) -> np.ndarray:
    """PDA posterior covariance beta0 P_pred + (1 - beta0) P* + K [sum beta_i nu_i nu_i^T - nu_c nu_c^T] K^T.

    P_pred, P_star (n, n); K (n, m) the filter's gain; nu (M, m); beta (M,). Returns a symmetric (n, n)."""
    nu_c = combined_innovation(nu, beta)
    spread = (nu.T * beta) @ nu - np.outer(nu_c, nu_c)
    P_tilde = K @ spread @ K.T  # (4.17) spread of innovations
    return symmetrise(beta0 * P_pred + (1.0 - beta0) * P_star + P_tilde)  # (4.16) PDA covariance
