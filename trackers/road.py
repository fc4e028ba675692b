"""Road-map aided tracking [D]: what a lane map tells a tracker about a car it cannot see, or sees turning.

The caller may give the tracker the road as a function of positions (the testbed builds it from its lane map,
testbed/sensing):

    road(xy (T, 2) [m]) -> (heading (T,) [rad], offset (T,) [m], half_width (T,) [m], curvature (T,) [1/m])

the nearest lane's direction, the signed offset of xy from its centre line (> 0: to the left of the lane's
direction), its half width and its signed curvature (> 0: the lane turns left). With it:

* **Curvature input** (`road_curvature`): a car keeps its lane, so in a bend it accelerates towards the bend's
  centre by a = v_t^2 kappa (v_t its speed along the lane). The prediction of a near-constant-velocity state adds
  that acceleration as a known input over dt, x_k = A x_{k-1} + B u with B = [dt^2/2 I; dt I] (the
  constant-velocity model's input matrix, thesis §1.1 (1.1)-(1.3) with a deterministic input), u = kappa v_t^2 n,
  n the lane's left normal, kappa and n taken at the previous estimate. A CV filter in a 20 m bend otherwise
  lags its car by v^2 kappa / beta-scale velocity errors (2.7 m/s at 11 m/s, sigma_v = 4 m/s^2, 10 Hz) and, when
  the car is hidden in the bend, coasts straight off the road. Modes of an IMM with a turn-rate state (a
  nonlinear motion model, the CT model) model the turn themselves and get no input.
  **Spread** (`road_curvature_spread`, on by default): the input is uncertain by its own size, Sigma_u = u u^T, so
  the prediction's covariance grows by B Sigma_u B^T = (B u)(B u)^T. Where the lane bends the gate widens across
  it: a car that leaves the bend (a roundabout's exit, whose lane the map reaches only metres later) pulls its
  track off the ring, where with the input exact its detections were weighed as clutter while the input held the
  track on the ring (shipped roundabout, jpda-kf, 3 seeds: 5 of 12 cars relabelled exact, 0 with the spread).
  An IMM's linear modes take the input exact: its turn-rate mode is the alternative hypothesis.
* **Lane keeping** (`road_lane_keeping`): a confirmed track with no gated measurement in a scan (hidden, or
  missed) is updated with the pseudo-measurement "the car is in the lane it is nearest to": its cross-lane
  offset is 0 with the variance of a uniform position across the lane, (2 w)^2 / 12 = w^2 / 3 for half width w
  (soft-constrained Kalman filtering, a scalar Kalman update with H = n^T on the position entries, Joseph form).
  A hidden car's cross-lane uncertainty then stays within a lane (1.15 m on a 4 m lane) instead of growing as
  sigma_v t^(3/2), so its gate stays that of one lane. Not for a track moving across its lane faster than
  `lane_keeping_max_cross_mps` (a car changing lanes: held in its old lane, it would be 4 m off when it
  re-appears in the new one), nor for one off the road (farther than the half width from the lane's centre: a
  roadside object is not pulled into a lane).

Neither touches a track whose filter has no position/velocity layout (`motion.position`, `motion.velocity`) or a
plug-in filter without the batched hooks (`shift_many`, `pseudo_update_many`): those are left as predicted.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

RoadInput = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
"""road(xy (T, 2)) -> (heading (T,), offset (T,), half_width (T,), curvature (T,)); see the module docstring."""


def lane_normals(heading: np.ndarray) -> np.ndarray:
    """Left unit normals (T, 2) of lane directions heading (T,) [rad]."""
    return np.column_stack([-np.sin(heading), np.cos(heading)])


def centripetal_input(road: RoadInput, xy: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The lane's centripetal acceleration u = kappa v_t^2 n (T, 2) [m/s^2] of cars at xy (T, 2) [m] with velocity
    v (T, 2) [m/s]; v_t = v . t the speed along the lane (its sign does not matter: kappa and n flip together)."""
    if len(xy) == 0:
        return np.zeros((0, 2))
    heading, _, _, kappa = road(xy)
    v_t = v[:, 0] * np.cos(heading) + v[:, 1] * np.sin(heading)
    return (kappa * v_t * v_t)[:, None] * lane_normals(heading)


def input_shift(u: np.ndarray, dt: float) -> np.ndarray:
    """The state change B u (T, 4) of [px, py, vx, vy] over dt [s] from accelerations u (T, 2): [dt^2/2 u; dt u]."""
    return np.concatenate([0.5 * dt * dt * u, dt * u], axis=1)  # (1.1)-(1.3): CV model with a known input


def lane_pseudo_measurement(road: RoadInput, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lane-keeping pseudo-measurement of cars at xy (T, 2) [m]: measurement rows h (T, 2) on the position
    (the lane's left normal), innovations y (T,) = 0 - offset [m] and variances r (T,) = w^2 / 3 [m^2]."""
    heading, offset, half_width, _ = road(xy)
    return lane_normals(heading), -np.asarray(offset, dtype=np.float64), half_width ** 2 / 3.0


def cross_lane_std(road: RoadInput, xy: np.ndarray, P_pos: np.ndarray) -> np.ndarray:
    """Standard deviation (T,) [m] across the nearest lane of position covariances P_pos (T, 2, 2) at xy (T, 2)."""
    if len(xy) == 0:
        return np.zeros(0)
    n = lane_normals(road(xy)[0])
    return np.sqrt(np.maximum(np.einsum("ti,tij,tj->t", n, P_pos, n), 0.0))
