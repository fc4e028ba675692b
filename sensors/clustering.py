"""Euclidean clustering of non-ground points into objects.

Methods (registry CLUSTER_METHODS):
  "grid":   bird's-eye occupancy grid of `cell_m` cells, connected components with 8-connectivity
            (scipy.ndimage.label's, compiled); two points share a cluster when a chain of occupied cells
            joins them.
  "dbscan": open3d tensor `cluster_dbscan(eps_m, min_points)` in 3-D.
Scan-line links (`scan_line_links`; sensors.perception joins clusters and noise points by them): consecutive
returns of one beam (adjacent azimuths, or two apart across a ray that returned nothing) lie on one surface when
the segment between them is at most `link_max_gap_m` long and meets the farther ray at `link_min_angle_deg` or
more. A car's side seen at a grazing angle 30-40 m ahead gives returns ~1.2 m apart along the lane (the azimuth
step over the sine of the grazing angle) that no cell size joins, while the jump from a car to the next one
behind a gap mostly runs nearly along the ray (the angle test of Bogoslavskyi and Stachniss's range-image
segmentation, IROS 2016).
Clusters with fewer than `min_points` points become noise (-1). Clusters are numbered by their first
point in lexicographic (x, y, z) order, so the labels do not depend on the input point order. DBSCAN
clusters the points in that order (its border points otherwise go to whichever cluster came first);
the grid's components depend on the occupied cells only, so it clusters the points as given and only
the clusters' lexicographically first points are sorted (the same labels, without sorting every point).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from roadtrack.sensors import checks, perception_jit
from roadtrack.sensors.grid import MAX_CELLS, bev_cells
from roadtrack.sensors.open3d_loader import open3d


@dataclass(frozen=True)
class ClusterConfig:
    """Clustering settings; lengths in metres."""

    method: str = "grid"
    cell_m: float = 0.5  # grid: BEV cell size
    eps_m: float = 0.7  # dbscan: neighbourhood radius
    min_points: int = 5  # smaller clusters are noise (also DBSCAN's core-point count)
    scan_line_links: bool = True  # perception: join consecutive returns of a beam on one surface (module doc)
    link_min_angle_deg: float = 3.0  # ... when their segment meets the farther ray at least at this angle
    link_max_gap_m: float = 2.0  # ... and is at most this long [m]

    def __post_init__(self) -> None:
        checks.choice("ClusterConfig.method", self.method, CLUSTER_METHODS)
        checks.positive("ClusterConfig.cell_m", self.cell_m)
        checks.positive("ClusterConfig.eps_m", self.eps_m)
        checks.positive_int("ClusterConfig.min_points", self.min_points)
        if not isinstance(self.scan_line_links, bool):
            raise ValueError(f"ClusterConfig.scan_line_links: expected a bool, got {self.scan_line_links!r}")
        checks.positive("ClusterConfig.link_min_angle_deg", self.link_min_angle_deg)
        if self.link_min_angle_deg >= 90.0:
            raise ValueError(f"ClusterConfig.link_min_angle_deg: expected below 90, got {self.link_min_angle_deg!r}")
        checks.positive("ClusterConfig.link_max_gap_m", self.link_max_gap_m)


def cluster(points: np.ndarray, cfg: ClusterConfig) -> np.ndarray:
    """points (N, 3) [m] -> labels (N,) int64: cluster 0..C-1, or -1 for noise / too-small clusters."""
    return cluster_unchecked(checks.float_array("points", points, (None, 3)), cfg)


def cluster_unchecked(pts: np.ndarray, cfg: ClusterConfig) -> np.ndarray:
    """cluster of points (N, 3) already float64 and finite (a sensors.Scan's), without checking them again."""
    if len(pts) == 0:
        return np.zeros(0, np.int64)
    if cfg.method == "grid":
        return _grid_numbered(pts, cfg)
    if cfg.method in ORDER_FREE:
        return numbered(pts, ORDER_FREE[cfg.method](pts, cfg), cfg.min_points)
    order = np.lexsort((pts[:, 2], pts[:, 1], pts[:, 0]))
    raw = CLUSTER_METHODS[cfg.method](pts[order], cfg)  # labels of the sorted points, -1 = noise
    sorted_labels = _canonical(raw, cfg.min_points)
    labels = np.empty(len(pts), np.int64)
    labels[order] = sorted_labels
    return labels


def scan_line_links(points: np.ndarray, ray: np.ndarray, shape: tuple[int, int], origin: np.ndarray,
                    returned: np.ndarray, cfg: ClusterConfig, labels: np.ndarray | None = None) -> np.ndarray:
    """Pairs (L, 2) int64 of indices into points (N, 3) [m] that are consecutive returns of one beam on one
    surface (module docstring): ray (N,) int64 flat range-image index a * B + b (-1 unknown: never linked),
    shape (A, B) the range image's, origin (3,) the sensor [m], returned (A, B) bool rays with any return
    (a ray without one may lie between two linked points). labels (N,) int64: cluster labels (-1 noise); when
    given, only pairs not already in one cluster are returned (the others join nothing)."""
    return scan_line_links_unchecked(checks.float_array("points", points, (None, 3)), ray, shape, origin, returned,
                                     cfg, labels)


def scan_line_links_unchecked(pts: np.ndarray, ray: np.ndarray, shape: tuple[int, int], origin: np.ndarray,
                              returned: np.ndarray, cfg: ClusterConfig, labels: np.ndarray | None = None) -> np.ndarray:
    """scan_line_links of points (N, 3) already float64 and finite (a sensors.Scan's), without checking them again."""
    n_az, n_beams = shape
    ray = np.asarray(ray, np.int64)
    has_labels = labels is not None
    # compiled: the same operations in numpy's order (perception_reference.scan_line_links_reference)
    return perception_jit.line_links(pts, ray, int(n_az), int(n_beams), np.asarray(returned, bool),
                                     np.asarray(labels, np.int64) if has_labels else ray, has_labels,
                                     np.asarray(origin, np.float64), float(cfg.link_max_gap_m),
                                     float(np.sin(np.deg2rad(cfg.link_min_angle_deg))))


def numbered(pts: np.ndarray, raw: np.ndarray, min_points: int) -> np.ndarray:
    """Labels (N,) for points (N, 3) from raw labels (N,) (-1 noise) that do not depend on the point order:
    what _canonical gives on the lexicographically sorted points, for raw labels (N,) that do not depend
    on the point order: clusters under min_points dropped, the rest numbered 0.. in the lexicographic
    (x, y, z) order of their first points. Each cluster's first point is found by one compiled pass
    (perception_jit.first_points; perception_reference.numbered_reference is the former numpy code)."""
    out = np.full(len(raw), -1, np.int64)
    valid = np.flatnonzero(raw >= 0)
    if len(valid) == 0:
        return out
    lab = raw[valid]
    counts, first = perception_jit.first_points(lab, valid, pts, int(lab.max()) + 1)
    out[valid] = _renumbering(pts, counts, valid[np.maximum(first, 0)], first >= 0, min_points)[lab]
    return out


def _renumbering(pts: np.ndarray, counts: np.ndarray, first: np.ndarray, has_points: np.ndarray,
                 min_points: int) -> np.ndarray:
    """(k,) int64 the label of each of k raw clusters (-1: dropped) as `numbered` gives it: those with count (k,)
    >= min_points (and has_points (k,) bool) numbered 0.. in the lexicographic (x, y, z) order of their first
    points, indices first (k,) into pts (N, 3), equal points by index."""
    kept = np.flatnonzero((counts >= min_points) & has_points)
    f = first[kept]
    ids = kept[np.lexsort((f, pts[f, 2], pts[f, 1], pts[f, 0]))]  # by first point, equal ones by position
    new = np.full(len(counts), -1, np.int64)
    new[ids] = np.arange(len(ids))
    return new


def _grid_numbered(pts: np.ndarray, cfg: ClusterConfig) -> np.ndarray:
    """numbered(pts, _grid(pts, cfg), cfg.min_points) for points (N, 3), N >= 1: the components, their counts and
    first points in one compiled call (perception_jit.grid_clusters), then the numbering."""
    comp, counts, first, ok = perception_jit.grid_clusters(pts, 1.0 / cfg.cell_m, MAX_CELLS)
    if not ok:
        bev_cells(pts, cfg.cell_m, "cluster")  # raises its ValueError
    return _renumbering(pts, counts, first, first >= 0, cfg.min_points)[comp]


def _canonical(raw: np.ndarray, min_points: int) -> np.ndarray:
    """Drop clusters under min_points; renumber the rest 0.. by first appearance."""
    out = np.full(len(raw), -1, np.int64)
    valid = raw >= 0
    if not valid.any():
        return out
    ids, first, counts = np.unique(raw[valid], return_index=True, return_counts=True)
    big = counts >= min_points
    ids, first = ids[big], first[big]
    new = np.full(int(raw.max()) + 1, -1, np.int64)
    new[ids[np.argsort(first)]] = np.arange(len(ids))
    out[valid] = new[raw[valid]]
    return out


def _grid(pts: np.ndarray, cfg: ClusterConfig) -> np.ndarray:
    """Component (N,) of each point's occupied cell, 8-connected: compiled (perception_jit.grid_clusters, which
    also counts them for `_grid_numbered`), the partition of scipy.ndimage.label (perception_reference.
    grid_labels_reference) numbered otherwise, which `numbered` makes irrelevant."""
    comp, _, _, ok = perception_jit.grid_clusters(pts, 1.0 / cfg.cell_m, MAX_CELLS)
    if not ok:
        bev_cells(pts, cfg.cell_m, "cluster")  # raises its ValueError
    return comp


def _dbscan(pts: np.ndarray, cfg: ClusterConfig) -> np.ndarray:
    o3d = open3d()
    local = (pts - pts.mean(axis=0)).astype(np.float32)  # float32 runs twice as fast; centred keeps precision
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(local))
    return cloud.cluster_dbscan(eps=cfg.eps_m, min_points=cfg.min_points).numpy().astype(np.int64)


CLUSTER_METHODS: dict[str, Callable[[np.ndarray, ClusterConfig], np.ndarray]] = {
    "grid": _grid,
    "dbscan": _dbscan,
}
ORDER_FREE = {"grid": _grid}  # methods whose clusters do not depend on the point order (labelled unsorted)
