"""Ground segmentation: label each LiDAR point as road surface or not.

Methods (registry GROUND_METHODS):
  "road_plane" (default): fits the road plane z = a x + b y + c robustly (least squares on the lowest point
            of every `cell_m` BEV cell, trimmed in 3 rounds, then on the points near that plane), so a pitched
            or rolled ego (the road then appears tilted: 0.5 deg is 0.6 m at 70 m), a road higher than expected
            or a curve does not matter. A point is road when it lies at most `tol` above the plane. With the
            sensor origin given, `tol` follows the sensor's error model: a road return at range r has a height
            error h / r times its range error (h: the sensor's height above the plane), so
            tol = road_tol_m + range_tol_m * h / r + r * tan(angle_tol_deg), capped at height_tol_m: 4 cm
            near, 7 mm at 70 m, which keeps most of the bottom of guard rails and car bodies out. Without an
            origin, tol = height_tol_m. Last, a point of the upper 3/4 of its band that shares a `foot_cell_m`
            cell with a point 5-50 cm above its band stands at the foot of an object, and is not road.
            Assumes one plane over the sensor's range (the simulated roads are flat; a real road's grade
            changes would need piecewise planes).
  "grid":   Cartesian BEV grid of `cell_m` cells; the lowest point of a cell and its 8 neighbours is the local
            road height when it lies within `max_ground_offset_m` of the expected `ground_z_m`, else (road not
            seen nearby: under a roof, behind a car, beside a raised panel) ground_z_m is; a point is ground
            when z <= local road height + height_tol_m. Absorbs road-height errors up to max_ground_offset_m,
            not a tilted road.
  "ransac": open3d tensor `segment_plane` (distance height_tol_m); inliers are ground, unless the best plane
            is tilted more than `max_tilt_deg` (then it is a wall, not the road, and no point is ground).
  "height": z <= ground_z_m + height_tol_m (exact for a flat road at a known height).

`ground_scores` compares a mask with the scan's per-ray truth labels (precision and recall of GROUND).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from roadtrack.sensors import checks, perception_jit
from roadtrack.sensors.grid import MAX_CELLS, bev_cells
from roadtrack.sensors.open3d_loader import open3d
from roadtrack.sensors.lidar import GROUND

_COARSE_BANDS_M = (1.0, 0.3, 0.1)  # road_plane: trimming schedule of the fit on the cells' lowest points
_FINE_BAND_M = 0.05  # road_plane: the refit takes the points within this of the coarse plane
_FOOT_ABOVE_M = (0.05, 0.5)  # road_plane: heights above its band of the object points that mark a foot
_FOOT_KEEP = 0.25  # road_plane: a point in the lowest quarter of its band stays road even at a foot


@dataclass(frozen=True)
class GroundConfig:
    """Ground segmentation settings; lengths in metres, world frame z."""

    method: str = "road_plane"  # road_plane, grid, ransac, height
    height_tol_m: float = 0.2  # band above local road (grid, height; road_plane's cap); plane distance (ransac)
    ground_z_m: float = 0.0  # expected road height
    cell_m: float = 1.0  # grid, road_plane: cell size
    max_ground_offset_m: float = 0.25  # grid: a local lowest point counts as road only this close to ground_z_m
    range_tol_m: float = 0.08  # road_plane: a road return's range may fall this short of the plane (~4 noise sigmas)
    angle_tol_deg: float = 0.0  # road_plane: beam direction error allowed on top (~4 sigmas of the angular jitter)
    road_tol_m: float = 0.005  # road_plane: height band always allowed above the plane (fit error, roughness)
    foot_cell_m: float = 0.04  # road_plane: cell of the object-foot test (0 = off)
    ransac_iterations: int = 100  # ransac: open3d num_iterations
    max_tilt_deg: float = 10.0  # ransac, road_plane: steepest plane accepted as the road
    seed: int = 0  # ransac: seeds open3d's global RNG before each fit, so results are reproducible

    def __post_init__(self) -> None:
        checks.choice("GroundConfig.method", self.method, GROUND_METHODS)
        checks.positive("GroundConfig.height_tol_m", self.height_tol_m)
        checks.positive("GroundConfig.cell_m", self.cell_m)
        checks.positive("GroundConfig.max_ground_offset_m", self.max_ground_offset_m, allow_zero=True)
        checks.positive("GroundConfig.range_tol_m", self.range_tol_m, allow_zero=True)
        checks.positive("GroundConfig.angle_tol_deg", self.angle_tol_deg, allow_zero=True)
        if self.angle_tol_deg >= 10.0:
            raise ValueError(f"GroundConfig.angle_tol_deg: expected 0..10, got {self.angle_tol_deg!r}")
        checks.positive("GroundConfig.road_tol_m", self.road_tol_m, allow_zero=True)
        checks.positive("GroundConfig.foot_cell_m", self.foot_cell_m, allow_zero=True)
        checks.positive_int("GroundConfig.ransac_iterations", self.ransac_iterations)
        checks.positive_int("GroundConfig.seed", self.seed, allow_zero=True)
        checks.positive("GroundConfig.max_tilt_deg", self.max_tilt_deg, allow_zero=True)
        if self.max_tilt_deg > 90.0:
            raise ValueError(f"GroundConfig.max_tilt_deg: expected 0..90, got {self.max_tilt_deg!r}")
        checks.finite("GroundConfig.ground_z_m", self.ground_z_m)


def segment_ground(points: np.ndarray, cfg: GroundConfig, origin: np.ndarray | None = None) -> np.ndarray:
    """points (N, 3) world frame [m] -> is_ground (N,) bool.

    origin: (3,) sensor position [m] (Scan.origin), optional; road_plane uses it for its range-aware band.
    """
    pts = checks.float_array("points", points, (None, 3))
    if origin is not None:
        origin = checks.float_array("origin", origin, (3,))
    return segment_ground_unchecked(pts, cfg, origin)


def segment_ground_unchecked(points: np.ndarray, cfg: GroundConfig, origin: np.ndarray | None = None) -> np.ndarray:
    """segment_ground of points (N, 3) and origin (3,) already float64 and finite (a sensors.Scan's), without
    checking them again."""
    if len(points) == 0:
        return np.zeros(0, bool)
    return GROUND_METHODS[cfg.method](points, cfg, origin)


def ground_scores(is_ground: np.ndarray, source: np.ndarray) -> tuple[float, float]:
    """Precision and recall of a ground mask against the truth labels.

    is_ground: (N,) bool mask; source: (N,) int64 Scan.source (GROUND for a road return).
    Returns (precision, recall): the share of the points labelled ground that hit the road, and the share of
    the road returns labelled ground; nan when undefined (no point labelled ground, no road return).
    """
    mask = np.asarray(is_ground)
    if mask.dtype != bool or mask.ndim != 1:
        raise ValueError(f"is_ground: expected a 1-D bool array, got dtype {mask.dtype}, shape {mask.shape}")
    truth = checks.int_array("source", source, (len(mask),)) == GROUND
    hits = np.count_nonzero(mask & truth)
    n_labelled, n_road = np.count_nonzero(mask), np.count_nonzero(truth)
    return (hits / n_labelled if n_labelled else float("nan"), hits / n_road if n_road else float("nan"))


def _height(pts: np.ndarray, cfg: GroundConfig, origin: np.ndarray | None) -> np.ndarray:
    return pts[:, 2] <= cfg.ground_z_m + cfg.height_tol_m


def _grid(pts: np.ndarray, cfg: GroundConfig, origin: np.ndarray | None) -> np.ndarray:
    ix, iy, shape = bev_cells(pts, cfg.cell_m, "ground")
    cell = ix * shape[1] + iy
    z = pts[:, 2]
    lowest = np.full(shape[0] * shape[1], np.inf)
    np.minimum.at(lowest, cell, z)
    # 3x3 neighbourhood: a cell covered by the low part of an object borrows the road seen next to it.
    local = _min3x3(lowest.reshape(shape)).ravel()[cell]
    local = np.where(np.abs(local - cfg.ground_z_m) <= cfg.max_ground_offset_m, local, cfg.ground_z_m)
    return z <= local + cfg.height_tol_m


def _road_plane(pts: np.ndarray, cfg: GroundConfig, origin: np.ndarray | None) -> np.ndarray:
    centre = origin if origin is not None else np.array([*pts[:, :2].mean(axis=0), cfg.ground_z_m])
    # coordinates relative to the sensor, as contiguous columns, and the points' x, y bounds: one compiled pass
    x, y, z, bounds = perception_jit.relative_columns(pts, float(centre[0]), float(centre[1]), float(centre[2]))
    plane = _coarse_plane(pts, centre, z, cfg, bounds)
    # the points within _FINE_BAND_M of the coarse plane (np.abs(z - a x - b y - c) <= band, compiled)
    near = perception_jit.near_plane(x, y, z, float(plane[0]), float(plane[1]), float(plane[2]), _FINE_BAND_M)
    plane = _plane_fit(*near, plane)  # the cells' lowest points sit low and off-centre
    if not _acceptable(plane, cfg):
        plane = np.array([0.0, 0.0, cfg.ground_z_m - centre[2]])
    # compiled: a point is road when its height above the plane is at most the band tol (the range-aware band of
    # the module docstring when the origin is known, else height_tol_m), unless it is at an object's foot
    return perception_jit.road_band(
        x, y, z, float(plane[0]), float(plane[1]), float(plane[2]), origin is not None, cfg.road_tol_m,
        cfg.range_tol_m * max(-plane[2], 0.0), float(np.tan(np.deg2rad(cfg.angle_tol_deg))), cfg.height_tol_m,
        cfg.foot_cell_m, _FOOT_ABOVE_M[0], _FOOT_ABOVE_M[1], _FOOT_KEEP)


def _coarse_plane(pts: np.ndarray, centre: np.ndarray, z: np.ndarray, cfg: GroundConfig,
                  bounds: np.ndarray) -> np.ndarray:
    """(3,) plane [a, b, c], z = a x + b y + c relative to `centre` (3,), through the lowest point z (N,) of
    each BEV cell of the points (N, 3), taken at the cell centre: least squares trimmed to _COARSE_BANDS_M
    around the previous plane, starting from the road at ground_z_m. bounds: (4,) the points' smallest and
    largest x, then y [m]."""
    inv = 1.0 / cfg.cell_m  # cells numbered the way bev_cells does
    x_min, x_max, y_min, y_max = bounds
    fx0, fy0 = np.floor(x_min * inv), np.floor(y_min * inv)
    shape = (int(np.floor(x_max * inv) - fx0) + 1, int(np.floor(y_max * inv) - fy0) + 1)
    if shape[0] * shape[1] > MAX_CELLS:
        bev_cells(pts, cfg.cell_m, "ground")  # raises its ValueError
    # the occupied cells' centres cx, cy and lowest z, in cell order
    cx, cy, low = perception_jit.cell_lowest(pts, z, inv, float(fx0), float(fy0), shape[1], shape[0] * shape[1],
                                             cfg.cell_m, float(centre[0]), float(centre[1]))
    plane = np.array([0.0, 0.0, cfg.ground_z_m - centre[2]])
    for band in _COARSE_BANDS_M:  # the cells with np.abs(low - a cx - b cy - c) <= band, compiled
        plane = _plane_fit(*perception_jit.near_plane(cx, cy, low, float(plane[0]), float(plane[1]),
                                                      float(plane[2]), band), plane)
    return plane


def _plane_fit(x: np.ndarray, y: np.ndarray, z: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Least-squares plane [a, b, c], z = a x + b y + c, through the points x, y, z (M,) (normal equations);
    `plane` when they do not fix one."""
    n = len(x)
    sx, sy, sxy = x.sum(), y.sum(), np.dot(x, y)
    normal = np.array([[np.dot(x, x), sxy, sx], [sxy, np.dot(y, y), sy], [sx, sy, n]])
    if n < 3 or _ill_conditioned(normal):
        return plane
    return np.linalg.solve(normal, np.array([np.dot(x, z), np.dot(y, z), z.sum()]))


_MAX_COND = 1e12  # _plane_fit: a normal matrix with a larger condition number does not fix a plane


def _ill_conditioned(normal: np.ndarray) -> bool:
    """np.linalg.cond(normal) > _MAX_COND for a 3x3 normal matrix (symmetric), without its SVD when a bound shows
    it well below: for a positive definite matrix cond = l_max / l_min <= trace / (4 det / trace^2) (l_max <=
    trace, and the other two eigenvalues' product is at most (trace / 2)^2). The bound is trusted only below
    _MAX_COND / 100, where the rounding of det is far too small to matter; anything else is np.linalg.cond's."""
    (a, b, c), (_, d, e), (_, _, f) = normal.tolist()
    trace = a + d + f
    det = a * (d * f - e * e) - b * (b * f - c * e) + c * (b * e - c * d)
    if det > 0.0 and trace > 0.0 and trace**3 / (4.0 * det) < _MAX_COND / 100.0:
        return False
    return bool(np.linalg.cond(normal) > _MAX_COND)


def _acceptable(plane: np.ndarray, cfg: GroundConfig) -> bool:
    return bool(np.hypot(plane[0], plane[1]) <= np.tan(np.deg2rad(cfg.max_tilt_deg)))


def _min3x3(grid: np.ndarray) -> np.ndarray:
    """Minimum over each cell and its 8 neighbours (cells off the grid ignored), like
    scipy.ndimage.minimum_filter(grid, size=3, mode="nearest")."""
    padded = np.full((grid.shape[0] + 2, grid.shape[1] + 2), np.inf)
    padded[1:-1, 1:-1] = grid
    rows = np.minimum(np.minimum(padded[:-2], padded[1:-1]), padded[2:])
    return np.minimum(np.minimum(rows[:, :-2], rows[:, 1:-1]), rows[:, 2:])


def _ransac(pts: np.ndarray, cfg: GroundConfig, origin: np.ndarray | None) -> np.ndarray:
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


GROUND_METHODS: dict[str, Callable[[np.ndarray, GroundConfig, np.ndarray | None], np.ndarray]] = {
    "road_plane": _road_plane,
    "grid": _grid,
    "ransac": _ransac,
    "height": _height,
}
