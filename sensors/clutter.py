"""Synthetic Poisson clutter: false detections uniform in a disk, count ~ Poisson(density * area).

Use it for object-list scenarios that bypass the LiDAR pipeline; with the pipeline, clutter arises from
roadside objects instead.
"""

from __future__ import annotations

import numpy as np

from roadtrack.sensors import checks
from roadtrack.sensors.perception import Detections


def poisson_clutter(
    rng: np.random.Generator, density_per_m2: float, center_xy: np.ndarray, radius_m: float
) -> np.ndarray:
    """(K, 2) float64 points uniform in the disk of radius_m [m] around center_xy (2,) [m], world frame;
    K ~ Poisson(density_per_m2 * pi * radius_m^2). density <= 0 or radius 0 gives K = 0."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: expected numpy.random.Generator, got {type(rng).__name__}")
    checks.finite("density_per_m2", density_per_m2)
    checks.positive("radius_m", radius_m, allow_zero=True)
    center = checks.float_array("center_xy", center_xy, (2,))
    mean = max(float(density_per_m2), 0.0) * np.pi * float(radius_m) ** 2
    k = int(rng.poisson(mean)) if mean > 0.0 else 0
    r = radius_m * np.sqrt(rng.random(k))  # sqrt: uniform in area, not in radius
    phi = 2.0 * np.pi * rng.random(k)
    return center + np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1).reshape(k, 2)


def clutter_detections(
    rng: np.random.Generator, density_per_m2: float, center_xy: np.ndarray, radius_m: float
) -> Detections:
    """poisson_clutter as Detections: provenance -1, n_points 0, extent zeros."""
    z = poisson_clutter(rng, density_per_m2, center_xy, radius_m)
    k = len(z)
    return Detections(z, np.full(k, -1, np.int64), np.zeros(k, np.int64), np.zeros((k, 3)))
