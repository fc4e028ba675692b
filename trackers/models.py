"""Motion and measurement models (thesis §1.1-1.2).

State `[px, py, vx, vy]` in m and m/s (positions first); measurement `[px, py]` in m.
"""

from __future__ import annotations

import numpy as np

STATE_DIM = 4
MEASUREMENT_DIM = 2


def cv_transition(dt: float) -> np.ndarray:
    """NCV transition matrix A (4, 4) for a step of `dt` seconds."""
    A = np.eye(STATE_DIM)  # (1.36)-(1.38) NCV: A = [[I, dt I], [0, I]]
    A[0, 2] = A[1, 3] = dt
    return A


def cv_noise_gain(dt: float) -> np.ndarray:
    """NCV process-noise gain G (4, 2): white acceleration enters as [dt^2/2 I; dt I]."""
    G = np.zeros((STATE_DIM, 2))  # (1.36)-(1.38) NCV gain G
    G[0, 0] = G[1, 1] = 0.5 * dt * dt
    G[2, 0] = G[3, 1] = dt
    return G


def cv_process_noise(dt: float, sigma_v: float) -> np.ndarray:
    """NCV process noise Q = G Qv G^T (4, 4), Qv = sigma_v^2 I2; sigma_v in m/s^2."""
    G = cv_noise_gain(dt)
    return (sigma_v * sigma_v) * (G @ G.T)  # thesis §1.1 [R]: Q = G Qv G^T (dimensionally consistent form of (1.38))


def position_measurement_matrix() -> np.ndarray:
    """H = [I2 0] (2, 4): positions are measured."""
    return np.eye(MEASUREMENT_DIM, STATE_DIM)  # (4.77)-(4.79) H = [I 0], positions-first ordering (§1.2 [R])


def measurement_noise(sigma_w: float) -> np.ndarray:
    """R = sigma_w^2 I2 (2, 2); sigma_w in m."""
    return (sigma_w * sigma_w) * np.eye(MEASUREMENT_DIM)  # (4.77)-(4.79) R = sigma_w^2 I
