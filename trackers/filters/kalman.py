"""Kalman filter and extended Kalman filter in PDA form (thesis §1.1-1.2, §4.2; EKF (1.11); seed 000 §3
for the second-order measurement terms).

Both are generic over the motion and measurement models. The KF requires linear models; the EKF
linearises f and h at the current estimate (first order) and optionally adds the second-order terms
of h to the innovation covariance and the predicted measurement.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from roadtrack.trackers.errors import FilterError
from roadtrack.trackers.filters.base import (ModelFilter, batch_weights, check_covariance, check_weights, cholesky,
                                   combined_innovation, identity, pda_covariance, symmetrise, weighted_outer)
from roadtrack.trackers.state import (FilterState, StateRows, derive_frozen, freeze, frozen_state, rows_of,
                                     updated_rows)


def gain_update(s_pred: FilterState, H: np.ndarray, R: np.ndarray, S: np.ndarray, K: np.ndarray,
                nu: np.ndarray, beta: np.ndarray, beta0: float) -> FilterState:
    """PDA-form update with gain K (n, m): x = x_pred + K nu_c; P = beta0 P_pred + (1 - beta0) P* + P~
    with the Joseph-form P* = (I - K H) P (I - K H)^T + K R K^T; e_post = (I - H K) nu_c (3.65)."""
    P = s_pred.P
    nu_c = combined_innovation(nu, beta)  # (4.15) combined innovation
    x = s_pred.x + K @ nu_c  # §4.2 PDA state update x = x_pred + K nu_c, (4.10)-(4.17)
    I_KH = np.eye(len(x)) - K @ H
    P_star = I_KH @ P @ I_KH.T + K @ R @ K.T  # (4.8), (2.12), (4.37): single-measurement posterior, Joseph form
    P_post = pda_covariance(P, P_star, K, nu, beta, beta0)  # (4.16)-(4.17)
    if not np.isfinite(x).all():
        raise FilterError("updated state x is not finite")
    check_covariance(P_post, "updated covariance P")
    e_post = nu_c - H @ (K @ nu_c)  # (3.65) e_{z,k|k} = (I - H K) e_{z,k|k-1}
    return replace(s_pred, x=x, P=P_post, e_post=e_post, F=None)


def one_detection_update(s_pred: FilterState, H: np.ndarray, R: np.ndarray, nu: np.ndarray, beta: np.ndarray,
                         beta0: float) -> FilterState:
    """`detection_update` of one track: H (m, n) its (Jacobian) measurement matrix, R (M, m, m) the covariances of
    the detections of nu (M, m) (an EKF adds its second-order terms to each), beta (M,), beta0."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape != nu.shape + nu.shape[-1:]:
        raise ValueError(f"update needs R (M, m, m) for nu {nu.shape}, got R {R.shape}")
    x, P, e = detection_update(s_pred.x[None], s_pred.P[None], H, R, nu[None], np.asarray(beta)[None],
                               np.array([beta0]))
    check_covariance(P[0], "updated covariance P")
    return replace(s_pred, x=x[0], P=P[0], e_post=e[0], F=None)


