"""A track's bird's-eye-view box: heading, length and width estimated beside its kinematic state (box tracking).

Each track carries b = [heading psi (rad), length l (m), width w (m)] with independent variances (3,), filtered by a
scalar Kalman filter per component with the fitted box of each associated detection as the measurement [D] (the
decoupled box state of AB3DMOT-style 3-D MOT, Weng et al. 2020, without its joint 10-D state: the kinematic filter
is any of ours, the box rides beside it):

  predict   var += q^2 dt                            random walk, q = (q_heading, q_extent, q_extent) per sqrt(s)
  innovate  nu_j = y_j - b, the heading part wrapped to (-pi/2, pi/2]: a fitted box's heading is known modulo
            pi (a rectangle turned by pi is the same rectangle; AB3DMOT's orientation correction)
  update    PDA form with the association weights of the kinematic update, per component (thesis §4.2
            (4.15)-(4.17) for a scalar state measured directly, H = 1):
            nu_c = sum_j beta_j nu_j, K = var / (var + r), b += K nu_c,
            var = beta0 var + (1 - beta0) (1 - K) var + K^2 (sum_j beta_j nu_j^2 - nu_c^2)

A new track starts from its first detection's box with variances r. Units: rad, m, s. Arrays: b (T, 3), var (T, 3),
detections' boxes y (M, 3) = [heading, length, width].
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BoxParams:
    """Measurement noise std of a fitted box's heading [rad] and extent [m], random-walk std of the true box's
    heading [rad / sqrt(s)] and extent [m / sqrt(s)] ([D]: a car's box changes little; a turning car's heading
    follows at 0.3 rad / sqrt(s))."""

    sigma_heading: float = 0.1
    sigma_extent_m: float = 0.4
    q_heading: float = 0.3
    q_extent: float = 0.05

    def __post_init__(self) -> None:
        for name in ("sigma_heading", "sigma_extent_m", "q_heading", "q_extent"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"BoxParams.{name} must be finite and > 0, got {v}")

    @property
    def r(self) -> np.ndarray:
        """Measurement variances (3,) of [heading, length, width]."""
        return np.array([self.sigma_heading, self.sigma_extent_m, self.sigma_extent_m]) ** 2

    @property
    def q(self) -> np.ndarray:
        """Random-walk variances per second (3,)."""
        return np.array([self.q_heading, self.q_extent, self.q_extent]) ** 2


def half_turn(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to (-pi/2, pi/2] [rad]: a box's heading difference modulo pi."""
    return -(((-np.asarray(a, dtype=np.float64)) + 0.5 * math.pi) % math.pi - 0.5 * math.pi)


def box_birth(y: np.ndarray, params: BoxParams) -> tuple[np.ndarray, np.ndarray]:
    """A new track's box: its detection's box y (3,) and the measurement variances."""
    return np.asarray(y, dtype=np.float64).copy(), params.r.copy()


def box_update(b: np.ndarray, var: np.ndarray, y: np.ndarray, W: np.ndarray, w0: np.ndarray, dt: float,
               params: BoxParams) -> tuple[np.ndarray, np.ndarray]:
    """One scan of T tracks' boxes: b (T, 3), var (T, 3), detections' boxes y (M, 3), association weights W (T, M)
    and miss weights w0 (T,) of the kinematic update, dt [s]. Returns the new (b, var) (module docstring)."""
    b, var = np.asarray(b, dtype=np.float64).reshape(-1, 3), np.asarray(var, dtype=np.float64).reshape(-1, 3)
    var = var + params.q * max(float(dt), 0.0)  # random-walk predict
    if len(b) == 0 or len(y) == 0:
        return b.copy(), var
    W = np.asarray(W, dtype=np.float64).reshape(len(b), len(y))
    w0 = np.asarray(w0, dtype=np.float64).reshape(len(b))
    nu = np.asarray(y, dtype=np.float64)[None, :, :] - b[:, None, :]  # (T, M, 3)
    nu[..., 0] = half_turn(nu[..., 0])  # heading modulo pi
    nu_c = np.einsum("tj,tjk->tk", W, nu)  # (4.15) combined innovation
    K = var / (var + params.r)  # scalar gains, H = 1
    spread = np.einsum("tj,tjk->tk", W, nu * nu) - nu_c * nu_c
    beta0 = w0[:, None]
    var_new = beta0 * var + (1.0 - beta0) * (1.0 - K) * var + K * K * spread  # (4.16)-(4.17) per component
    b_new = b + K * nu_c
    b_new[:, 0] = (b_new[:, 0] + math.pi) % (2.0 * math.pi) - math.pi
    b_new[:, 1:] = np.maximum(b_new[:, 1:], 0.1)  # an extent stays a length
    return b_new, np.maximum(var_new, 1e-12)
