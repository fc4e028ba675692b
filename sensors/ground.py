"""Ground segmentation: label each LiDAR point as road surface or not.

Methods (registry GROUND_METHODS):
  "grid":   Cartesian BEV grid of `cell_m` cells; the lowest point of a cell and its 8 neighbours is the local
            road height when it lies within `max_ground_offset_m` of the expected `ground_z_m`, else (road not
            seen nearby: under a roof, behind a car, beside a raised panel) ground_z_m is; a point is ground
            when z <= local road height + height_tol_m. Absorbs road-height errors up to max_ground_offset_m.
  "ransac": open3d tensor `segment_plane` (distance height_tol_m); inliers are ground, unless the best plane
            is tilted more than `max_tilt_deg` (then it is a wall, not the road, and no point is ground).
  "height": z <= ground_z_m + height_tol_m (exact for a flat road at a known height).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import ndimage

from sensors import _checks
from sensors._grid import bev_cells
from sensors._o3d import open3d


@dataclass(frozen=True)
class GroundConfig:
    """Ground segmentation settings; lengths in metres, world frame z."""

    method: str = "grid"
    height_tol_m: float = 0.2  # band above local road (grid) or road (height); plane distance (ransac)
    ground_z_m: float = 0.0  # expected road height
    cell_m: float = 1.0  # grid: cell size
    max_ground_offset_m: float = 0.25  # grid: a local lowest point counts as road only this close to ground_z_m
    ransac_iterations: int = 100  # ransac: open3d num_iterations
    max_tilt_deg: float = 10.0  # ransac: steepest plane accepted as the road
    seed: int = 0  # ransac: seeds open3d's global RNG before each fit, so results are reproducible

    def __post_init__(self) -> None:
        _checks.choice("GroundConfig.method", self.method, GROUND_METHODS)
        _checks.positive("GroundConfig.height_tol_m", self.height_tol_m)
        _checks.positive("GroundConfig.cell_m", self.cell_m)
        _checks.positive("GroundConfig.max_ground_offset_m", self.max_ground_offset_m, allow_zero=True)
        _checks.positive_int("GroundConfig.ransac_iterations", self.ransac_iterations)
        _checks.positive_int("GroundConfig.seed", self.seed, allow_zero=True)
        _checks.positive("GroundConfig.max_tilt_deg", self.max_tilt_deg, allow_zero=True)
        if self.max_tilt_deg > 90.0:
            raise ValueError(f"GroundConfig.max_tilt_deg: expected 0..90, got {self.max_tilt_deg!r}")
        _checks.finite("GroundConfig.ground_z_m", self.ground_z_m)


def segment_ground(points: np.ndarray, cfg: GroundConfig) -> np.ndarray:
    """points (N, 3) world frame [m] -> is_ground (N,) bool."""
    pts = _checks.float_array("points", points, (None, 3))
    if len(pts) == 0:
        return np.zeros(0, bool)
    return GROUND_METHODS[cfg.method](pts, cfg)


def _height(pts: np.ndarray, cfg: GroundConfig) -> np.ndarray:
    return pts[:, 2] <= cfg.ground_z_m + cfg.height_tol_m


def _grid(pts: np.ndarray, cfg: GroundConfig) -> np.ndarray:
    ix, iy, shape = bev_cells(pts, cfg.cell_m, "ground")
    cell = ix * shape[1] + iy
    z = pts[:, 2]
    lowest = np.full(shape[0] * shape[1], np.inf)
    np.minimum.at(lowest, cell, z)
    # 3x3 neighbourhood: a cell covered by the low part of an object borrows the road seen next to it.
    local = ndimage.minimum_filter(lowest.reshape(shape), size=3, mode="nearest").ravel()[cell]
    local = np.where(np.abs(local - cfg.ground_z_m) <= cfg.max_ground_offset_m, local, cfg.ground_z_m)
    return z <= local + cfg.height_tol_m


def _ransac(pts: np.ndarray, cfg: GroundConfig) -> np.ndarray:
    is_ground = np.zeros(len(pts), bool)
    if len(pts) < 3:
        return is_ground
    o3d = open3d()
    o3d.utility.random.seed(cfg.seed)
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(pts))
    plane, inliers = cloud.segment_plane(
        distance_threshold=cfg.height_tol_m, ransac_n=3, num_iterations=cfg.ransac_iterations
    )
    normal = plane.numpy()[:3]
    cos_tilt = abs(normal[2]) / max(np.linalg.norm(normal), 1e-12)
    if cos_tilt >= np.cos(np.deg2rad(cfg.max_tilt_deg)):
        is_ground[inliers.numpy()] = True
    return is_ground


GROUND_METHODS: dict[str, Callable[[np.ndarray, GroundConfig], np.ndarray]] = {
    "grid": _grid,
    "ransac": _ransac,
    "height": _height,
}