@dataclass(frozen=True)
class KalmanFilter(ModelFilter):
    """Linear KF. motion: a linear motion model (e.g. ConstantVelocity); measurement: a linear one."""

    motion: object
    measurement: object

    def __post_init__(self) -> None:
        if not (self.motion.linear and self.measurement.linear):
            raise ValueError(f"KalmanFilter needs linear models, got {type(self.motion).__name__} and "
                             f"{type(self.measurement).__name__}; use the EKF")

    def update(self, s_pred: FilterState, nu: np.ndarray, beta: np.ndarray, beta0: float,
               R: np.ndarray | None = None) -> FilterState:
        """PDA-form update. nu (M, m) innovations z_i - z_hat; beta (M,) weights; beta0 miss weight; R (M, m, m)
        the detections' own covariances (`detection_update`) or None (the measurement model's R).

        M = 0 or beta0 = 1 returns `s_pred` itself. beta = [1], beta0 = 0 is the standard KF update with
        the Joseph-form covariance."""
        nu, beta, beta0 = check_weights(nu, beta, beta0, self.measurement.ndim)
        if nu.shape[0] == 0 or beta0 == 1.0:
            return s_pred  # (4.16) with beta0 = 1: no update
        if R is not None:
            return one_detection_update(s_pred, self.measurement_jacobian(s_pred), R, nu, beta, beta0)
        H, R = self.measurement_jacobian(s_pred), self.measurement.R
        S = symmetrise(H @ s_pred.P @ H.T + R)
        cholesky(S, "innovation covariance S")
        K = np.linalg.solve(S, H @ s_pred.P).T  # (4.3)-(4.8) KF gain K = P H^T S^-1
        return gain_update(s_pred, H, R, S, K, nu, beta, beta0)

    # ---- batched forms (same equations over T tracks at once; used by the tracker; predict: ModelFilter's
    # predict_arrays, (4.3)-(4.8) x = A x, P = A P A^T + G Qv G^T (§1.1 [R]))
    def predicted_measurements(self, preds: list[FilterState]) -> tuple[np.ndarray, np.ndarray]:
        m = self.measurement.ndim
        if not preds:
            return np.zeros((0, m)), np.zeros((0, m, m))
        H = self.measurement.matrix(self.motion)
        P = rows_of(preds, "P")
        S = H @ P @ H.T + self.measurement.R  # (4.3)-(4.8) innovation covariance S
        return rows_of(preds, "x") @ H.T, 0.5 * (S + np.swapaxes(S, 1, 2))

    def update_many(self, preds: list[FilterState], nu: np.ndarray, W: np.ndarray,
                    w0: np.ndarray, R: np.ndarray | None = None) -> list[FilterState]:
        """`update` of T tracks at once: nu (T, M, m), W (T, M), w0 (T,), R (M, m, m) or None. A track with w0 = 1
        keeps its prediction."""
        return gain_update_many(preds, nu, W, w0, self.measurement.matrix(self.motion), self.measurement.R, R_det=R)


def gain_update_many(preds: list[FilterState], nu: np.ndarray, W: np.ndarray, w0: np.ndarray, H: np.ndarray,
                     R: np.ndarray, effective_R: bool = False, R_det: np.ndarray | None = None) -> list[FilterState]:
    """KF-gain PDA updates of T tracks (`gain_update` with K = P H^T S^-1): nu (T, M, m), W (T, M), w0 (T,), the
    linear measurement's H (m, n) and R (m, m). effective_R: the Joseph form with R_eff = S - H P H^T, as the
    per-track EKF update computes it. R_det (M, m, m): the detections' own covariances (`detection_update`) instead
    of R. A track with w0 = 1 or no weight keeps its prediction; ValueError as the per-track check
    (`batch_weights`)."""
    T = len(preds)
    active = np.flatnonzero((w0 < 1.0) & (W > 0.0).any(axis=1)) if T else np.zeros(0, dtype=np.int64)
    out = list(preds)
    if active.size == 0:
        return StateRows(out, preds.x, preds.P, preds.e_post) if type(preds) is StateRows else out
    nua, Wa, b0 = batch_weights(nu, W, w0, active)  # (A, M, m), (A, M), (A,)
    X = rows_of(preds, "x", active)
    P = rows_of(preds, "P", active)
    if R_det is not None:
        Xn, Pn, e_post = detection_update(X, P, H, np.asarray(R_det, dtype=np.float64), nua, Wa, b0)
        return _updated(preds, out, active, Xn, Pn, e_post)
    HPH = H @ P @ H.T
    S = HPH + R
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    try:
        np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise FilterError("innovation covariance S is not positive definite") from None
    R_j = S - HPH if effective_R else R  # (1.11): R plus the EKF's second-order terms (here none)
    K = np.swapaxes(np.linalg.solve(S, H @ P), 1, 2)  # (4.3)-(4.8) KF gain K = P H^T S^-1, (a, n, m)
    nu_c = np.einsum("aj,ajm->am", Wa, nua)  # (4.15) combined innovation
    Xn = X + np.einsum("anm,am->an", K, nu_c)  # §4.2 PDA state update
    I_KH = identity(X.shape[1]) - K @ H
    P_star = I_KH @ P @ np.swapaxes(I_KH, 1, 2) + K @ R_j @ np.swapaxes(K, 1, 2)  # (4.8) Joseph form
    spread = weighted_outer(Wa, nua) - np.einsum("ai,ak->aik", nu_c, nu_c)
    Pn = b0[:, None, None] * P + (1.0 - b0)[:, None, None] * P_star + K @ spread @ np.swapaxes(K, 1, 2)  # (4.16)-(4.17)
    Pn = 0.5 * (Pn + np.swapaxes(Pn, 1, 2))
    if not (np.isfinite(Xn).all() and np.isfinite(Pn).all()):
        raise FilterError("updated state is not finite")
    e_post = nu_c - np.einsum("im,am->ai", H, np.einsum("anm,am->an", K, nu_c))  # (3.65)
    return _updated(preds, out, active, Xn, Pn, e_post)


