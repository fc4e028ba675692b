"""Track initiation (thesis §7.2 [D]): a kinematic Gaussian [p; v] (2d,) from one or two measurements.

The filter lifts it into its own state with `filter.initial_state(x0, P0)` (e.g. a turn rate appended).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment


def single_point(z: np.ndarray, measurement, v_max: float, R: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Position from z, velocity 0: P0 = diag(R_p, v_max^2 / 3 I) (thesis §7.2 [D]); v_max [m/s]; R (d, d): the
    detection's own position covariance (a position measurement's), or None for the model's."""
    if not math.isfinite(v_max) or v_max <= 0:
        raise ValueError(f"initiation needs v_max > 0, got {v_max}")
    p, Rp = measurement.position_of(z)
    Rp = Rp if R is None else np.asarray(R, dtype=np.float64)
    d = len(p)
    P0 = np.zeros((2 * d, 2 * d))
    P0[:d, :d] = Rp  # §7.2: position variance R
    P0[d:, d:] = (v_max * v_max / 3.0) * np.eye(d)  # §7.2: velocity uniform on [-v_max, v_max]
    return np.concatenate([p, np.zeros(d)]), P0


def two_point(p_prev: np.ndarray, z: np.ndarray, dt: float, measurement, R: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """Two-point differencing (thesis §7.2 [D]) from the previous position p_prev (d,) and measurement z:
    x = [p; (p - p_prev) / dt], P0 = [[R, R/dt], [R/dt, 2R/dt^2]], R the position covariance of z (given: the
    detection's own, else the model's)."""
    if not math.isfinite(dt) or dt <= 0:
        raise ValueError(f"two-point initiation needs dt > 0, got {dt}")
    p0 = np.asarray(p_prev, dtype=np.float64)
    p, R_model = measurement.position_of(z)
    R = R_model if R is None else np.asarray(R, dtype=np.float64)
    P0 = np.block([[R, R / dt], [R / dt, 2.0 * R / dt ** 2]])  # §7.2 two-point differencing covariance
    return np.concatenate([p, (p - p0) / dt]), P0  # §7.2 x = [z_k; (z_k - z_{k-1}) / T_s]


def pair_candidates(C: np.ndarray, Zf: np.ndarray, reach: float) -> list[tuple[int, int]]:
    """One-to-one pairs (candidate row of C (K, d), row of Zf (F, d)) within `reach` [m], minimum total distance."""
    if len(C) == 0 or len(Zf) == 0:
        return []
    D = np.linalg.norm(C[:, None, :] - Zf[None, :, :], axis=-1)
    rows, cols = linear_sum_assignment(np.where(D <= reach, D, 1e12))
    return [(int(r), int(c)) for r, c in zip(rows, cols) if D[r, c] <= reach]
