"""From a LiDAR scan to vehicle-like object detections: ground removal, clustering, box fit, selection.

Each detection's measurement z is computed from the points only; `provenance` (which vehicle made it)
comes from the scan's truth labels and is meant for scoring, never for the tracker.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from sensors import _checks
from sensors.boxfit import lshape_rectangle, min_area_rectangle
from sensors.clustering import ClusterConfig, cluster
from sensors.ground import GroundConfig, segment_ground
from sensors.lidar import Scan


@dataclass(frozen=True)
class Detections:
    """M detections of one frame.

    z: (M, 2) float64 measurement (x, y), world frame [m].
    provenance: (M,) int64 vehicle id whose points are the plurality of the cluster, or -1 (clutter).
    n_points: (M,) int64 points in the cluster (0 for synthetic clutter).
    extent: (M, 3) float64 length >= width of the cluster's footprint box (the representative's box fit),
        and height of the cluster's top above the road [m] (zeros for synthetic clutter).
    """

    z: np.ndarray
    provenance: np.ndarray
    n_points: np.ndarray
    extent: np.ndarray

    def __post_init__(self) -> None:
        z = _checks.float_array("Detections.z", self.z, (None, 2))
        m = len(z)
        object.__setattr__(self, "z", z)
        object.__setattr__(self, "provenance", _checks.int_array("Detections.provenance", self.provenance, (m,)))
        object.__setattr__(self, "n_points", _checks.int_array("Detections.n_points", self.n_points, (m,)))
        object.__setattr__(self, "extent", _checks.float_array("Detections.extent", self.extent, (m, 3)))

    def __len__(self) -> int:
        return len(self.z)

    @staticmethod
    def empty() -> "Detections":
        return Detections(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))

    def concat(self, other: "Detections") -> "Detections":
        """self's detections, then other's."""
        return Detections(
            np.concatenate([self.z, other.z]),
            np.concatenate([self.provenance, other.provenance]),
            np.concatenate([self.n_points, other.n_points]),
            np.concatenate([self.extent, other.extent]),
        )


def _centroid(xy: np.ndarray) -> tuple[np.ndarray, float, float]:
    _, length, width = min_area_rectangle(xy)
    return xy.mean(axis=0), length, width


# name -> fit(xy (n, 2)) -> (measurement (2,), footprint length, width); see sensors/boxfit.py
REPRESENTATIVES: dict[str, Callable[[np.ndarray], tuple[np.ndarray, float, float]]] = {
    "bbox_center": min_area_rectangle,  # centre of the minimum-area oriented 2-D box of the cluster
    "lshape_center": lshape_rectangle,  # centre of the L-shape (closeness criterion) box
    "centroid": _centroid,  # mean (x, y) of the cluster's points; extent from the minimum-area box
}


@dataclass(frozen=True)
class PerceptionConfig:
    """Pipeline settings; lengths in metres, heights above the road (GroundConfig.ground_z_m)."""

    ground: GroundConfig = GroundConfig()
    cluster: ClusterConfig = ClusterConfig()
    max_height_m: float = 4.0  # points higher than this (bridges, high signs) are dropped before clustering
    vehicle_like: bool = True  # keep only clusters whose box fits a vehicle (bounds below)
    min_extent_m: float = 1.0  # longer footprint side at least (a far car may show one face only)
    max_length_m: float = 8.0  # longer footprint side at most
    max_width_m: float = 3.5  # shorter footprint side at most
    min_height_m: float = 0.8  # top of the cluster above the road, at least (thesis 8.2: 0.8-3.5 m; rejects guard rails)
    max_object_height_m: float = 3.5  # ... and at most
    max_median_height_m: float = 2.0  # median point height above the road, at most (tree crowns, high signs)
    complete_one_face: bool = True  # a cluster showing one face only: move its centre half a car deeper
    one_face_width_m: float = 0.6  # a fitted box narrower than this shows one face only
    size_prior_m: tuple[float, float] = (4.6, 1.8)  # typical car length, width for that completion [m]
    representative: str = "lshape_center"  # see REPRESENTATIVES; L-shape fit: 0.12 m median error near cars

    def __post_init__(self) -> None:
        if not isinstance(self.ground, GroundConfig):
            raise TypeError(f"PerceptionConfig.ground: expected GroundConfig, got {type(self.ground).__name__}")
        if not isinstance(self.cluster, ClusterConfig):
            raise TypeError(f"PerceptionConfig.cluster: expected ClusterConfig, got {type(self.cluster).__name__}")
        if not isinstance(self.vehicle_like, bool):
            raise ValueError(f"PerceptionConfig.vehicle_like: expected a bool, got {self.vehicle_like!r}")
        _checks.positive("PerceptionConfig.max_median_height_m", self.max_median_height_m)
        _checks.positive("PerceptionConfig.one_face_width_m", self.one_face_width_m)
        if not isinstance(self.complete_one_face, bool):
            raise ValueError(f"PerceptionConfig.complete_one_face: expected a bool, got {self.complete_one_face!r}")
        if len(self.size_prior_m) != 2 or not all(np.isfinite(self.size_prior_m)) or min(self.size_prior_m) <= 0:
            raise ValueError(f"PerceptionConfig.size_prior_m: expected (length, width) > 0, got {self.size_prior_m!r}")
        for name in ("max_height_m", "max_length_m", "max_width_m", "max_object_height_m"):
            _checks.positive(f"PerceptionConfig.{name}", getattr(self, name))
        for name in ("min_extent_m", "min_height_m"):
            _checks.positive(f"PerceptionConfig.{name}", getattr(self, name), allow_zero=True)
        _checks.choice("PerceptionConfig.representative", self.representative, REPRESENTATIVES)


@dataclass(frozen=True)
class PerceptionResult:
    """detections: the frame's Detections (M).
    is_ground: (N,) bool per scan point.
    labels: (N,) int64 index into detections of the cluster holding each point; -1 for ground, noise,
        points above max_height_m and clusters rejected as not vehicle-like.
    """

    detections: Detections
    is_ground: np.ndarray
    labels: np.ndarray


def perceive(scan: Scan, cfg: PerceptionConfig) -> PerceptionResult:
    """Scan -> ground mask, clusters, one detection per vehicle-like cluster."""
    if not isinstance(scan, Scan):
        raise TypeError(f"scan: expected Scan, got {type(scan).__name__}")
    if not isinstance(cfg, PerceptionConfig):
        raise TypeError(f"cfg: expected PerceptionConfig, got {type(cfg).__name__}")
    pts = scan.points
    road_z = cfg.ground.ground_z_m
    is_ground = segment_ground(pts, cfg.ground)
    candidates = np.flatnonzero(~is_ground & (pts[:, 2] - road_z <= cfg.max_height_m))
    sub = cluster(pts[candidates], cfg.cluster)
    labels = np.full(len(pts), -1, np.int64)
    n_clusters = int(sub.max()) + 1 if len(sub) else 0
    if n_clusters == 0:
        return PerceptionResult(Detections.empty(), is_ground, labels)

    members = candidates[sub >= 0]
    member_label = sub[sub >= 0]
    # by cluster, then lexicographic within a cluster: fits see their points in a canonical order
    order = np.lexsort((pts[members, 2], pts[members, 1], pts[members, 0], member_label))
    members, member_label = members[order], member_label[order]
    ends = np.cumsum(np.bincount(member_label, minlength=n_clusters))
    starts = ends - np.diff(ends, prepend=0)

    n_points = ends - starts
    # Cheap vectorised tests first: the box fit runs only on clusters that can still pass.
    mz = pts[members, 2]
    top = np.maximum.reduceat(mz, starts) - road_z
    diag = np.hypot(np.maximum.reduceat(pts[members, 0], starts) - np.minimum.reduceat(pts[members, 0], starts),
                    np.maximum.reduceat(pts[members, 1], starts) - np.minimum.reduceat(pts[members, 1], starts))
    keep = np.ones(n_clusters, bool)
    if cfg.vehicle_like:  # the oriented box's longer side is at most the axis-aligned diagonal
        keep = (top >= cfg.min_height_m) & (top <= cfg.max_object_height_m) & (diag >= cfg.min_extent_m)

    z = np.zeros((n_clusters, 2))
    extent = np.zeros((n_clusters, 3))
    extent[:, 2] = top
    provenance = np.full(n_clusters, -1, np.int64)
    median_z = np.zeros(n_clusters)
    represent = REPRESENTATIVES[cfg.representative]
    for k in np.flatnonzero(keep):
        idx = members[starts[k] : ends[k]]
        z[k], length, width = represent(pts[idx, :2])
        extent[k, :2] = (length, width)
        provenance[k] = _plurality_vehicle(scan.source[idx])
        median_z[k] = np.median(mz[starts[k] : ends[k]]) - road_z
        if cfg.complete_one_face and width < cfg.one_face_width_m:
            z[k] = _complete_one_face(z[k], pts[idx, :2], length, width, scan.origin[:2], cfg.size_prior_m)

    if cfg.vehicle_like:
        keep &= (
            (extent[:, 0] >= cfg.min_extent_m)
            & (extent[:, 0] <= cfg.max_length_m)
            & (extent[:, 1] <= cfg.max_width_m)
            & (median_z <= cfg.max_median_height_m)  # a crown above a thin trunk is not a vehicle
        )
    new_index = np.where(keep, np.cumsum(keep) - 1, -1)
    labels[members] = new_index[member_label]
    detections = Detections(z[keep], provenance[keep], n_points[keep], extent[keep])
    return PerceptionResult(detections, is_ground, labels)


def _complete_one_face(centre: np.ndarray, xy: np.ndarray, length: float, width: float, sensor_xy: np.ndarray,
                       prior: tuple[float, float]) -> np.ndarray:
    """Centre of a vehicle of which one face is seen: shifted away from the sensor along the face normal.

    A face longer than the prior width + 0.5 m is a side (hidden depth = prior width), otherwise an end
    (hidden depth = prior length). Without it a car seen from behind is measured at its rear face, half a
    car length short [D].
    """
    if len(xy) >= 2:
        axis = np.linalg.svd(xy - xy.mean(axis=0), full_matrices=False)[2][0]
    else:
        axis = np.array([1.0, 0.0])
    normal = np.array([-axis[1], axis[0]])
    toward = centre - sensor_xy
    if normal @ toward < 0:
        normal = -normal
    depth = prior[1] if length > prior[1] + 0.5 else prior[0]
    return centre + normal * max(depth - width, 0.0) / 2


def _plurality_vehicle(source: np.ndarray) -> int:
    """Most frequent source label if it is a vehicle id (>= 0), else -1; ties go to the smallest label."""
    values, counts = np.unique(source, return_counts=True)
    best = int(values[np.argmax(counts)])
    return best if best >= 0 else -1