def _updated(preds: list, out: list, active: np.ndarray, Xn: np.ndarray, Pn: np.ndarray, e_post: np.ndarray) -> list:
    """`out` (the predictions) with the active tracks' updated states x, P, e_post (A rows each, made read-only here);
    a StateRows carrying every row when `preds` carries x, P and e_post."""
    freeze(Xn, Pn, e_post)
    for t, x, P, e in zip(active.tolist(), Xn, Pn, e_post):
        s = preds[t]
        out[t] = (frozen_state(x, P, e, None, s.info) if type(s) is FilterState
                  else derive_frozen(s, x=x, P=P, e_post=e, F=None))
    return updated_rows(preds, out, active, Xn, Pn, e_post)


def detection_update(X: np.ndarray, P: np.ndarray, H: np.ndarray, R: np.ndarray, nu: np.ndarray, W: np.ndarray,
                     w0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PDA update of A tracks whose detections carry their own covariances R (M, m, m): X (A, n), P (A, n, n),
    H (m, n), innovations nu (A, M, m), weights W (A, M) (0: not used), miss weights w0 (A,). Returns x (A, n),
    P (A, n, n) and e_post (A, m).

    Each detection j has its own gain K_j = P H^T S_j^-1, S_j = H P H^T + R_j, and the posterior is the moment-
    matched mixture of the hypotheses (thesis §4.2, (4.10)-(4.17), with a gain per hypothesis [D]):
    dx = sum_j beta_j K_j nu_j, x = x_pred + dx,
    P = beta0 P_pred + sum_j beta_j [P*_j + (K_j nu_j)(K_j nu_j)^T] - dx dx^T, P*_j the Joseph form with R_j.
    With every R_j equal it is (4.16)-(4.17) exactly."""
    A, n = X.shape
    a, j = np.nonzero(W > 0.0)  # the (track, detection) pairs that carry weight
    w = W[a, j]
    Pp = P[a]
    S = H @ Pp @ H.T + R[j]  # (4.3)-(4.8) S_j = H P H^T + R_j
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    try:
        np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise FilterError("innovation covariance S is not positive definite") from None
    K = np.swapaxes(np.linalg.solve(S, H @ Pp), 1, 2)  # (4.3)-(4.8) K_j = P H^T S_j^-1, (p, n, m)
    d = np.einsum("pnm,pm->pn", K, nu[a, j])  # K_j nu_j
    I_KH = identity(n) - K @ H
    P_star = I_KH @ Pp @ np.swapaxes(I_KH, 1, 2) + K @ R[j] @ np.swapaxes(K, 1, 2)  # (4.8) Joseph form, R_j
    dx = np.zeros((A, n))
    np.add.at(dx, a, w[:, None] * d)  # (4.15) combined correction sum_j beta_j K_j nu_j
    mix = np.zeros((A, n, n))
    np.add.at(mix, a, w[:, None, None] * (P_star + np.einsum("pi,pk->pik", d, d)))
    Pn = w0[:, None, None] * P + mix - np.einsum("ai,ak->aik", dx, dx)  # (4.16)-(4.17) mixture moments
    Pn = 0.5 * (Pn + np.swapaxes(Pn, 1, 2))
    Xn = X + dx
    if not (np.isfinite(Xn).all() and np.isfinite(Pn).all()):
        raise FilterError("updated state is not finite")
    e_post = np.einsum("aj,ajm->am", W, nu) - dx @ H.T  # (3.65) e_{z,k|k} = nu_c - H dx
    return Xn, Pn, e_post


@dataclass(frozen=True)
class ExtendedKalmanFilter(ModelFilter):
    """EKF (thesis (1.11)): f, h linearised at the estimate. second_order: add the second-order terms of
    h (seed 000 §3: z_hat += 1/2 sum_i e_i tr(Hxx_i P), S_ij += 1/2 tr(Hxx_i P Hxx_j P)); needs a
    measurement model with `hessians`."""

    motion: object
    measurement: object
    second_order: bool = False

    def __post_init__(self) -> None:
        if self.second_order and not hasattr(self.measurement, "hessians"):
            raise ValueError(f"second_order EKF needs a measurement model with hessians; "
                             f"{type(self.measurement).__name__} has none")

    def _second_order_terms(self, s: FilterState) -> tuple[np.ndarray, np.ndarray]:
        m = self.measurement.ndim
        if not self.second_order:
            return np.zeros(m), np.zeros((m, m))
        Hs = self.measurement.hessians(s.x, self.motion)  # (m, n, n)
        HP = Hs @ s.P  # (m, n, n)
        dz = 0.5 * np.trace(HP, axis1=1, axis2=2)  # seed 000 §3: second-order bias of h
        dS = 0.5 * np.einsum("iab,jba->ij", HP, HP)  # seed 000 §3: 1/2 tr(Hxx_i P Hxx_j P)
        return dz, dS

    def predicted_measurement(self, s_pred: FilterState) -> tuple[np.ndarray, np.ndarray]:
        z_hat, S = super().predicted_measurement(s_pred)
        dz, dS = self._second_order_terms(s_pred)
        return z_hat + dz, symmetrise(S + dS)

    def update(self, s_pred: FilterState, nu: np.ndarray, beta: np.ndarray, beta0: float,
               R: np.ndarray | None = None) -> FilterState:
        """PDA-form EKF update with K = P H^T S^-1, H the Jacobian of h at the prediction; R (M, m, m): the
        detections' own covariances (each plus the second-order terms) or None."""
        nu, beta, beta0 = check_weights(nu, beta, beta0, self.measurement.ndim)
        if nu.shape[0] == 0 or beta0 == 1.0:
            return s_pred
        H = self.measurement_jacobian(s_pred)
        if R is not None:
            return one_detection_update(s_pred, H, np.asarray(R, dtype=np.float64)
                                        + self._second_order_terms(s_pred)[1], nu, beta, beta0)
        _, S = self.predicted_measurement(s_pred)
        cholesky(S, "innovation covariance S")
        K = np.linalg.solve(S, H @ s_pred.P).T  # (1.11) EKF gain with the Jacobian H
        R_eff = S - H @ s_pred.P @ H.T  # R plus the second-order terms: keeps the Joseph form consistent
        return gain_update(s_pred, H, R_eff, S, K, nu, beta, beta0)

    # ---- batched forms (the per-track ones above are their reference, tests/test_trackers_svsf.py)
    def predicted_measurements(self, preds: list[FilterState]) -> tuple[np.ndarray, np.ndarray]:
        """z_hat (T, m), S (T, m, m): vectorised for the first-order EKF of a linear measurement (H x, H P H^T + R)."""
        if self.second_order or not self.measurement.linear or not preds:
            return super().predicted_measurements(preds)
        return self.linear_predicted_measurements(preds)

    def update_many(self, preds: list[FilterState], nu: np.ndarray, W: np.ndarray,
                    w0: np.ndarray, R: np.ndarray | None = None) -> list[FilterState]:
        """`update` of T tracks at once for the first-order EKF of a linear measurement (the KF gain update with
        R_eff = S - H P H^T), else the per-track loop: nu (T, M, m), W (T, M), w0 (T,), R (M, m, m) or None."""
        if self.second_order or not self.measurement.linear:
            return super().update_many(preds, nu, W, w0, R)
        return gain_update_many(preds, nu, W, w0, self.measurement.matrix(self.motion), self.measurement.R,
                                effective_R=True, R_det=R)
