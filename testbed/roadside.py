"""Static roadside objects (guard rails, posts, sign panels, trees) placed along the road edges.

They are real geometry for the ray caster: whatever of them survives ground removal, clustering and the
vehicle-like test becomes clutter, as in a real perception stack. Placement is seeded.
"""
from __future__ import annotations

import numpy as np

from .scenario import RoadsideSpec

# (length, width, height) [m]
BARRIER_SEGMENT = (4.0, 0.3, 0.75)  # guard rail
POST = (0.2, 0.2, 1.2)
SIGN = (2.0, 0.15, 1.2)  # panel, lifted by SIGN_LIFT
SIGN_LIFT = 1.0
TRUNK = (0.4, 0.4)  # trunk footprint [m]; its height is the crown's lift
CROWN_SIZE_RANGE = ((2.5, 5.0), (2.5, 5.0), (2.0, 5.0))
CROWN_LIFT_RANGE = (2.2, 3.5)
BUSH_SIZE_RANGE = ((1.0, 3.5), (1.0, 3.5), (0.8, 2.5))


def _along(points: np.ndarray, spacing: float, phase: float = 0.0) -> np.ndarray:
    """Indices of edge samples (1 m apart) every ``spacing`` metres."""
    if spacing <= 0:
        return np.zeros(0, dtype=np.int64)
    return np.arange(int(phase) % max(int(spacing), 1), len(points), max(int(round(spacing)), 1))


def roadside_boxes(edges: list[tuple[np.ndarray, np.ndarray]], spec: RoadsideSpec,
                   rng: np.random.Generator) -> np.ndarray:
    """Boxes ``(K, 7)`` [cx, cy, L, W, H, yaw, z_bottom] beside the road.

    ``edges``: list of (points (P, 2), outward normals (P, 2)) sampled every 1 m (see
    :func:`testbed.simulation.road_edges`).
    """
    out: list[list[float]] = []
    for pts, normals in edges:
        if len(pts) < 2:
            continue
        tangent = np.gradient(pts, axis=0)
        yaw = np.arctan2(tangent[:, 1], tangent[:, 0])
        off = spec.barrier_offset_m
        if spec.barriers:
            seg = int(BARRIER_SEGMENT[0])
            for i in range(seg // 2, len(pts), seg):
                c = pts[i] + normals[i] * off
                out.append([c[0], c[1], *BARRIER_SEGMENT, yaw[i], 0.0])
        for i in _along(pts, spec.post_spacing_m, phase=rng.integers(0, 1000)):
            c = pts[i] + normals[i] * (off + 0.5)
            out.append([c[0], c[1], *POST, yaw[i], 0.0])
        length_km = len(pts) / 1000.0
        for _ in range(rng.poisson(spec.signs_per_km * length_km)):
            i = rng.integers(0, len(pts))
            c = pts[i] + normals[i] * (off + 1.5)
            out.append([c[0], c[1], *SIGN, yaw[i] + rng.uniform(-0.3, 0.3), SIGN_LIFT])
        for _ in range(rng.poisson(spec.trees_per_km * length_km)):  # trunk + crown
            i = rng.integers(0, len(pts))
            crown = [rng.uniform(lo, hi) for lo, hi in CROWN_SIZE_RANGE]
            lift = rng.uniform(*CROWN_LIFT_RANGE)
            c = pts[i] + normals[i] * (off + 2.0 + crown[1] / 2 + rng.uniform(0.0, 8.0))
            yaw_t = rng.uniform(-np.pi, np.pi)
            out.append([c[0], c[1], *TRUNK, lift, yaw_t, 0.0])
            out.append([c[0], c[1], *crown, yaw_t, lift])
        for _ in range(rng.poisson(spec.bushes_per_km * length_km)):
            i = rng.integers(0, len(pts))
            size = [rng.uniform(lo, hi) for lo, hi in BUSH_SIZE_RANGE]
            c = pts[i] + normals[i] * (off + 1.0 + size[1] / 2 + rng.uniform(0.0, 6.0))
            out.append([c[0], c[1], *size, rng.uniform(-np.pi, np.pi), 0.0])
    return np.asarray(out, dtype=np.float64).reshape(-1, 7)


def boxes_near(boxes: np.ndarray, center_xy: np.ndarray, radius: float) -> np.ndarray:
    """Boolean mask (K,) of boxes whose centre lies within ``radius`` (+ their half diagonal) of a point."""
    if len(boxes) == 0:
        return np.zeros(0, dtype=bool)
    d = np.hypot(boxes[:, 0] - center_xy[0], boxes[:, 1] - center_xy[1])
    return d <= radius + 0.5 * np.hypot(boxes[:, 2], boxes[:, 3])
