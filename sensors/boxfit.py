"""Oriented 2-D rectangles around a cluster's bird's-eye-view points.

Each fit takes xy (n, 2) [m] and returns (centre (2,), length, width) with length >= width [m].
  min_area_rectangle: minimum-area enclosing rectangle (rotating calipers over the convex-hull edges).
      Exact for a fully seen footprint, but for an L-shaped view (two faces of a car) a rectangle along
      the L's hypotenuse has the same area as the true one, so the fit can tilt and shift the centre.
  lshape_rectangle: L-shape fit with the closeness criterion of Zhang et al., "Efficient L-shape fitting
      for vehicle detection using laser scanners", IEEE IV 2017: the heading maximising
      sum_i 1 / max(d_i, d0), d_i the distance of point i to the nearest rectangle edge, searched on a
      `step_deg` grid over [0, 90) deg; the rectangle is then the enclosing one at that heading.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError


def min_area_rectangle(xy: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Minimum-area enclosing rectangle; collinear or repeated points give one along their principal axis."""
    origin = xy.mean(axis=0)
    local = xy - origin  # well conditioned far from the world origin
    try:
        hull = local[ConvexHull(local).vertices]
        edges = np.diff(np.vstack([hull, hull[:1]]), axis=0)
        angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2))
    except (QhullError, ValueError):  # fewer than 3 points, or all collinear
        hull = local
        angles = np.array([_principal_angle(local)])
    return _enclosing(origin, hull, angles)


def lshape_rectangle(
    xy: np.ndarray, step_deg: float = 1.0, d0_m: float = 0.01, max_points: int = 256
) -> tuple[np.ndarray, float, float]:
    """Closeness-criterion L-shape rectangle; at most `max_points` evenly spaced points score each heading."""
    origin = xy.mean(axis=0)
    local = xy - origin
    if len(local) < 3:
        return _enclosing(origin, local, np.array([_principal_angle(local)]))
    sample = local[np.linspace(0, len(local) - 1, min(len(local), max_points)).astype(np.int64)]
    angles = np.deg2rad(np.arange(0.0, 90.0, step_deg))
    c, s = np.cos(angles), np.sin(angles)
    u = sample @ np.stack([c, s])  # (n, A) coordinate along each candidate heading
    v = sample @ np.stack([-s, c])
    du = np.minimum(u.max(axis=0) - u, u - u.min(axis=0))
    dv = np.minimum(v.max(axis=0) - v, v - v.min(axis=0))
    closeness = np.sum(1.0 / np.maximum(np.minimum(du, dv), d0_m), axis=0)
    best = angles[int(np.argmax(closeness))]
    return _enclosing(origin, local, np.array([best]))


def _principal_angle(local: np.ndarray) -> float:
    if len(local) < 2:
        return 0.0
    axis = np.linalg.svd(local, full_matrices=False)[2][0]
    return float(np.arctan2(axis[1], axis[0]))


def _enclosing(origin: np.ndarray, pts: np.ndarray, angles: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Smallest-area enclosing rectangle of pts among the candidate headings `angles` (E,) [rad]."""
    c, s = np.cos(angles), np.sin(angles)
    u = pts @ np.stack([c, s])
    v = pts @ np.stack([-s, c])
    du = u.max(axis=0) - u.min(axis=0)
    dv = v.max(axis=0) - v.min(axis=0)
    k = int(np.argmin(du * dv))
    mu = 0.5 * (u[:, k].max() + u[:, k].min())
    mv = 0.5 * (v[:, k].max() + v[:, k].min())
    centre = origin + mu * np.array([c[k], s[k]]) + mv * np.array([-s[k], c[k]])
    return centre, float(max(du[k], dv[k])), float(min(du[k], dv[k]))
