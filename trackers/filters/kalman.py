"""Linear Kalman filter, NCV motion with position measurements, in PDA form (thesis §1.1-1.2, §4.2)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from trackers.errors import FilterError
from trackers.filters.base import (check_covariance, check_weights, cholesky, combined_innovation, pda_covariance,
                                   symmetrise)
from trackers.models import (MEASUREMENT_DIM, STATE_DIM, cv_process_noise, cv_transition, measurement_noise,
                             position_measurement_matrix)
from trackers.state import FilterState


@dataclass(frozen=True)
class KalmanFilter:
    """KF for state [px, py, vx, vy]. sigma_v: white-acceleration std [m/s^2]; sigma_w: position noise std [m]."""

    sigma_v: float
    sigma_w: float
    _H: np.ndarray = field(init=False, repr=False, compare=False)
    _R: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("sigma_v", "sigma_w"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"KalmanFilter.{name} must be a finite number, got {v!r}")
        if self.sigma_v < 0 or self.sigma_w <= 0:
            raise ValueError(f"KalmanFilter needs sigma_v >= 0 and sigma_w > 0, got {self.sigma_v}, {self.sigma_w}")
        object.__setattr__(self, "_H", position_measurement_matrix())
        object.__setattr__(self, "_R", measurement_noise(self.sigma_w))

    def predict(self, s: FilterState, dt: float) -> FilterState:
        """Prior after `dt` seconds (dt >= 0)."""
        dt = float(dt)
        if not np.isfinite(dt) or dt < 0:
            raise ValueError(f"predict needs a finite dt >= 0, got {dt}")
        A = cv_transition(dt)
        x = A @ s.x  # (4.3)-(4.8) KF predict: x = A x
        P = symmetrise(A @ s.P @ A.T + cv_process_noise(dt, self.sigma_v))  # P = A P A^T + G Qv G^T (§1.1 [R])
        check_covariance(P, "predicted covariance P")
        return replace(s, x=x, P=P)

    def predicted_measurement(self, s_pred: FilterState) -> tuple[np.ndarray, np.ndarray]:
        """z_hat = H x (m,), S = H P H^T + R (m, m)."""
        H = self._H
        S = symmetrise(H @ s_pred.P @ H.T + self._R)  # (4.3)-(4.8) innovation covariance S
        return H @ s_pred.x, S

    def update(self, s_pred: FilterState, nu: np.ndarray, beta: np.ndarray, beta0: float) -> FilterState:
        """PDA-form update. nu (M, m) innovations z_i - z_hat; beta (M,) weights; beta0 miss weight.

        M = 0 or beta0 = 1 returns `s_pred` itself. beta = [1], beta0 = 0 is the standard KF update with
        the Joseph-form covariance. e_post is set to the a-posteriori error (I - H K) nu_c (3.65)."""
        nu, beta, beta0 = check_weights(nu, beta, beta0, MEASUREMENT_DIM)
        if nu.shape[0] == 0 or beta0 == 1.0:
            return s_pred  # (4.16) with beta0 = 1: no update
        H, R, P = self._H, self._R, s_pred.P
        S = symmetrise(H @ P @ H.T + R)
        cholesky(S, "innovation covariance S")
        K = np.linalg.solve(S, H @ P).T  # (4.3)-(4.8) KF gain K = P H^T S^-1
        nu_c = combined_innovation(nu, beta)  # (4.15) combined innovation
        x = s_pred.x + K @ nu_c  # §4.2 PDA state update x = x_pred + K nu_c, (4.10)-(4.17)
        I_KH = np.eye(STATE_DIM) - K @ H
        P_star = I_KH @ P @ I_KH.T + K @ R @ K.T  # (4.8) single-measurement posterior, Joseph form
        P_post = pda_covariance(P, P_star, K, nu, beta, beta0)  # (4.16)-(4.17)
        if not np.isfinite(x).all():
            raise FilterError("updated state x is not finite")
        check_covariance(P_post, "updated covariance P")
        e_post = nu_c - H @ (K @ nu_c)  # (3.65) e_{z,k|k} = (I - H K) e_{z,k|k-1}
        return replace(s_pred, x=x, P=P_post, e_post=e_post)

    def initiate(self, z: np.ndarray, v_max: float) -> FilterState:
        """New track at position z (2,) with zero velocity, P0 = diag(R, v_max^2/3 I) (thesis §7.2 [D])."""
        z = np.asarray(z, dtype=np.float64)
        if z.shape != (MEASUREMENT_DIM,) or not np.isfinite(z).all():
            raise ValueError(f"initiate needs a finite z of shape ({MEASUREMENT_DIM},), got {z!r}")
        if not np.isfinite(v_max) or v_max <= 0:
            raise ValueError(f"initiate needs v_max > 0, got {v_max}")
        P0 = np.zeros((STATE_DIM, STATE_DIM))
        P0[:2, :2] = self._R  # §7.2: position variance R
        P0[2:, 2:] = (v_max * v_max / 3.0) * np.eye(2)  # §7.2: velocity uniform on [-v_max, v_max]
        return FilterState(x=np.concatenate([z, np.zeros(2)]), P=P0, e_post=np.zeros(MEASUREMENT_DIM))

    def initiate_two_point(self, z_prev: np.ndarray, z: np.ndarray, dt: float) -> FilterState:
        """New track from two measurements dt apart (thesis §7.2 [D], two-point differencing):
        x = [z; (z - z_prev)/dt], P0 = [[R, R/dt], [R/dt, 2R/dt^2]]."""
        z_prev, z = np.asarray(z_prev, dtype=np.float64), np.asarray(z, dtype=np.float64)
        if z.shape != (MEASUREMENT_DIM,) or z_prev.shape != (MEASUREMENT_DIM,) or not (
                np.isfinite(z).all() and np.isfinite(z_prev).all()):
            raise ValueError(f"initiate_two_point needs finite z, z_prev of shape ({MEASUREMENT_DIM},)")
        if not np.isfinite(dt) or dt <= 0:
            raise ValueError(f"initiate_two_point needs dt > 0, got {dt}")
        R = self._R
        P0 = np.block([[R, R / dt], [R / dt, 2.0 * R / dt**2]])  # §7.2 two-point differencing covariance
        x = np.concatenate([z, (z - z_prev) / dt])  # §7.2 x = [z_k; (z_k - z_{k-1}) / T_s]
        return FilterState(x=x, P=P0, e_post=np.zeros(MEASUREMENT_DIM))
