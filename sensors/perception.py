"""From a LiDAR scan to vehicle detections: ground removal, clustering, split/merge, selection, box fit.

Stages of `perceive` (each switchable in PerceptionConfig; `PerceptionConfig.thesis()` is the plain
pipeline of the thesis: ground, clusters, fixed size and height bounds, L-shape centre, and reproduces
the pipeline before issue 8 exactly):

1. Ground removal (sensors/ground.py), points above `max_height_m` dropped, BEV clustering
   (sensors/clustering.py). `PerceptionResult.cluster_labels` keeps this raw partition.
2. Split (`split_vehicles`): a cluster spanning at least `split_min_width_m` across its axis (the lane
   heading from the road map, else its principal axis; a thinner one is a single surface: a guard rail
   with its posts, a wall) is cut when it is too big for one vehicle (longer side > the length bound,
   shorter side > max_width_m), at its widest gap of at least `min_split_gap_m` along or across the
   axis, or when it has a gap wider than `split_gap_m` along the axis, there; only if both parts keep
   `min_points` points and a side of at least `min_extent_m`. Up to `max_splits` cuts. Flag SPLIT.
3. Merge (`merge_fragments`), in two passes, closest pairs first, each only when the union still fits
   one vehicle (minimum-area rectangle within the length bound for its top and max_width_m):
   a. before selection: objects whose points come within `merge_gap_m` of each other (a corner
      fragment beside its car);
   b. after the fits: an object whose points come within `merge_gap_m` of another's fitted vehicle box
      (a rear face completed to a car and the ring grazing the roof near the car's far end, 4 m away),
      then refitted. Flag MERGED.
4. Selection (`vehicle_like`); the first failing test names the rejection (REJECT_REASONS, in order):
   "too_long" / "too_wide" (with `shape_filter`): the points' principal extents exceed the bounds of
       stage 5 (a guard-rail run, a wall), whatever the height.
   "too_low": the top is below the required top. `min_height_mode="fixed"`: min_height_m. "beams": at
       the object's nearest horizontal range d, the highest beam that still hits a car of `ref_height_m`
       runs at h* = max_b {z_s + d tan(e_b) <= ref_height_m} (z_s the sensor height above the road, e_b
       the scan's beam elevations; "fixed" when the scan has none), and the required top is
       min(min_height_m, h* - height_margin_m): 0.8 m up to 43 m, 0.29 m at 65 m on an HDL-32E at
       1.9 m. With `robust_height` half of the object's `body_bin_m` bins along its axis must reach
       it too, not only one point (a post standing on a guard rail lifts the top, not the rail).
   "too_high": top above max_object_height_m. "too_small": footprint diagonal below min_extent_m.
   "edge_on" (with `shape_filter`): lower than min_height_m (so kept only by the range-aware bound) and
       spanning less than edge_on_width_m across the line of sight, or a line thinner than that within
       grazing_deg of it: a far guard rail seen edge-on. A far car shows its rear or front across the
       line of sight unless a nearer object hides it.
   "high_median": median point height above max_median_height_m (a tree crown).
   "lifted" (with `shape_filter`): a crown over its trunk (the points under the object's mid-height span
       less than lift_trunk_m, those above at least lift_crown_m; a vehicle's body reaches down along its
       whole near face) or alone (lowest point above lift_floor_m).
   "thin_long", "post", "panel" (with `shape_filter`): sensors/boxfit.shape_class of the points (guard
       rails, poles, sign panels) or of the fitted box; their reported centre is the centre of the
       points' box (a panel is never completed like a car's rear).
   "too_small" / "too_long" / "too_wide" after the fit: the points' extents along / across the fitted
       box below min_extent_m, beyond max_length_m (max_truck_length_m for an object whose top reaches
       a size prior longer than that: boxfit's TRUCK) / max_width_m.
   "off_road" (`roi` and a RoadMap): neither the fitted centre nor the points' centroid lies within the
       lane half width + roi_margin_m of the nearest lane centre sample. Last, so its count is the
       number of vehicle-like objects (bushes, ...) only the map removes. Flag OFF_ROAD (rejected only).
5. Measurement per kept object by `fit` (FITS): "vehicle_box" (sensors/boxfit.fit_vehicle_box with the
   lane heading at the centroid as prior when there is a map, the occluded azimuth edges from the range
   image, and its covariance R; flag COMPLETED when it moved the centre beyond the points), or a plain
   representative "lshape_center", "bbox_center", "centroid" (R = DEFAULT_STD_M^2 I, and the old
   one-face completion when complete_one_face).

Each detection's z is computed from the points only; `provenance` (which vehicle made it) comes from the
scan's truth labels and is meant for scoring, never for the tracker.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Callable

import numpy as np

from roadtrack.sensors import checks, perception_jit, perception_reference
from roadtrack.sensors.boxfit import (
    SHAPES,
    BoxFit,
    BoxFitConfig,
    fit_vehicle_box_unchecked,
    fit_vehicle_boxes_unchecked,
    lshape_rectangle,
    min_area_rectangle,
    shape_class,
    side_continuation,
)
from roadtrack.sensors.clustering import ClusterConfig, cluster_unchecked, numbered, scan_line_links_unchecked
from roadtrack.sensors.ground import GroundConfig, segment_ground_unchecked
from roadtrack.sensors.lidar import Scan
from roadtrack.sensors.perception_reference import hull_points_reference, union_fits_reference
from roadtrack.sensors.roi import RoadMap

MERGED: int = 1  # fragments were merged into the detection
SPLIT: int = 2  # it was separated from a larger cluster
COMPLETED: int = 4  # its centre was completed beyond the points by the size prior
OFF_ROAD: int = 8  # (rejected objects only) outside the map's road + margin

DEFAULT_STD_M = 0.5  # isotropic measurement std of the plain representatives (and Detections' default R) [m]

SHAPE_REASONS = tuple(s for s in SHAPES if s != "vehicle")  # ("thin_long", "post", "panel")
REJECT_REASONS = ("too_low", "too_high", "too_small", "edge_on", "high_median", "lifted", *SHAPE_REASONS,
                  "too_long", "too_wide", "off_road")
HEIGHT_MODES = ("beams", "fixed")


@dataclass(frozen=True)
class Detections:
    """M detections of one frame.

    z: (M, 2) float64 measurement (x, y), world frame [m].
    provenance: (M,) int64 vehicle id whose points are the plurality of the cluster, or -1 (clutter).
    n_points: (M,) int64 points in the cluster (0 for synthetic clutter).
    extent: (M, 3) float64 length >= width of the fitted box (the vehicle box's estimated size, or the
        plain representative's box around the points) and height of the cluster's top above the road [m]
        (zeros for synthetic clutter).
    R: (M, 2, 2) float64 measurement covariance of z, world frame [m^2]. Default: DEFAULT_STD_M^2 I.
    centroid: (M, 2) float64 mean (x, y) of the cluster's points [m]. Default: z.
    heading: (M,) float64 long-axis direction of the fitted box [rad] (mod pi). Default: 0.
    flags: (M,) int64 bit set of MERGED, SPLIT, COMPLETED. Default: 0.
    """

    z: np.ndarray
    provenance: np.ndarray
    n_points: np.ndarray
    extent: np.ndarray
    R: np.ndarray | None = None
    centroid: np.ndarray | None = None
    heading: np.ndarray | None = None
    flags: np.ndarray | None = None

    def __post_init__(self) -> None:
        z = checks.float_array("Detections.z", self.z, (None, 2))
        m = len(z)
        object.__setattr__(self, "z", z)
        object.__setattr__(self, "provenance", checks.int_array("Detections.provenance", self.provenance, (m,)))
        object.__setattr__(self, "n_points", checks.int_array("Detections.n_points", self.n_points, (m,)))
        object.__setattr__(self, "extent", checks.float_array("Detections.extent", self.extent, (m, 3)))
        r = np.broadcast_to(DEFAULT_STD_M**2 * np.eye(2), (m, 2, 2)).copy() if self.R is None else self.R
        r = checks.float_array("Detections.R", r, (m, 2, 2))
        if np.any(np.abs(r - r.transpose(0, 2, 1)) > 1e-9 * (1.0 + np.abs(r))) or np.any(r[:, [0, 1], [0, 1]] <= 0):
            raise ValueError("Detections.R: expected symmetric matrices with positive diagonals")
        object.__setattr__(self, "R", r)
        c = z.copy() if self.centroid is None else self.centroid
        object.__setattr__(self, "centroid", checks.float_array("Detections.centroid", c, (m, 2)))
        h = np.zeros(m) if self.heading is None else self.heading
        object.__setattr__(self, "heading", checks.float_array("Detections.heading", h, (m,)))
        f = np.zeros(m, np.int64) if self.flags is None else self.flags
        object.__setattr__(self, "flags", checks.int_array("Detections.flags", f, (m,)))

    def __len__(self) -> int:
        return len(self.z)

    @staticmethod
    def empty() -> "Detections":
        return Detections(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))

    def concat(self, other: "Detections") -> "Detections":
        """self's detections, then other's."""
        return Detections(*(np.concatenate([getattr(self, f), getattr(other, f)]) for f in _DETECTION_FIELDS))


_DETECTION_FIELDS = ("z", "provenance", "n_points", "extent", "R", "centroid", "heading", "flags")


@dataclass(frozen=True)
class Rejected:
    """K objects (clusters after split/merge) that did not become detections, for reporting.

    centre: (K, 2) float64 fitted centre if the object got as far as the fit, else its points' centroid [m].
    reason: (K,) str the first selection test it failed (REJECT_REASONS).
    provenance: (K,) int64 plurality source label of its points (vehicle id, or -1 for static objects).
    n_points: (K,) int64. flags: (K,) int64 MERGED / SPLIT / OFF_ROAD bits.
    """

    centre: np.ndarray
    reason: np.ndarray
    provenance: np.ndarray
    n_points: np.ndarray
    flags: np.ndarray

    def __post_init__(self) -> None:
        c = checks.float_array("Rejected.centre", self.centre, (None, 2))
        k = len(c)
        reason = np.asarray(self.reason, dtype=str).reshape(-1)
        if len(reason) != k:
            raise ValueError(f"Rejected.reason: expected shape ({k},), got {reason.shape}")
        unknown = sorted(set(reason.tolist()) - set(REJECT_REASONS))
        if unknown:
            raise ValueError(f"Rejected.reason: unknown {unknown[0]!r}; valid: {', '.join(REJECT_REASONS)}")
        object.__setattr__(self, "centre", c)
        object.__setattr__(self, "reason", reason)
        object.__setattr__(self, "provenance", checks.int_array("Rejected.provenance", self.provenance, (k,)))
        object.__setattr__(self, "n_points", checks.int_array("Rejected.n_points", self.n_points, (k,)))
        object.__setattr__(self, "flags", checks.int_array("Rejected.flags", self.flags, (k,)))

    def __len__(self) -> int:
        return len(self.centre)

    @staticmethod
    def empty() -> "Rejected":
        return Rejected(np.zeros((0, 2)), np.zeros(0, str), np.zeros(0, np.int64), np.zeros(0, np.int64),
                        np.zeros(0, np.int64))

    def counts(self) -> dict[str, int]:
        """Number of rejected objects per reason, every reason listed (0 when none)."""
        return {r: int(np.sum(self.reason == r)) for r in REJECT_REASONS}


def _centroid(xy: np.ndarray) -> tuple[np.ndarray, float, float]:
    _, length, width = min_area_rectangle(xy)
    return xy.mean(axis=0), length, width


# name -> fit(xy (n, 2)) -> (measurement (2,), footprint length, width); see sensors/boxfit.py
REPRESENTATIVES: dict[str, Callable[[np.ndarray], tuple[np.ndarray, float, float]]] = {
    "bbox_center": min_area_rectangle,  # centre of the minimum-area oriented 2-D box of the cluster
    "lshape_center": lshape_rectangle,  # centre of the L-shape (closeness criterion) box
    "centroid": _centroid,  # mean (x, y) of the cluster's points; extent from the minimum-area box
}
# every measurement a detection can carry: the vehicle box fit, or one of the plain REPRESENTATIVES
FITS: dict[str, str] = {
    "vehicle_box": "sensors.boxfit.fit_vehicle_box: oriented vehicle box, size prior, lane-heading prior",
    **{name: "plain representative, R = DEFAULT_STD_M^2 I" for name in REPRESENTATIVES},
}


@dataclass(frozen=True)
class PerceptionConfig:
    """Pipeline settings; lengths in metres, heights above the road (GroundConfig.ground_z_m).

    Defaults are the full pipeline; `PerceptionConfig.thesis()` is the thesis's plain one.
    """

    ground: GroundConfig = GroundConfig()
    cluster: ClusterConfig = ClusterConfig()
    max_height_m: float = 4.0  # points higher than this (bridges, high signs) are dropped before clustering
    vehicle_like: bool = True  # keep only clusters whose box fits a vehicle (bounds below)
    min_extent_m: float = 1.0  # longer footprint side at least (a far car may show one face only)
    max_length_m: float = 8.0  # longer footprint side at most (cars, vans)
    max_width_m: float = 3.5  # shorter footprint side at most
    min_height_m: float = 0.8  # top above the road at least (thesis 8.2: 0.8-3.5 m); less far away with "beams"
    max_object_height_m: float = 4.2  # ... and at most (trucks are 3.4-4 m)
    max_median_height_m: float = 3.0  # median point height at most (a crown; a far truck's can reach 2.8 m)
    complete_one_face: bool = True  # plain representatives showing one face: centre moved half a car deeper
    one_face_width_m: float = 0.6  # a fitted box narrower than this shows one face only
    size_prior_m: tuple[float, float] = (4.6, 1.8)  # typical car length, width for that completion [m]
    fit: str = "vehicle_box"  # measurement: vehicle_box, or a plain lshape_center, bbox_center, centroid
    boxfit: BoxFitConfig = BoxFitConfig()  # vehicle box fit and shape classes (sensors/boxfit.py)
    roi: bool = True  # reject objects off the road map's lanes (needs a RoadMap)
    roi_margin_m: float = 1.0  # ROI: the lane half width plus this [m]
    min_height_mode: str = "beams"  # beams: range-aware bound from the scan's beam geometry; fixed: min_height_m
    ref_height_m: float = 1.4  # beams: top of the lowest car the bound must keep [m]
    height_margin_m: float = 0.1  # beams: the bound lies this far under that car's highest beam [m]
    robust_height: bool = True  # half the footprint must reach the required top, not one point (a post on a rail)
    body_bin_m: float = 0.5  # robust_height: bins along the object's axis [m]
    shape_filter: bool = True  # reject guard rails, posts, sign panels, far rails seen edge-on, trees by shape
    lift_trunk_m: float = 1.0  # lifted: the points under the mid-height span less than this (a trunk) ...
    lift_crown_m: float = 2.0  # lifted: ... and those above it at least this (a crown)
    lift_floor_m: float = 2.0  # lifted: or its lowest point is higher than this (a crown alone)
    lift_min_top_m: float = 2.2  # lifted over a trunk: only an object whose top reaches this (a crown starts 2.2 m up)
    edge_on_width_m: float = 1.0  # edge_on: a far low object spanning less than this across the line of sight
    grazing_deg: float = 30.0  # edge_on: ... or a line thinner than that within this angle of the line of sight
    max_truck_length_m: float = 20.0  # longer footprint side at most when the top reaches a truck size prior
    split_vehicles: bool = True  # cut clusters holding several vehicles at their widest gap
    split_gap_m: float = 1.2  # a cluster of vehicle size is cut only at a gap along its axis wider than this
    min_split_gap_m: float = 0.3  # a cluster too big for one vehicle is cut at a gap at least this wide [m]
    split_min_width_m: float = 1.0  # only clusters spanning this much across their axis are cut (not rails)
    max_splits: int = 4  # cuts per cluster at most
    merge_fragments: bool = True  # join fragments of one vehicle when the union still fits one
    merge_gap_m: float = 1.0  # fragments this close (points, or points and fitted box) may be joined [m]
    link_max_length_m: float = 6.0  # scan-line links attach noise while the object stays this long (a car) [m]

    def __post_init__(self) -> None:
        if not isinstance(self.ground, GroundConfig):
            raise TypeError(f"PerceptionConfig.ground: expected GroundConfig, got {type(self.ground).__name__}")
        if not isinstance(self.cluster, ClusterConfig):
            raise TypeError(f"PerceptionConfig.cluster: expected ClusterConfig, got {type(self.cluster).__name__}")
        if not isinstance(self.boxfit, BoxFitConfig):
            raise TypeError(f"PerceptionConfig.boxfit: expected BoxFitConfig, got {type(self.boxfit).__name__}")
        for name in ("vehicle_like", "complete_one_face", "roi", "robust_height", "shape_filter",
                     "split_vehicles", "merge_fragments"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"PerceptionConfig.{name}: expected a bool, got {getattr(self, name)!r}")
        if len(self.size_prior_m) != 2 or not all(np.isfinite(self.size_prior_m)) or min(self.size_prior_m) <= 0:
            raise ValueError(f"PerceptionConfig.size_prior_m: expected (length, width) > 0, got {self.size_prior_m!r}")
        for name in ("max_height_m", "max_length_m", "max_width_m", "max_object_height_m", "max_median_height_m",
                     "one_face_width_m", "ref_height_m", "body_bin_m", "edge_on_width_m", "grazing_deg",
                     "lift_trunk_m", "lift_crown_m", "lift_floor_m", "max_truck_length_m", "split_gap_m",
                     "split_min_width_m", "min_split_gap_m", "merge_gap_m", "link_max_length_m"):
            checks.positive(f"PerceptionConfig.{name}", getattr(self, name))
        for name in ("min_extent_m", "min_height_m", "roi_margin_m", "height_margin_m", "lift_min_top_m"):
            checks.positive(f"PerceptionConfig.{name}", getattr(self, name), allow_zero=True)
        checks.positive_int("PerceptionConfig.max_splits", self.max_splits)
        checks.choice("PerceptionConfig.fit", self.fit, FITS)
        if self.min_height_mode not in HEIGHT_MODES:
            raise ValueError(f"PerceptionConfig.min_height_mode: expected one of {', '.join(HEIGHT_MODES)}, "
                             f"got {self.min_height_mode!r}")
        if self.max_truck_length_m < self.max_length_m:
            raise ValueError(f"PerceptionConfig.max_truck_length_m: must be >= max_length_m, "
                             f"got {self.max_truck_length_m!r}")
        if self.split_gap_m < self.min_split_gap_m:
            raise ValueError(f"PerceptionConfig.split_gap_m: must be >= min_split_gap_m, got {self.split_gap_m!r}")
        if self.split_vehicles and self.merge_fragments and self.split_gap_m < self.merge_gap_m:
            raise ValueError(f"PerceptionConfig.split_gap_m: must be >= merge_gap_m (else merging undoes the "
                             f"split), got {self.split_gap_m!r}")

    @staticmethod
    def thesis() -> "PerceptionConfig":
        """The thesis's plain pipeline: plain cell clustering (no scan-line links), no map ROI, fixed 0.8 m height bound, 3.5 m top, 8 m length for every
        object (max_truck_length_m = max_length_m), 2 m median height, no shape test, no split or merge,
        L-shape centre with the one-face completion, and the grid ground segmentation (the pipeline before the
        production-like stack: it reproduces that pipeline's detections exactly)."""
        return PerceptionConfig(
            ground=GroundConfig(method="grid"), cluster=ClusterConfig(scan_line_links=False), max_object_height_m=3.5, max_median_height_m=2.0, fit="lshape_center", roi=False,
            min_height_mode="fixed", robust_height=False, shape_filter=False, max_truck_length_m=8.0,
            split_vehicles=False, merge_fragments=False,
        )

    @property
    def truck_min_top_m(self) -> float:
        """Lowest top [m] from which a size prior longer than max_length_m applies (inf if none does)."""
        return min((p.min_top_m for p in self.boxfit.priors if p.length_m > self.max_length_m), default=np.inf)

    def max_length_for(self, top: np.ndarray) -> np.ndarray:
        """(K,) longest footprint [m] allowed for objects with these tops (K,) [m]: a truck's if tall enough."""
        return np.where(np.asarray(top) >= self.truck_min_top_m, self.max_truck_length_m, self.max_length_m)


@dataclass(frozen=True)
class PerceptionResult:
    """detections: the frame's Detections (M).
    is_ground: (N,) bool per scan point.
    labels: (N,) int64 index into detections of the object holding each point; -1 for ground, noise,
        points above max_height_m and rejected objects.
    rejected: the objects the selection removed, with the reason (Rejected).
    cluster_labels: (N,) int64 raw cluster id of each point from the clusterer, before split, merge and
        selection; -1 for ground, noise and points above max_height_m. Default: all -1.
    """

    detections: Detections
    is_ground: np.ndarray
    labels: np.ndarray
    rejected: Rejected = Rejected.empty()
    cluster_labels: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.cluster_labels is None:
            object.__setattr__(self, "cluster_labels", np.full(len(self.labels), -1, np.int64))


PERCEIVE_STAGES = ("ground", "clustering", "split and merge", "screen", "box fits", "box merge", "ROI and output")
"""The stages perceive reports to its `timer`, in order (a stage that does not run is not reported)."""


def perceive(scan: Scan, cfg: PerceptionConfig, road: RoadMap | None = None,
             timer: Callable[[str], None] | None = None) -> PerceptionResult:
    """Scan -> ground mask, clusters, one detection per vehicle-like object (see the module docstring).

    road: the lane map; with it the box fit gets the lane heading as prior, and with cfg.roi objects off
    the road are rejected. Without it there is no ROI test.
    timer: called with the name of each stage (PERCEIVE_STAGES) as it ends (a benchmark's stopwatch), or None.
    """
    lap = timer if timer is not None else _no_lap
    if not isinstance(scan, Scan):
        raise TypeError(f"scan: expected Scan, got {type(scan).__name__}")
    if not isinstance(cfg, PerceptionConfig):
        raise TypeError(f"cfg: expected PerceptionConfig, got {type(cfg).__name__}")
    if road is not None and not isinstance(road, RoadMap):
        raise TypeError(f"road: expected RoadMap or None, got {type(road).__name__}")
    pts = scan.points
    road_z = cfg.ground.ground_z_m
    is_ground = segment_ground_unchecked(pts, cfg.ground, scan.origin)  # a Scan's points and origin are finite
    lap("ground")
    # the clustering's input: neither ground nor above max_height_m (their indices, and their points)
    candidates, cand_pts = perception_jit.candidate_points(pts, is_ground, float(road_z), float(cfg.max_height_m))
    sub = cluster_unchecked(cand_pts, cfg.cluster)
    cluster_labels = np.full(len(pts), -1, np.int64)
    cluster_labels[candidates] = sub
    if cfg.cluster.scan_line_links and cfg.roi and road is not None and scan.ranges.size and len(sub):
        links = scan_line_links_unchecked(cand_pts, scan.ray[candidates], scan.ranges.shape, scan.origin,
                                          np.isfinite(scan.ranges), cfg.cluster, labels=sub)
        if len(links):  # on the lanes only: a roadside rail or wall is the grazing surface links would grow
            lane = road.on_road(cand_pts[links.reshape(-1), :2], cfg.roi_margin_m).reshape(-1, 2)
            sub = _linked(cand_pts, sub, links[lane.all(axis=1)], cfg)
    labels = np.full(len(pts), -1, np.int64)
    lap("clustering")
    if len(sub) == 0 or sub.max() < 0:
        return PerceptionResult(Detections.empty(), is_ground, labels, Rejected.empty(), cluster_labels)

    objects = _raw_objects(pts, candidates, sub)
    flags = [0] * len(objects)
    st = _stats(pts, objects, road_z, scan.origin[:2], road)
    for step, on in ((_split, cfg.split_vehicles), (_merge, cfg.merge_fragments)):
        if on:
            before = objects
            objects, flags, changed = step(pts, objects, flags, cfg, st)
            if changed:
                st = _restats(pts, objects, before, st, road_z, scan.origin[:2], road)
    lap("split and merge")
    return _select(scan, objects, np.asarray(flags, np.int64), cfg, road, st, is_ground, labels, cluster_labels, lap)


def _no_lap(stage: str) -> None:
    """perceive's timer when it has none."""


# --- objects --------------------------------------------------------------------------------------------

def _linked(pts: np.ndarray, labels: np.ndarray, links: np.ndarray, cfg: PerceptionConfig) -> np.ndarray:
    """Cluster labels (N,) of points (N, 3) (-1 noise) with noise points attached to clusters along scan-line links
    (L, 2) (sensors.clustering.scan_line_links), shortest link first, as long as the object's bird's-eye box stays
    within ``link_max_length_m`` (a car; a truck's length when its top reaches a truck prior): a convoy seen at a
    grazing angle, whose bumper gaps one beam cannot tell from a side, is not chained into long thin objects."""
    n_clusters = int(labels.max()) + 1 if len(labels) else 0
    node = np.where(labels >= 0, labels, n_clusters + np.arange(len(labels)))  # a noise point is a node of its own
    a, b = node[links[:, 0]], node[links[:, 1]]
    # a link attaches a noise point to a cluster (directly or along a chain of noise points), never two clusters to
    # each other (a car and the next one, a rail's pieces: split and merge decide those) and never makes an
    # object of noise points alone
    cross = (a != b) & ((labels[links[:, 0]] < 0) | (labels[links[:, 1]] < 0))
    if not cross.any():
        return labels
    links, a, b = links[cross], a[cross], b[cross]
    used = np.unique(np.concatenate([a, b]))  # the nodes some link touches, with their points' boxes and tops
    touched = np.zeros(n_clusters + len(labels), bool)  # np.isin(node, used) by a table of the node numbers
    touched[used] = True
    sel = np.flatnonzero(touched[node])
    which = np.searchsorted(used, node[sel])
    order = np.argsort(which, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(which[order]) != 0])
    xyz = pts[sel[order]]
    lo, hi = np.minimum.reduceat(xyz[:, :2], starts), np.maximum.reduceat(xyz[:, :2], starts)
    top = np.maximum.reduceat(xyz[:, 2], starts) - cfg.ground.ground_z_m
    p, q = pts[links[:, 0]], pts[links[:, 1]]  # shortest first; ties by the points, not by their order
    length = np.linalg.norm(q - p, axis=1)
    ia, ib = np.searchsorted(used, a), np.searchsorted(used, b)
    pending = np.lexsort((q[:, 2], q[:, 1], q[:, 0], p[:, 2], p[:, 1], p[:, 0], length))
    roots = perception_jit.link_unions(ia, ib, pending, lo, hi, top, used < n_clusters, float(cfg.truck_min_top_m),
                                       float(cfg.max_truck_length_m), float(cfg.link_max_length_m))
    out = np.where(labels >= 0, node, -1)
    out[sel] = used[roots[which]]  # every point of a touched node takes its union's representative node
    return numbered(pts, out, cfg.cluster.min_points)


def _raw_objects(pts: np.ndarray, candidates: np.ndarray, sub: np.ndarray) -> list[np.ndarray]:
    """The clusters as arrays of point indices, each in lexicographic (x, y, z) order so fits see a
    canonical order whatever the scan's point order. candidates (C,) the clustered points' indices into pts
    (N, 3), sub (C,) their cluster labels (-1 noise, at least one >= 0)."""
    # by (label, x) in one float key (monotonic, so equal only for equal x or x closer than its rounding);
    # any tie falls back to the full lexicographic sort
    members, key, counts = perception_jit.member_keys(candidates, sub, pts)
    order = np.argsort(key)
    by_key, distinct = perception_jit.take_if_distinct(key, order, members)
    if distinct:
        return np.split(by_key, np.cumsum(counts)[:-1])
    member_label = sub[sub >= 0]
    x = pts[members, 0]
    tie = np.diff(key[order]) == 0.0
    # runs of equal keys (repeated x): the full lexicographic order within each run
    in_run = np.r_[tie, False] | np.r_[False, tie]
    pos = np.flatnonzero(in_run)
    run = np.cumsum(np.r_[True, ~tie])[pos]  # run number of each position in a run
    sel = order[pos]  # then by position, as lexsort breaks its ties
    order[pos] = sel[np.lexsort((sel, pts[members[sel], 2], pts[members[sel], 1], x[sel], member_label[sel], run))]
    return np.split(members[order], np.cumsum(counts)[:-1])


def _canonical(pts: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The point indices idx in lexicographic (x, y, z) order of their points, equal points in idx's order
    (perception_reference.canonical_reference): one stable sort by x (a group joined from canonical objects is
    a few sorted runs), the full lexicographic order only within runs of equal x."""
    x = pts[idx, 0]
    order = np.argsort(x, kind="stable")
    tie = np.diff(x[order]) == 0.0
    if np.any(tie):
        in_run = np.r_[tie, False] | np.r_[False, tie]
        pos = np.flatnonzero(in_run)
        run = np.cumsum(np.r_[True, ~tie])[pos]  # run number of each position in a run
        sel = order[pos]
        order[pos] = sel[np.lexsort((sel, pts[idx[sel], 2], pts[idx[sel], 1], run))]
    return idx[order]


@dataclass(frozen=True)
class _Stats:
    """Per-object summaries (K objects) of the packed point indices `members` with `starts`."""

    members: np.ndarray  # (sum n,) point indices, object by object
    starts: np.ndarray  # (K,)
    n: np.ndarray  # (K,) points
    top: np.ndarray  # (K,) highest point above the road [m]
    lo: np.ndarray  # (K, 2) axis-aligned footprint corners [m]
    hi: np.ndarray  # (K, 2)
    centroid: np.ndarray  # (K, 2) [m]
    axis: np.ndarray  # (K,) long-axis direction: lane heading at the centroid, else principal axis [rad]
    along: np.ndarray  # (K,) footprint extent along `axis` [m]
    across: np.ndarray  # (K,) ... and across it
    d_min: np.ndarray  # (K,) nearest horizontal range from the sensor [m]
    u: np.ndarray  # (sum n,) each member's coordinate along its object's axis, from the centroid [m]
    xy: np.ndarray  # (sum n, 2) the members' bird's-eye points [m]
    z: np.ndarray  # (sum n,) ... and heights (world z) [m]
    rel: np.ndarray  # (sum n, 2) ... relative to their object's centroid [m]
    principal: np.ndarray  # (K,) principal axis of the points [rad]
    thickness: np.ndarray  # (K,) footprint extent across the principal axis [m]
    p_length: np.ndarray  # (K,) ... and along it


def _stats(pts: np.ndarray, objects: list[np.ndarray], road_z: float, sensor_xy: np.ndarray,
           road: RoadMap | None) -> _Stats:
    n = np.fromiter(map(len, objects), np.int64, len(objects))
    members = np.concatenate(objects)
    starts = np.cumsum(n) - n
    top, lo, hi, centroid, sxx, syy, sxy, d_min, xy, z, rel = perception_jit.object_sums(
        pts, members, starts, n, float(road_z), float(sensor_xy[0]), float(sensor_xy[1]))
    principal = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    cos_p, sin_p = np.cos(principal), np.sin(principal)
    axis = road.heading_at(centroid) if road is not None else principal  # the lane heading at the centroid
    cos_a, sin_a = (np.cos(axis), np.sin(axis)) if road is not None else (cos_p, sin_p)
    # extents across and along the principal axis, u and the extents along and across `axis`: one pass
    thickness, p_length, u, along, across = perception_jit.axis_extents(rel, cos_p, sin_p, cos_a, sin_a, starts, n)
    return _Stats(members, starts, n, top, lo, hi, centroid, axis, along, across, d_min, u, xy, z, rel, principal,
                  thickness, p_length)


def _restats(pts: np.ndarray, objects: list[np.ndarray], before: list[np.ndarray], old: _Stats, road_z: float,
             sensor_xy: np.ndarray, road: RoadMap | None) -> _Stats:
    """_stats(pts, objects, ...) after a split or merge, bit for bit: an object that is one of `before` (the same
    array: the same points in the same order), whose _stats are `old`, keeps its summaries (each depends on its own
    points only; perception_jit.take_runs copies its rows), only the others are computed."""
    index = {id(o): k for k, o in enumerate(before)}
    src = np.fromiter((index.get(id(o), -1) for o in objects), np.int64, len(objects))
    new = np.flatnonzero(src < 0)
    if len(new) == len(objects):
        return _stats(pts, objects, road_z, sensor_xy, road)
    kept = np.flatnonzero(src >= 0)
    if len(new) == 0:
        fresh = old  # (unused rows: every object is kept)
    else:
        fresh = _stats(pts, [objects[k] for k in new], road_z, sensor_xy, road)
    where = np.zeros(len(objects), np.int64)  # the object's index in old (kept) or in fresh (new)
    where[kept], where[new] = src[kept], np.arange(len(new))
    is_new = src < 0
    n = np.where(is_new, fresh.n[np.minimum(where, len(fresh.n) - 1)], old.n[np.maximum(src, 0)])
    starts = np.cumsum(n) - n
    per_object = {}
    for name in ("top", "lo", "hi", "centroid", "axis", "along", "across", "d_min", "principal", "thickness",
                 "p_length"):
        a, b = getattr(old, name), getattr(fresh, name)
        out = np.empty((len(objects),) + a.shape[1:])
        out[kept] = a[src[kept]]
        if len(new):
            out[new] = b
        per_object[name] = out
    members, u, xy, z, rel = perception_jit.take_runs(
        is_new, where, old.starts, fresh.starts, n, starts, old.members, old.u, old.xy, old.z, old.rel,
        fresh.members, fresh.u, fresh.xy, fresh.z, fresh.rel)
    return _Stats(members=members, starts=starts, n=n, u=u, xy=xy, z=z, rel=rel, **per_object)


def _extent(rel: np.ndarray, cx: np.ndarray, cy: np.ndarray, n: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(K,) extent of each object's points rel (sum n, 2) along its unit direction (cx, cy) (K,) each."""
    return perception_jit.extent(rel, np.ascontiguousarray(cx, np.float64), np.ascontiguousarray(cy, np.float64),
                                  starts, n)


# --- split ----------------------------------------------------------------------------------------------

def _split(pts: np.ndarray, objects: list[np.ndarray], flags: list[int], cfg: PerceptionConfig,
           st: _Stats) -> tuple[list[np.ndarray], list[int], bool]:
    """Cut objects holding several vehicles (see the module docstring, stage 2); whether any was cut."""
    too_big = _too_big(np.maximum(st.along, st.across), np.minimum(st.along, st.across), st.top, cfg)
    # a single thin surface (a guard rail, a wall, a rail with its posts) is not cut into vehicle-sized pieces
    wide = st.across >= cfg.split_min_width_m
    gappy = _widest_gaps(st, np.flatnonzero(wide & ~too_big)) > cfg.split_gap_m  # the others are decided already
    candidate = (too_big | gappy) & wide
    out: list[np.ndarray] = []
    out_flags: list[int] = []
    for k, obj in enumerate(objects):
        rows = slice(st.starts[k], st.starts[k] + st.n[k])
        pieces = split_object(obj, st.xy[rows], st.z[rows], st.axis[k], cfg) if candidate[k] else [obj]
        out += pieces
        out_flags += [flags[k] | (SPLIT if len(pieces) > 1 else 0)] * len(pieces)
    return out, out_flags, len(out) > len(objects)


def _widest_gaps(st: _Stats, keys: np.ndarray | None = None) -> np.ndarray:
    """(K,) the widest gap [m] between consecutive members of each object of keys (Q,) (default all; 0 for the
    others) along its axis (st.u), compiled (perception_jit.widest_gaps: each object's u sorted on its own);
    perception_reference.widest_gaps_reference, the former sort of all members by one float key of (object, u),
    where that key cannot tell two u of one of those objects apart (it gives the same gaps where it can)."""
    keys = np.arange(len(st.n)) if keys is None else np.asarray(keys, np.int64)
    gaps, clear = perception_jit.widest_gaps(st.u, st.starts, st.n, float(st.u.min()), float(np.ptp(st.u) + 1.0),
                                             keys)
    if clear:
        return gaps
    ref = perception_reference.widest_gaps_reference(st.u, st.starts, st.n)
    out = np.zeros(len(st.n))
    out[keys] = ref[keys]
    return out


def _too_big(length, width, top, cfg: PerceptionConfig):
    """Whether footprints of these sides (length >= width) [m] and tops [m] exceed one vehicle's bounds."""
    return (length > cfg.max_length_for(top)) | (width > cfg.max_width_m)


def split_object(obj: np.ndarray, xy: np.ndarray, z: np.ndarray, axis: float,
                 cfg: PerceptionConfig) -> list[np.ndarray]:
    """The pieces of the split candidate `obj` (n,) (point indices, canonical order), whose points are xy (n, 2)
    and z (n,) [m]: cut at its best gap along or across `axis` [rad] (np.float64), then each part again, up to
    cfg.max_splits deep (module docstring, stage 2); [obj] when it stays whole. Each piece keeps obj's order.

    perception_reference.split_reference, compiled (perception_jit.split_pieces) but for the projections on the
    axis: those stay numpy's matrix-vector products of the whole object (a compiled x c + y s differs in the last
    bit from the BLAS kernel's fused multiply-add; a point's product does not depend on the rows around it)."""
    c, s = np.cos(axis), np.sin(axis)
    bounds = np.array([cfg.max_length_m, cfg.max_width_m, cfg.truck_min_top_m, cfg.max_truck_length_m])
    u, v = xy @ np.array([c, s]), xy @ np.array([-s, c])
    piece, count = perception_jit.split_pieces(
        u, v, z, np.argsort(u, kind="stable"), np.argsort(v, kind="stable"),
        float(cfg.ground.ground_z_m), bounds, float(cfg.min_split_gap_m), float(cfg.split_gap_m),
        float(cfg.min_extent_m), int(cfg.cluster.min_points), int(cfg.max_splits))
    if count == 1:
        return [obj]
    order = np.argsort(piece, kind="stable")
    return np.split(obj[order], np.cumsum(np.bincount(piece, minlength=count))[:-1])


# --- merge ----------------------------------------------------------------------------------------------

def _merge(pts: np.ndarray, objects: list[np.ndarray], flags: list[int], cfg: PerceptionConfig,
           st: _Stats) -> tuple[list[np.ndarray], list[int], bool]:
    """Join fragments of one vehicle by the gap between their points (see the module docstring, stage
    3a); whether any were joined. perception_reference.merge_reference, compiled."""
    if len(objects) < 2:
        return objects, flags, False
    fits = ~_too_big(np.maximum(st.p_length, st.thickness), np.minimum(st.p_length, st.thickness), st.top, cfg)
    idx = np.flatnonzero(fits)
    if len(idx) < 2:
        return objects, flags, False
    lo, hi = st.lo[idx], st.hi[idx]
    # axis-aligned box gap of every pair, a lower bound of the points' gap
    gap = np.maximum(np.maximum(lo[None] - hi[:, None], lo[:, None] - hi[None]), 0.0)
    box_gap = np.hypot(gap[..., 0], gap[..., 1])
    ii, jj = np.nonzero(np.triu(box_gap <= cfg.merge_gap_m, k=1))
    if len(ii) == 0:
        return objects, flags, False
    pa, pb = idx[ii], idx[jj]  # pa < pb
    d = perception_jit.pair_gaps(st.xy, st.starts, st.n, pa, pb, float(cfg.merge_gap_m))
    near = d <= cfg.merge_gap_m
    order = np.lexsort((pb[near], pa[near], d[near]))  # closest first, ties by the pair
    roots, groups = unite_fitting(pts, objects, st, pa[near][order], pb[near][order], cfg)
    size = np.bincount(roots, minlength=len(objects))
    joined = np.zeros(len(objects), np.int64)
    np.bitwise_or.at(joined, roots, np.asarray(flags, np.int64))
    out, out_flags = [], []
    for i in np.flatnonzero(roots == np.arange(len(objects))):
        merged = size[i] > 1
        out.append(_canonical(pts, groups[i]) if merged else objects[i])
        out_flags.append(int(joined[i]) | (MERGED if merged else 0))
    return out, out_flags, len(out) < len(objects)


UNION_MARGIN_M = 1e-7
"""unite_fitting runs the reference test (scipy's hull) on a union whose rectangle side lies this close to its
bound [m] (or whose minimum-area rectangle is flat or ambiguous): rounding could decide those either way."""


def unite_fitting(pts: np.ndarray, objects: list[np.ndarray], st: _Stats, pa: np.ndarray, pb: np.ndarray,
                  cfg: PerceptionConfig) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """The merge's union loop (perception_reference.unite_reference): the groups of objects pa[p] < pb[p] (P,)
    joined, in order p, when their union's minimum-area rectangle fits one vehicle. Returns the root (K,) of
    every object (the smallest of its group) and, per joined group's root, its point indices (its parts in the
    order they were joined). st: the objects' _stats.

    Compiled (perception_jit.merge_pairs, a monotone-chain hull and rotating calipers) but for a test within
    UNION_MARGIN_M of a bound, or with a flat or ambiguous rectangle: that one is the reference's own."""
    k_all = len(objects)
    parent, head, tail = np.arange(k_all), np.arange(k_all), np.arange(k_all)
    nxt, top = np.full(k_all, -1, np.int64), st.top.copy()
    bounds = np.array([cfg.max_length_m, cfg.max_width_m, cfg.truck_min_top_m, cfg.max_truck_length_m])
    p, decided = 0, -1
    while True:
        p = perception_jit.merge_pairs(st.xy, st.starts, st.n, pa, pb, p, decided, bounds, UNION_MARGIN_M, parent,
                                       head, nxt, tail, top)
        if p >= len(pa):
            break
        ra, rb = (_root_of(parent, int(o)) for o in (pa[p], pb[p]))
        group = {r: np.concatenate([objects[o] for o in _listed(head, nxt, r)]) for r in (ra, rb)}
        hull = {r: np.concatenate([hull_points_reference(pts[objects[o], :2]) for o in _listed(head, nxt, r)])
                for r in (ra, rb)}
        decided = int(union_fits_reference(pts, group, hull, ra, rb, cfg) is not None)
    roots = parent
    while np.any(parent[roots] != roots):
        roots = parent[roots]
    groups = {int(r): np.concatenate([objects[o] for o in _listed(head, nxt, int(r))])
              for r in np.flatnonzero(np.bincount(roots, minlength=k_all) > 1)}
    return roots, groups


def _root_of(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        i = int(parent[i])
    return i


def _listed(head: np.ndarray, nxt: np.ndarray, root: int) -> list[int]:
    """The objects of root's group in order (unite_fitting's lists)."""
    out, o = [], int(head[root])
    while o >= 0:
        out.append(o)
        o = int(nxt[o])
    return out


# --- selection and fit ----------------------------------------------------------------------------------

def _required_top(scan: Scan, d_min: np.ndarray, cfg: PerceptionConfig) -> np.ndarray:
    """(K,) minimum top [m] of an object whose nearest point is d_min (K,) [m] from the sensor."""
    fixed = np.full(len(d_min), cfg.min_height_m)
    if cfg.min_height_mode == "fixed" or len(scan.elevations) == 0:
        return fixed
    z_s = scan.origin[2] - cfg.ground.ground_z_m
    beam_h = z_s + d_min[:, None] * np.tan(scan.elevations)[None, :]  # (K, B) height of each beam at d_min
    reach = np.where(beam_h <= cfg.ref_height_m, beam_h, -np.inf).max(axis=1)
    return np.clip(np.minimum(fixed, reach - cfg.height_margin_m), 0.0, None)


def _select(scan: Scan, objects: list[np.ndarray], flags: np.ndarray, cfg: PerceptionConfig,
            road: RoadMap | None, st: _Stats, is_ground: np.ndarray, labels: np.ndarray,
            cluster_labels: np.ndarray, lap: Callable[[str], None] = _no_lap) -> PerceptionResult:
    """Selection tests, fits, the box merge, ROI; the PerceptionResult. st: the objects' _stats; lap: perceive's
    timer."""
    pts = scan.points
    road_z = cfg.ground.ground_z_m
    boxfit = _boxfit_for(scan, cfg)
    reason, shape_centre = _screen(scan, st, cfg)
    lap("screen")
    pool = _SidePool(pts, is_ground, cfg, boxfit)
    fits = _fit_all(scan, st, np.flatnonzero(reason == ""), road is not None, cfg, boxfit, pool)
    lap("box fits")
    if cfg.merge_fragments and len(fits) > 1:
        before = objects
        objects, flags, reason, fits, shape_centre, merged = _merge_boxes(
            pts, objects, flags, reason, fits, shape_centre, st, cfg)
        if merged:
            st = _restats(pts, objects, before, st, road_z, scan.origin[:2], road)
            fits.update(_fit_all(scan, st, np.asarray(merged, np.int64), road is not None, cfg, boxfit, pool))
        lap("box merge")

    k_all = len(objects)
    centre = st.centroid.copy()
    for k, c in shape_centre.items():
        centre[k] = c
    z = np.zeros((k_all, 2))
    extent = np.zeros((k_all, 3))
    extent[:, 2] = st.top
    R = np.broadcast_to(DEFAULT_STD_M**2 * np.eye(2), (k_all, 2, 2)).copy()
    heading = st.axis.copy()
    provenance = _plurality_vehicle(scan.source[st.members], st.n)
    max_length = cfg.max_length_for(st.top)
    if fits:
        _apply_fits(fits, z, heading, extent, R, centre, flags, reason, max_length, cfg)
    if cfg.roi and road is not None:
        on = road.on_road(np.concatenate([centre, st.centroid]), cfg.roi_margin_m)  # one query: centres, centroids
        off = (reason == "") & ~on[:k_all] & ~on[k_all:]
        reason[off] = "off_road"
        flags[off] |= OFF_ROAD
    keep = reason == ""
    new_index = np.where(keep, np.cumsum(keep) - 1, -1)
    labels[st.members] = np.repeat(new_index, st.n)
    detections = Detections(z[keep], provenance[keep], st.n[keep], extent[keep], R[keep], st.centroid[keep],
                            np.mod(heading[keep], np.pi), flags[keep] & ~OFF_ROAD)
    rejected = Rejected(centre[~keep], reason[~keep].astype(str), provenance[~keep], st.n[~keep], flags[~keep])
    lap("ROI and output")
    return PerceptionResult(detections, is_ground, labels, rejected, cluster_labels)


def _apply_fits(fits: dict[int, BoxFit], z, heading, extent, R, centre, flags, reason, max_length,
                cfg: PerceptionConfig) -> None:
    """_select's use of the fits, in place on its (K, ...) arrays: object k's measurement z, heading, extent (length,
    width), R and reported centre from fits[k], the COMPLETED flag, and (cfg.vehicle_like) the first failing test of
    the fitted box: its shape (cfg.shape_filter), then "too_small" / "too_long" / "too_wide" by its seen extents
    against min_extent_m, max_length (K,) [m] and max_width_m."""
    keys = np.fromiter(fits.keys(), np.int64, len(fits))
    fl = list(fits.values())
    z[keys] = [f.centre for f in fl]
    centre[keys] = z[keys]
    heading[keys] = [f.heading for f in fl]
    extent[keys, :2] = [(f.length, f.width) for f in fl]
    R[keys] = [f.R for f in fl]
    flags[keys[np.array([f.completed for f in fl], bool)]] |= COMPLETED
    if not cfg.vehicle_like:
        return
    seen = np.array([(f.seen_length, f.seen_width) for f in fl], np.float64).reshape(-1, 2)
    longer, shorter = seen.max(axis=1), seen.min(axis=1)
    shape = np.array([f.shape for f in fl], dtype=object)
    open_ = np.ones(len(fl), bool)  # no test has failed yet
    if cfg.shape_filter:  # by the fitted axis (shape_class uses the principal one)
        open_ = shape == "vehicle"
        reason[keys[~open_]] = shape[~open_]
    for failed, name in ((longer < cfg.min_extent_m, "too_small"), (longer > max_length[keys], "too_long"),
                         (shorter > cfg.max_width_m, "too_wide")):
        reason[keys[open_ & failed]] = name
        open_ &= ~failed


def _above_road(z: np.ndarray, road_z: float) -> np.ndarray:
    """Heights z (M,) [m] above the road at road_z [m]: z - road_z, bit for bit; z itself when road_z is 0 (x - 0.0
    is x for every float, -0.0 included), without a pass over the members."""
    return z if road_z == 0.0 else z - road_z


def _members(st: _Stats, k: int) -> np.ndarray:
    return st.members[st.starts[k] : st.starts[k] + st.n[k]]


def _boxfit_for(scan: Scan, cfg: PerceptionConfig) -> BoxFitConfig:
    """cfg.boxfit with the scan's azimuth spacing (the completion's ray spacing), whatever the beam preset."""
    if len(scan.azimuths) >= 2:
        step = float(np.rad2deg(abs(scan.azimuths[1] - scan.azimuths[0])))
        if step > 0 and abs(step - cfg.boxfit.azimuth_step_deg) > 1e-9:
            return dataclasses.replace(cfg.boxfit, azimuth_step_deg=step)
    return cfg.boxfit


def _screen(scan: Scan, st: _Stats, cfg: PerceptionConfig) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """The selection tests before the fit: reason (K,) object array ("" = passed) and the box centre of
    the objects rejected by shape (they are not completed)."""
    k_all = len(st.n)
    reason = np.full(k_all, "", dtype=object)
    shape_centre: dict[int, np.ndarray] = {}
    if not cfg.vehicle_like:
        return reason, shape_centre
    diag = np.hypot(*(st.hi - st.lo).T)
    required = _required_top(scan, st.d_min, cfg)
    low = st.top < required
    z = _above_road(st.z, cfg.ground.ground_z_m)
    if cfg.robust_height:
        low |= ~_body_reaches(z, st, required, cfg.body_bin_m)
    if cfg.shape_filter:  # too big for a vehicle by the points' principal extents: a guard-rail run, a wall
        length, width = np.maximum(st.p_length, st.thickness), np.minimum(st.p_length, st.thickness)
        reason[length > cfg.max_length_for(st.top)] = "too_long"
        reason[(reason == "") & (width > cfg.max_width_m)] = "too_wide"
    reason[(reason == "") & low] = "too_low"
    reason[(reason == "") & (st.top > cfg.max_object_height_m)] = "too_high"
    reason[(reason == "") & (diag < cfg.min_extent_m)] = "too_small"
    if cfg.shape_filter:  # low and narrow as seen from the sensor: a far rail or wall seen edge-on
        sight = np.arctan2(st.centroid[:, 1] - scan.origin[1], st.centroid[:, 0] - scan.origin[0])
        facing = _extent(st.rel, -np.sin(sight), np.cos(sight), st.n, st.starts)  # across the line of sight
        along_sight = np.abs(np.sin(st.principal - sight)) < np.sin(np.deg2rad(cfg.grazing_deg))
        thin = (facing < cfg.edge_on_width_m) | ((st.thickness < cfg.edge_on_width_m) & along_sight)
        edge_on = thin & (st.top < cfg.min_height_m)
        reason[(reason == "") & edge_on] = "edge_on"
    median = perception_jit.medians(z, st.starts, st.n)
    reason[(reason == "") & (median > cfg.max_median_height_m)] = "high_median"
    if cfg.shape_filter:
        reason[(reason == "") & _lifted(z, st, cfg)] = "lifted"
        for k in np.flatnonzero((reason == "") & _maybe_not_vehicle(st, cfg.boxfit)):
            rows = slice(st.starts[k], st.starts[k] + st.n[k])
            xy = st.xy[rows].copy()  # pts[members, :2] (the members' rows of st.xy)
            shape = shape_class(xy, z[rows], float(st.top[k]), cfg.boxfit)
            if shape != "vehicle":
                reason[k] = shape
                shape_centre[k] = min_area_rectangle(xy)[0]
    return reason, shape_centre


def _maybe_not_vehicle(st: _Stats, cfg: BoxFitConfig, tol: float = 1e-9) -> np.ndarray:
    """(K,) bool: the objects shape_class may not call "vehicle" (the others need not be classified).

    shape_class's footprint rules read the extents along and across the points' principal axis, which
    _stats computes the same way (st.p_length, st.thickness) up to rounding: an object within `tol` [m]
    of a footprint bound, or whose top admits the panel rule, is passed to shape_class itself."""
    length, width = np.maximum(st.p_length, st.thickness), np.minimum(st.p_length, st.thickness)
    thin = (width < cfg.thin_width_m + tol) & (length > cfg.thin_length_m - tol) & (st.top < cfg.thin_max_top_m)
    post = (length < cfg.post_size_m + tol) & (st.top >= cfg.post_min_top_m)
    panel = (st.top >= cfg.panel_min_top_m) & (st.top < cfg.panel_max_top_m)
    return thin | post | panel


def _lifted(z: np.ndarray, st: _Stats, cfg: PerceptionConfig) -> np.ndarray:
    """(K,) bool: a tree crown, over its trunk or alone; z (sum n,) the members' heights above the road [m].

    Over its trunk: the points below the object's mid-height (between its lowest and highest point) span
    less than lift_trunk_m in x and y while those above span at least lift_crown_m. A vehicle's body
    reaches down along its whole near face (a car seen from behind: the lower rear spans its width under
    the roof rings). Only an object whose top reaches lift_min_top_m can be a crown over its trunk: a car whose
    lower body a guard rail or a nearer car hides (a car on the far side of a bend behind the barrier) shows a
    narrow low part under a wide roof too, but its top stays below a crown's lowest lift (2.2 m, the roadside
    trees of testbed/world/roadside.py). Alone: its lowest point is above lift_floor_m. No car reaches that high,
    and a car in front of a vehicle hides it only below the car's roof (the sensor is higher)."""
    bottom, low_span, high_span = perception_jit.lift_spans(z, st.xy, st.top, st.starts, st.n)
    crown_on_trunk = (low_span < cfg.lift_trunk_m) & (high_span >= cfg.lift_crown_m) & (st.top >= cfg.lift_min_top_m)
    return crown_on_trunk | (bottom > cfg.lift_floor_m)


def _body_reaches(z: np.ndarray, st: _Stats, required: np.ndarray, bin_m: float) -> np.ndarray:
    """(K,) bool: in at least half of each object's bin_m bins along its axis, the highest point reaches
    the required top (K,) [m]; z (sum n,) the members' heights above the road [m]. A post on a guard rail
    lifts the rail's top, not its body."""
    return perception_jit.body_reaches(z, st.u, np.ascontiguousarray(required, np.float64), float(bin_m),
                                        st.starts, st.n)


def _merge_boxes(pts, objects, flags, reason, fits, shape_centre, st, cfg):
    """Join a fitted object with another whose points come within merge_gap_m of its fitted (completed)
    vehicle box, when the union still fits one vehicle: a rear face completed to a car and the roof ring
    near the car's far end (4 m from the face, beyond the point-gap merge). Closest pairs first.

    Returns the new objects, flags, reason, fits (merged objects left out: they are refitted),
    shape_centre, and the indices of the merged objects in the new list."""
    keys = np.array(sorted(k for k, f in fits.items() if f.shape == "vehicle"), np.int64)
    if len(keys) < 2:
        return objects, flags, reason, fits, shape_centre, []
    c = np.array([fits[k].centre for k in keys])
    h = np.array([fits[k].heading for k in keys])
    half = np.array([(fits[k].length / 2, fits[k].width / 2) for k in keys])
    reach = np.hypot(half[:, 0], half[:, 1]) + cfg.merge_gap_m
    lo, hi = st.lo[keys], st.hi[keys]
    near = np.hypot(*np.maximum(np.maximum(lo[None] - c[:, None], c[:, None] - hi[None]), 0.0).transpose(2, 0, 1))
    ii, jj = np.nonzero((near <= reach[:, None]) & ~np.eye(len(keys), dtype=bool))
    keep = _box_gap_bound(c[ii], h[ii], half[ii], lo[jj], hi[jj]) <= cfg.merge_gap_m + _BOUND_MARGIN_M
    ii, jj = ii[keep], jj[keep]
    dist: dict[tuple[int, int], float] = {}
    for a, b in zip(ii, jj):
        xy = pts[_members(st, keys[b]), :2] - c[a]
        ca, sa = np.cos(h[a]), np.sin(h[a])
        du = np.maximum(np.abs(xy @ np.array([ca, sa])) - half[a, 0], 0.0)
        dv = np.maximum(np.abs(xy @ np.array([-sa, ca])) - half[a, 1], 0.0)
        d = float(np.min(np.hypot(du, dv)))
        pair = (int(min(keys[a], keys[b])), int(max(keys[a], keys[b])))
        if d <= cfg.merge_gap_m and d < dist.get(pair, np.inf):
            dist[pair] = d
    if not dist:
        return objects, flags, reason, fits, shape_centre, []
    pairs = sorted(dist.items(), key=lambda item: (item[1], item[0]))  # closest first, ties by the pair
    roots, groups = unite_fitting(pts, objects, st, np.array([a for (a, _), _ in pairs], np.int64),
                                  np.array([b for (_, b), _ in pairs], np.int64), cfg)
    size = np.bincount(roots, minlength=len(objects))
    joined = np.zeros(len(objects), np.int64)
    np.bitwise_or.at(joined, roots, np.asarray(flags, np.int64))
    out, out_flags, out_reason, out_fits, out_centre, merged = [], [], [], {}, {}, []
    for k in range(len(objects)):
        if roots[k] != k:
            continue
        new = len(out)
        if size[k] > 1:
            out.append(_canonical(pts, groups[k]))
            out_flags.append(int(joined[k]) | MERGED)
            merged.append(new)
        else:
            out.append(objects[k])
            out_flags.append(int(flags[k]))
            if k in fits:
                out_fits[new] = fits[k]
        out_reason.append(reason[k])
        if k in shape_centre:
            out_centre[new] = shape_centre[k]
    return (out, np.asarray(out_flags, np.int64), np.asarray(out_reason, dtype=object), out_fits, out_centre,
            merged)


_BOUND_MARGIN_M = 1e-6
"""_merge_boxes drops a pair only when the lower bound of its points' distance exceeds merge_gap_m by this [m]
(far more than the rounding of either computation), so the pairs it keeps decide the merge alone."""


def _box_gap_bound(c: np.ndarray, heading: np.ndarray, half: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> np.ndarray:
    """(P,) a lower bound of the distance [m] from any point within the axis-aligned boxes lo, hi (P, 2) [m] to
    the oriented boxes of centres c (P, 2) [m], headings (P,) [rad] and half sides half (P, 2) [m]: the distance
    of the corners' extents along and across each oriented box from its sides (hypot of both, 0 inside)."""
    cos_h, sin_h = np.cos(heading)[:, None], np.sin(heading)[:, None]
    corner_x = np.stack([lo[:, 0], lo[:, 0], hi[:, 0], hi[:, 0]], axis=1) - c[:, :1]  # (P, 4)
    corner_y = np.stack([lo[:, 1], hi[:, 1], lo[:, 1], hi[:, 1]], axis=1) - c[:, 1:]
    gaps = []
    for u, h in ((corner_x * cos_h + corner_y * sin_h, half[:, 0]), (corner_y * cos_h - corner_x * sin_h, half[:, 1])):
        u_lo, u_hi = u.min(axis=1), u.max(axis=1)
        nearest = np.where((u_lo <= 0.0) & (u_hi >= 0.0), 0.0, np.minimum(np.abs(u_lo), np.abs(u_hi)))
        gaps.append(np.maximum(nearest - h, 0.0))
    return np.hypot(gaps[0], gaps[1])


def _fit_all(scan: Scan, st: _Stats, keys: np.ndarray, hinted: bool, cfg: PerceptionConfig,
             boxfit: BoxFitConfig, pool: _SidePool | None = None) -> dict[int, BoxFit]:
    """The fits of objects `keys` (K,); with a map (hinted) the lane heading at the centroid is the prior;
    pool: the points a truck's seen side may continue into. Plain representatives are BoxFits with faces 0."""
    if cfg.fit != "vehicle_box":
        return {int(k): _representative(scan.points[_members(st, k), :2], scan.origin[:2], cfg) for k in keys}
    if len(keys) == 0:
        return {}
    ends = _open_ends(scan, st, keys)
    open_ends = np.array([e if e is not None else (False, False) for e in ends], bool).reshape(-1, 2)
    # the keys' members are their rows of st.xy and st.z (the kernel reads object k's rows from starts[k] on)
    fits = fit_vehicle_boxes_unchecked(st.xy, _above_road(st.z, cfg.ground.ground_z_m), st.starts[keys], st.n[keys],
                                       scan.origin[:2], st.top[keys], st.axis[keys] if hinted else None, open_ends,
                                       boxfit)
    out = dict(zip(keys.tolist(), fits))
    grown = np.array([p.min_length_m > 0 for p in boxfit.priors])[boxfit.prior_indices(st.top[keys])]  # trucks
    for j in np.flatnonzero(grown):
        k, e = int(keys[j]), ends[j]
        if not (e and any(e)) and pool is not None and len(pool.idx):
            out[k] = _truck_side(scan, _members(st, k), out[k], float(st.top[k]), float(st.axis[k]) if hinted else None,
                                 e, cfg, boxfit, pool)
    return out


class _SidePool:
    """The non-ground points between boxfit.side_min_z_m and max_height_m above the road (those a truck's side
    seen at a grazing angle returns, mostly left as noise or fragments by the clustering), gathered on first use
    (a frame without a truck needs none): idx (P,) indices into pts (N, 3), xy (P, 2) [m], z (P,) above the road."""

    def __init__(self, pts: np.ndarray, is_ground: np.ndarray, cfg: PerceptionConfig, boxfit: BoxFitConfig):
        self._pts, self._is_ground, self._road_z = pts, is_ground, cfg.ground.ground_z_m
        self._bounds = (boxfit.side_min_z_m, cfg.max_height_m)

    @functools.cached_property
    def _pool(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """idx, xy, z in one compiled pass over the points (perception_jit.side_pool)."""
        return perception_jit.side_pool(self._pts, self._is_ground, float(self._road_z), float(self._bounds[0]),
                                        float(self._bounds[1]))

    @property
    def idx(self) -> np.ndarray:
        return self._pool[0]

    @property
    def xy(self) -> np.ndarray:
        return self._pool[1]

    @property
    def z(self) -> np.ndarray:
        return self._pool[2]


def _representative(xy: np.ndarray, sensor_xy: np.ndarray, cfg: PerceptionConfig) -> BoxFit:
    """The plain representative cfg.fit of the points xy (n, 2) [m] (REPRESENTATIVES), R = DEFAULT_STD_M^2 I."""
    centre, length, width = REPRESENTATIVES[cfg.fit](xy)
    completed = False
    if cfg.complete_one_face and width < cfg.one_face_width_m:
        centre = _complete_one_face(centre, xy, length, width, sensor_xy, cfg.size_prior_m)
        completed = True
    return BoxFit(centre=centre, heading=_principal_angle(xy), length=length, width=width, seen_length=length,
                  seen_width=width, faces=0, completed=completed, R=DEFAULT_STD_M**2 * np.eye(2))


def _truck_side(scan: Scan, idx: np.ndarray, f: BoxFit, top: float, hint: float | None,
                open_ends: tuple[bool, bool] | None, cfg: PerceptionConfig, boxfit: BoxFitConfig,
                pool: _SidePool) -> BoxFit:
    """The fit f of the points idx of an object whose class's length is grown from the seen side
    (SizePrior.min_length_m > 0: trucks) and whose azimuth ends are not occluded, refitted with the points of
    `pool` that continue its seen side (boxfit.side_continuation: the clustering leaves a side seen at a
    grazing angle as noise and fragments); f when there are none."""
    pts, road_z = scan.points, cfg.ground.ground_z_m
    more = pool.idx[side_continuation(f, pool.xy, pool.z, scan.origin[:2], max_length_m=cfg.max_truck_length_m,
                                      cfg=boxfit)]
    in_object = np.zeros(len(pts), bool)
    in_object[idx] = True
    more = more[~in_object[more]]  # np.setdiff1d(more, idx): more is sorted and unique (one side each)
    if len(more) == 0:
        return f
    both = _canonical(pts, np.concatenate([idx, more]))
    return fit_vehicle_box_unchecked(pts[both, :2], scan.origin[:2], top_m=top, heading_hint=hint,
                                     open_ends=open_ends, cfg=boxfit, z=pts[both, 2] - road_z)


def _open_ends(scan: Scan, st: _Stats, keys: np.ndarray, margin_m: float = 0.5,
               look: int = 2) -> list[tuple[bool, bool] | None]:
    """Per object of `keys`: whether its (first, last) azimuth edge, counter-clockwise, is bounded by a
    nearer return; None for all without a range image (or with a point of unknown ray).

    sensors/boxfit.open_ends_from_ranges for all objects at once (same rule, same arguments; the tests
    check they agree): perception_reference.open_ends_reference, compiled (perception_jit.open_ends)."""
    if scan.ranges.size == 0 or len(keys) == 0:
        return [None] * len(keys)
    ends, known = perception_jit.open_ends(scan.ray, st.members, st.starts, st.n, np.asarray(keys, np.int64),
                                           np.ascontiguousarray(scan.ranges), float(margin_m), int(look))
    return [(bool(a), bool(b)) for a, b in ends] if known else [None] * len(keys)


def _principal_angle(xy: np.ndarray) -> float:
    if len(xy) < 2:
        return 0.0
    axis = np.linalg.svd(xy - xy.mean(axis=0), full_matrices=False)[2][0]
    return float(np.arctan2(axis[1], axis[0]))


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


def _plurality_vehicle(source: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(K,) per object (its n (K,) consecutive entries of source): the most frequent source label if it is a
    vehicle id (>= 0), else -1; ties go to the smallest label. Compiled (perception_jit.plurality);
    perception_reference.plurality_reference is the former numpy code."""
    return perception_jit.plurality(np.ascontiguousarray(source, np.int64), np.cumsum(n) - n, np.asarray(n, np.int64))
