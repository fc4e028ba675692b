"""Oriented 2-D rectangles around a cluster's bird's-eye-view points, and the vehicle box fit.

Rectangle fits take xy (n, 2) [m] and return (centre (2,), length, width) with length >= width [m]:
  min_area_rectangle: minimum-area enclosing rectangle (rotating calipers over the convex-hull edges).
      Exact for a fully seen footprint, but for an L-shaped view (two faces of a car) a rectangle along
      the L's hypotenuse has the same area as the true one, so the fit can tilt and shift the centre.
  lshape_rectangle: L-shape fit with the closeness criterion of Zhang et al., "Efficient L-shape fitting
      for vehicle detection using laser scanners", IEEE IV 2017: the heading maximising
      sum_i 1 / max(d_i, d0), d_i the distance of point i to the nearest rectangle edge, searched on a
      `step_deg` grid over [0, 90) deg; the rectangle is then the enclosing one at that heading.

fit_vehicle_box: the centre of the whole vehicle of which a LiDAR sees one or two faces (BoxFit).
  1. Heading. The closeness criterion above (on at most `max_points` evenly spaced points), then a
     total-least-squares line through the points on the edge holding most points (sub-degree, where the
     closeness grid is coarse and flat for a single noisy face). With a road-direction `heading_hint` the
     grid is `step_deg` within `hint_window_deg` of the hint (vehicles on a road are aligned with it; a
     lane change is a few degrees) and `coarse_step_deg` outside, where an orientation must score
     `hint_override` times better to win (a vehicle clearly turned). The long axis is the one nearer the
     hint, unless the extent across it exceeds the prior width + 1 m (a vehicle across the road). Without
     a hint: a coarse grid over 90 deg refined at `step_deg`, and the long axis is along the face holding
     most points if that face is longer than the prior width + 3 std + 0.1 m (car 2.35 m, truck 2.75 m),
     else across it (the face is an end; a side cut short by an occluder is then mistaken for one: give
     a hint). Fewer than 3 points: the hint, else the line of sight.
  2. Seen faces, from geometry, never from face length. In the box frame (u along the heading, v across)
     the points span [u0, u1] x [v0, v1]. The end toward the sensor is a true edge when the sensor lies
     beyond it along u (the nearest surface of a box is its face); the side likewise along v. So a
     2.5 m truck rear seen end-on is an end (it lies across the heading), and a car's rear seen at a
     slight angle (a fitted width of 1 m) is an end too. `faces` counts those edges whose points span
     at least `min_face_m`.
  3. Completion that never shrinks and anchors on true edges. Each of the four extents gets a gap g: how
     far the true edge can lie beyond the outermost point. g = 0 for a seen edge toward the sensor. An
     edge reached along a seen face (the far end of a side, the far corner of a rear) is bounded by the
     ray spacing there: g = gap_factor * |d|^2 * dazimuth / h, |d| the range to that corner and h the
     sensor's distance from the face's line, less |d| tan(gap_heading_tol_deg) for the heading error
     (the spacing of consecutive azimuths along a line seen at grazing incidence; inf when h <= 0 or
     when the next ray would reach beyond the sensor's `max_range_m`). An
     edge with no seen face leading to it, or cut by an azimuth edge occluded by a nearer object
     (`open_ends`, see _open_azimuth_edges), has g = inf, and an occluded edge is no anchor. Along each
     axis the size D = min(max(seen, prior), seen + g_lo + g_hi), and the extension D - seen goes to the
     ends with room, equally when both have it. So a car seen end-on is extended from its rear face away
     from the sensor to the prior length; a fully seen side keeps its length; a half-hidden car is
     extended from its true edge past the occluded one. Priors by the cluster's top (SizePrior): car
     4.6 x 1.8, truck (top >= 2.5 m) 15.4 x 2.5. A class with SizePrior.min_length_m (trucks, 7.5-18.75 m)
     takes its length from what is seen instead: when both ends are bounded each lies half its ray
     spacing d^2 dazimuth / h beyond the points (var spacing^2 / 12), at least min_length_m (less: the
     side is hidden); the prior's length only for an end that nothing bounds (an end seen alone).
     side_continuation finds the points of a side seen at a grazing angle that the clustering left out.
  4. Shape (shape_class): clusters that are not vehicle-shaped are not completed (thin_long and post
     from the footprint, skipped when an end is occluded; panel needs the heights `z`).
  5. Covariance R (2, 2) world [m^2], per box axis (along, across) then rotated by the heading:
       var = floor^2 + range_noise^2 + sigma_D^2 / 4 + split^2 / 12,
     sigma_D the std of the axis' full size (the prior's std when the prior set it, (g_lo + g_hi) /
     sqrt(12) when the points bound it), split = min(g_lo, g_hi, D - seen) the room for where the unseen
     part lies when both ends are open. A heading error sigma_theta (heading_std_deg with a hint,
     free_heading_std_deg without, times sqrt(few_points / n) below few_points points) rotates the
     completion offset (centre - seen centre) and adds |offset|^2 sigma_theta^2 across it. On ray-cast
     cars and trucks at 5-65 m the mean normalised squared centre error e' R^-1 e is 1.4 (cars) and 2.0
     (trucks), for a chi-square(2) mean of 2 (tests/test_sensors_boxfit.py).
  The steps run as one compiled function (sensors/boxfit_jit.py, numba): ~10 us instead of ~200 us a fit.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from roadtrack.sensors import boxfit_jit, checks

_MIN, _MAX = np.minimum.reduce, np.maximum.reduce  # without ndarray.min's wrapper (hot loops)

SHAPES = ("vehicle", "thin_long", "post", "panel")
"""shape_class results; only "vehicle" is completed by fit_vehicle_box."""


HULL_TOL = 1e-9
"""min_area_rectangle's compiled hull hands a point set to qhull when a vertex decision lies within this fraction
of the set's extent of collinear (boxfit_jit.convex_hull)."""


def min_area_rectangle(xy: np.ndarray, compiled_hull: bool = True) -> tuple[np.ndarray, float, float]:
    """Minimum-area enclosing rectangle; collinear or repeated points give one along their principal axis.

    The hull's vertices come from boxfit_jit.convex_hull, qhull's (scipy.spatial.ConvexHull) where that one
    cannot decide within rounding or with compiled_hull=False: the same vertices, counter-clockwise, so the
    same rectangle bit for bit (tests/test_perception_identical.py)."""
    origin = xy.mean(axis=0)
    local = xy - origin  # well conditioned far from the world origin
    try:
        vertices = boxfit_jit.convex_hull(np.ascontiguousarray(local), HULL_TOL) if compiled_hull else ()
        hull = local[vertices if len(vertices) else ConvexHull(local).vertices]
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
    closeness = _closeness(sample, angles, d0_m)
    best = angles[int(np.argmax(closeness))]
    return _enclosing(origin, local, np.array([best]))


def _closeness(local: np.ndarray, angles: np.ndarray, d0_m: float) -> np.ndarray:
    """(E,) closeness score of the points (n, 2) for each rectangle orientation `angles` (E,) [rad]."""
    e = len(angles)
    both = np.concatenate([angles, angles + np.pi / 2])
    u = local @ np.array([np.cos(both), np.sin(both)])  # (n, 2E): along each heading, then across it
    d = np.minimum(_MAX(u, axis=0) - u, u - _MIN(u, axis=0))  # distance to the nearer edge of that axis
    d = np.minimum(d[:, :e], d[:, e:])
    np.maximum(d, d0_m, out=d)
    return np.reciprocal(d, out=d).sum(axis=0)


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


# --- vehicle box fit ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SizePrior:
    """Footprint prior of a vehicle class chosen by the cluster's top above the road [m]."""

    name: str
    min_top_m: float  # the class applies from this top on (the highest class that applies wins)
    length_m: float
    width_m: float
    length_std_m: float
    width_std_m: float
    # > 0: the class's length varies too much for one prior (trucks): where a seen side bounds the far end the
    # length is the seen one (at least this), the prior's only for an end seen alone; 0: the prior's wherever
    # the points allow it (cars)
    min_length_m: float = 0.0

    def __post_init__(self) -> None:
        checks.positive(f"SizePrior.min_top_m ({self.name})", self.min_top_m, allow_zero=True)
        for name in ("length_m", "width_m", "length_std_m", "width_std_m"):
            checks.positive(f"SizePrior.{name} ({self.name})", getattr(self, name))
        checks.positive(f"SizePrior.min_length_m ({self.name})", self.min_length_m, allow_zero=True)


CAR = SizePrior("car", 0.0, 4.6, 1.8, 0.4, 0.15)  # scenario cars 4.2-5.0 x 1.75-2.0, highway-env 5.0 x 2.0
# scenario trucks: 12-18.75 (uniform) x 2.45-2.55, 3.4-4 m high. The class starts at a 2.5 m top: cars are at
# most 1.7 m high, and the HDL-32E's highest beam (+10.67 deg from 1.9 m) sees a truck's top only up to
# 1.9 + 0.19 d m at d m, 2.8 m at 4.8 m.
# Trucks are 7.5 m (a two-axle rigid truck) to 18.75 m long: the 15.4 m prior (mean of the shipped 12-18.75 m) is
# used only when no side is seen (a truck right ahead in the sensor's lane: its length is not observable there).
TRUCK = SizePrior("truck", 2.5, 15.4, 2.5, 1.95, 0.05, min_length_m=7.5)


@dataclass(frozen=True)
class BoxFitConfig:
    """Settings of fit_vehicle_box and shape_class; lengths in metres, angles in degrees."""

    priors: tuple[SizePrior, ...] = (CAR, TRUCK)
    # heading search
    step_deg: float = 2.0  # heading grid near the hint, and of the refinement (then a parabola through the peak)
    coarse_step_deg: float = 6.0  # heading grid away from the hint, and without one
    d0_m: float = 0.02  # closeness floor, about the range noise
    max_points: int = 32  # evenly spaced points that score the headings
    hint_window_deg: float = 20.0
    hint_override: float = 2.0  # a heading outside the window must score this many times better
    # seen faces and completion
    face_tol_m: float = 0.25  # a point this close to an edge of the seen box lies on that face
    min_face_m: float = 0.3  # a face counts (BoxFit.faces) when its points span at least this along it
    open_nbr_deg: float = 1.0  # azimuth neighbourhood that tells the face at an occluded edge
    azimuth_step_deg: float = 0.16  # the sensor's azimuth spacing (HDL-32E)
    max_range_m: float = 70.0  # the sensor's maximum range: no points beyond, so no bound from them there
    gap_factor: float = 1.5  # an edge reached along a face may lie this many ray spacings beyond its last point
    gap_heading_tol_deg: float = 1.5  # heading error allowed for in that spacing (it matters at grazing views)
    side_min_z_m: float = 1.8  # side_continuation: points at least this high above the road (no car reaches it)
    # covariance
    range_noise_m: float = 0.02
    floor_std_m: float = 0.05  # model error of a box footprint (rounded corners, ground cut, fit noise)
    heading_std_deg: float = 1.0  # heading error with a road hint (measured p95: cars 1.0 deg, trucks 0.2 deg)
    free_heading_std_deg: float = 1.5  # ... without
    few_points: int = 30  # below this many points the heading std grows as sqrt(few_points / n)
    # shape classes (shape_class)
    thin_width_m: float = 0.5
    thin_length_m: float = 6.0
    thin_max_top_m: float = 2.0
    post_size_m: float = 0.5
    post_min_top_m: float = 1.0
    panel_gap_m: float = 0.9
    panel_min_top_m: float = 1.8
    panel_max_top_m: float = 2.8
    panel_max_cover: float = 0.3
    panel_bin_m: float = 0.25

    def __post_init__(self) -> None:
        if not self.priors or not all(isinstance(p, SizePrior) for p in self.priors):
            raise ValueError(f"BoxFitConfig.priors: expected a non-empty tuple of SizePrior, got {self.priors!r}")
        for name in ("step_deg", "coarse_step_deg", "d0_m", "hint_window_deg", "face_tol_m", "min_face_m",
                     "open_nbr_deg", "azimuth_step_deg", "max_range_m", "gap_factor", "gap_heading_tol_deg",
                     "side_min_z_m", "heading_std_deg", "free_heading_std_deg", "thin_width_m", "thin_length_m", "thin_max_top_m",
                     "post_size_m", "panel_gap_m", "panel_min_top_m", "panel_max_top_m", "panel_bin_m"):
            checks.positive(f"BoxFitConfig.{name}", getattr(self, name))
        for name in ("range_noise_m", "floor_std_m", "post_min_top_m", "panel_max_cover"):
            checks.positive(f"BoxFitConfig.{name}", getattr(self, name), allow_zero=True)
        checks.positive_int("BoxFitConfig.max_points", self.max_points)
        checks.positive_int("BoxFitConfig.few_points", self.few_points)
        checks.finite("BoxFitConfig.hint_override", self.hint_override)
        if self.hint_override < 1.0:
            raise ValueError(f"BoxFitConfig.hint_override: expected >= 1, got {self.hint_override!r}")

    def prior(self, top_m: float) -> SizePrior:
        """The size prior of the highest class whose min_top_m the top reaches (the first one otherwise)."""
        best = self.priors[0]
        for p in self.priors:
            if top_m >= p.min_top_m and p.min_top_m >= best.min_top_m:
                best = p
        return best

    def prior_indices(self, tops_m: np.ndarray) -> np.ndarray:
        """(K,) int64 index into priors of prior(t) for each of tops_m (K,) [m]: the same rule, on arrays."""
        tops = np.asarray(tops_m, np.float64).reshape(-1)
        best = np.zeros(len(tops), np.int64)
        best_min = np.full(len(tops), self.priors[0].min_top_m)
        for j, p in enumerate(self.priors):
            take = (tops >= p.min_top_m) & (p.min_top_m >= best_min)
            best[take] = j
            best_min[take] = p.min_top_m
        return best


@dataclass(frozen=True)
class BoxFit:
    """One cluster's vehicle box (see fit_vehicle_box); lengths [m], world frame."""

    centre: np.ndarray  # (2,) estimated vehicle centre
    heading: float  # [rad] long axis direction (mod pi), within pi/2 of the hint when there is one
    length: float  # full length >= width (after completion)
    width: float
    seen_length: float  # extent of the points along the heading
    seen_width: float  # across it
    faces: int  # 1 = one face seen, 2 = an L (corner) seen, 0 = no face (too few points to tell)
    completed: bool  # centre moved beyond the points' box by the size prior
    R: np.ndarray  # (2, 2) measurement covariance of `centre` [m^2]
    shape: str = "vehicle"  # shape_class of the cluster (non-vehicles are not completed)
    size_class: str = "car"  # SizePrior.name used
    seen_centre: np.ndarray = field(default_factory=lambda: np.zeros(2))  # (2,) centre of the points' box


def shape_class(xy: np.ndarray, z: np.ndarray | None, top_m: float, cfg: BoxFitConfig = BoxFitConfig()) -> str:
    """Coarse shape of a cluster: "vehicle", "thin_long", "post" or "panel".

    xy (n, 2) bird's-eye points [m]; z (n,) their heights above the road [m] (None: skip the panel rule);
    top_m the cluster's top above the road. Rules, in this order, on the points' principal-axis extents:
      thin_long: width < thin_width_m (0.5), length > thin_length_m (6) and top < thin_max_top_m (2):
          a guard-rail run or a wall (a truck's side is as thin and long, but taller).
      post: length < post_size_m (0.5) and top >= post_min_top_m (1): a pole or a tree trunk.
      panel: a raised object below a truck's height with a gap underneath: top in
          [panel_min_top_m, panel_max_top_m) = [1.8, 2.8) and, along the principal axis in
          panel_bin_m (0.25 m) bins, the points lower than panel_gap_m (0.9 m) cover at most
          panel_max_cover (30 %) of the bins the higher points cover (they may be thin posts). A sign
          panel lifted 1 m (top 2.2 m). A car never returns points at 1.8 m or above (its top is at most
          1.7 m; the HDL-32E's level beam runs at 1.9 m); a truck's seen top is above 2.8 m beyond 4.8 m,
          and nearer it shows its lower body.
      vehicle: anything else (clusters that are too small or too large for a vehicle are left to the
          caller's size tests).
    """
    xy = checks.float_array("xy", xy, (None, 2))
    checks.finite("top_m", top_m)
    if z is not None:
        z = checks.float_array("z", z, (len(xy),))
    if len(xy) == 0:
        return "vehicle"
    local = xy - xy.mean(axis=0)
    cov = local.T @ local
    axis = 0.5 * math.atan2(2.0 * cov[0, 1], cov[0, 0] - cov[1, 1])  # principal axis
    c, s = math.cos(axis), math.sin(axis)
    u, v = local @ np.array([c, s]), local @ np.array([-s, c])
    return _shape(u, v, (u.min(), u.max(), v.min(), v.max()), z, top_m, cfg)


def _shape(u: np.ndarray, v: np.ndarray, ext, z: np.ndarray | None, top_m: float, cfg: BoxFitConfig,
           footprint: bool = True) -> str:
    """shape_class rules on the points' coordinates u (n,) along and v (n,) across the cluster's axis,
    ext their extents (u_lo, u_hi, v_lo, v_hi); footprint=False skips the footprint rules (a cluster cut
    by an occluder is smaller than its object)."""
    u_lo, u_hi, v_lo, v_hi = ext
    length, width = max(u_hi - u_lo, v_hi - v_lo), min(u_hi - u_lo, v_hi - v_lo)
    if footprint and width < cfg.thin_width_m and length > cfg.thin_length_m and top_m < cfg.thin_max_top_m:
        return "thin_long"
    if footprint and length < cfg.post_size_m and top_m >= cfg.post_min_top_m:
        return "post"
    if z is not None and cfg.panel_min_top_m <= top_m < cfg.panel_max_top_m:
        along, lo = (u, u_lo) if u_hi - u_lo >= v_hi - v_lo else (v, v_lo)
        low = z < cfg.panel_gap_m
        bins = ((along - lo) / cfg.panel_bin_m).astype(np.int64)
        high_bins = np.unique(bins[~low])
        if len(high_bins) and np.isin(high_bins, bins[low]).mean() <= cfg.panel_max_cover:
            return "panel"
    return "vehicle"


def fit_vehicle_box(xy: np.ndarray, sensor_xy: np.ndarray, *, top_m: float,
                    heading_hint: float | None = None,
                    open_ends: tuple[bool, bool] | None = None,
                    cfg: BoxFitConfig = BoxFitConfig(),
                    z: np.ndarray | None = None) -> BoxFit:
    """Vehicle box of one cluster (see the module docstring for the method).

    xy (n >= 1, 2) the cluster's bird's-eye points, world [m]; sensor_xy (2,) the sensor, world [m];
    top_m the cluster's top above the road [m] (chooses the size prior: a 3.4-4 m top is a truck);
    heading_hint a road direction [rad] (mod pi) or None; open_ends whether the cluster's (first, last)
    edge in counter-clockwise azimuth order, seen from the sensor, is bounded by a nearer object (see
    open_ends_from_ranges) or None; z (n,) optional point heights above the road [m] for the panel test
    of shape_class (without it only the footprint rules apply; an addition to the issue-8 contract).
    Clusters that are not vehicle-shaped keep the centre of their points' box (not completed).
    """
    xy = checks.float_array("xy", xy, (None, 2))
    if len(xy) == 0:
        raise ValueError("xy: expected at least one point, got 0")
    sensor = checks.float_array("sensor_xy", sensor_xy, (2,))
    checks.finite("top_m", top_m)
    if heading_hint is not None:
        checks.finite("heading_hint", heading_hint)
    if open_ends is None:
        open_ends = (False, False)
    elif len(open_ends) != 2:
        raise ValueError(f"open_ends: expected (bool, bool) or None, got {open_ends!r}")
    if not isinstance(cfg, BoxFitConfig):
        raise TypeError(f"cfg: expected BoxFitConfig, got {type(cfg).__name__}")

    if z is not None:
        z = checks.float_array("z", z, (len(xy),))
    prior = cfg.prior(top_m)
    return _fit_compiled(xy, sensor, float(top_m), prior, heading_hint, open_ends, z, cfg)


def fit_vehicle_box_unchecked(xy: np.ndarray, sensor_xy: np.ndarray, *, top_m: float,
                              heading_hint: float | None = None, open_ends: tuple[bool, bool] | None = None,
                              cfg: BoxFitConfig = BoxFitConfig(), z: np.ndarray | None = None) -> BoxFit:
    """fit_vehicle_box without its argument checks, for callers that already hold float64 arrays of the
    documented shapes, a finite top_m and hint and a BoxFitConfig (sensors/perception.py): the same result."""
    return _fit_compiled(xy, sensor_xy, float(top_m), cfg.prior(top_m), heading_hint,
                         (False, False) if open_ends is None else open_ends, z, cfg)


def _fit_compiled(xy: np.ndarray, sensor: np.ndarray, top_m: float, prior: SizePrior, hint: float | None,
                  open_ends: tuple[bool, bool], z: np.ndarray | None, cfg: BoxFitConfig) -> BoxFit:
    """fit_vehicle_box's steps by the compiled kernel (sensors/boxfit_jit.py) on validated inputs (prior:
    cfg.prior(top_m)): a batch of one."""
    return fit_vehicle_boxes_unchecked(xy, z, _ONE_START, np.array([len(xy)]), sensor, np.array([top_m]),
                                       None if hint is None else np.array([float(hint)]),
                                       np.array([[bool(open_ends[0]), bool(open_ends[1])]]), cfg)[0]


_ONE_START = np.zeros(1, np.int64)


def fit_vehicle_boxes_unchecked(xy: np.ndarray, z: np.ndarray | None, starts: np.ndarray, n: np.ndarray,
                                sensor_xy: np.ndarray, tops: np.ndarray, hints: np.ndarray | None,
                                open_ends: np.ndarray, cfg: BoxFitConfig) -> list[BoxFit]:
    """fit_vehicle_box_unchecked of K objects in one compiled call, for callers holding them packed: object k's
    points are xy[starts[k] : starts[k] + n[k]] (sum n, 2) [m] with heights z (sum n,) above the road [m] (or
    None), its top tops[k] (K,) [m], its heading hint hints[k] (K,) [rad] (hints None: none), its open ends
    open_ends[k] (K, 2) bool. The same BoxFits, bit for bit (the same kernel on the same numbers)."""
    window, n_inner, refine, free = _grids(cfg.step_deg, cfg.coarse_step_deg, cfg.hint_window_deg)
    which = cfg.prior_indices(tops)
    rows = boxfit_jit.fit_many(
        np.ascontiguousarray(xy, np.float64), _NO_Z if z is None else np.ascontiguousarray(z, np.float64),
        np.asarray(starts, np.int64), np.asarray(n, np.int64), np.ascontiguousarray(sensor_xy, np.float64),
        np.asarray(tops, np.float64),
        _prior_table(cfg)[which],
        hints is not None, np.zeros(len(starts)) if hints is None else np.asarray(hints, np.float64),
        open_ends[:, 0].copy(), open_ends[:, 1].copy(), z is not None, window, n_inner, refine, free, _params(cfg))
    return [BoxFit(centre=np.array([r[0], r[1]]), heading=r[2], length=r[3], width=r[4], seen_length=r[5],
                   seen_width=r[6], faces=int(r[7]), completed=bool(r[8]), R=np.array([[r[9], r[10]], [r[10], r[11]]]),
                   shape=boxfit_jit.SHAPE_CODES[int(r[12])], size_class=p.name, seen_centre=np.array([r[13], r[14]]))
            for r, p in zip(rows.tolist(), [cfg.priors[j] for j in which.tolist()])]


_NO_Z = np.zeros(0)


@functools.lru_cache(maxsize=16)
def _prior_table(cfg: BoxFitConfig) -> np.ndarray:
    """(P, 5) per size prior of cfg: length, width, their stds and min_length_m [m] (fit_many's prior rows)."""
    t = np.array([[p.length_m, p.width_m, p.length_std_m, p.width_std_m, p.min_length_m] for p in cfg.priors],
                 np.float64).reshape(-1, 5)
    t.setflags(write=False)
    return t


@functools.lru_cache(maxsize=16)
def _params(cfg: BoxFitConfig) -> np.ndarray:
    p = boxfit_jit.params(cfg)
    p.setflags(write=False)
    return p


@functools.lru_cache(maxsize=8)
def _grids(step_deg: float, coarse_deg: float, window_deg: float) -> tuple[np.ndarray, int, np.ndarray, np.ndarray]:
    """Heading grids [rad]: offsets from a hint (the window at step_deg, then the rest of the quarter turn at
    coarse_deg), how many are in the window, the refinement offsets (+-coarse at step) and the free grid."""
    fine, coarse, half = math.radians(step_deg), math.radians(coarse_deg), math.radians(window_deg)
    inner = np.arange(-half, half + 1e-9, fine)
    window = np.concatenate([inner, np.arange(half + coarse, math.pi / 2 - half, coarse)])
    grids = (window, np.arange(-coarse, coarse + 1e-9, fine), np.arange(0.0, math.pi / 2, coarse))
    for g in grids:
        g.setflags(write=False)
    return grids[0], len(inner), grids[1], grids[2]


def side_continuation(fit: BoxFit, xy: np.ndarray, z: np.ndarray, sensor_xy: np.ndarray, *,
                      max_length_m: float, cfg: BoxFitConfig = BoxFitConfig()) -> np.ndarray:
    """Indices into xy (m, 2) [m] of the points that continue the side of `fit` the sensor sees beyond the
    end of its points: a truck's side seen at a grazing angle returns one azimuth column every 1-3 m, which
    the clustering leaves as noise or 5-point fragments, so the cluster ends 1 m behind its front face.

    A point qualifies when it lies within face_tol_m of the seen side's line, is at least side_min_z_m
    above the road (z (m,) [m]: no car returns from there) and is reached from the cluster's end (away from
    the sensor) by steps of at most the ray spacing there (gap_factor * |d|^2 * dazimuth / h, as the box fit's
    gaps without the heading tolerance, at least face_tol_m). The chain stops where that fails; when it would make the box longer than
    max_length_m [m] it is cut at its widest step (the next vehicle in the lane). Empty when the sensor
    sees no side of the box (it is in line with the side) or fit is not a vehicle.
    """
    c, s = math.cos(fit.heading), math.sin(fit.heading)
    rel = xy - fit.seen_centre
    u, v = rel @ np.array([c, s]), rel @ np.array([-s, c])
    rs = sensor_xy - fit.seen_centre
    us, vs = c * rs[0] + s * rs[1], -s * rs[0] + c * rs[1]
    half_l, half_w = fit.seen_length / 2, fit.seen_width / 2
    if fit.shape != "vehicle" or abs(vs) <= half_w:
        return np.zeros(0, np.int64)
    v_side = math.copysign(half_w, vs)
    h = abs(vs - v_side)
    near = np.flatnonzero((np.abs(v - v_side) <= cfg.face_tol_m) & (z >= cfg.side_min_z_m))
    daz = math.radians(cfg.azimuth_step_deg) * cfg.gap_factor
    out = []
    for sign in (1.0, -1.0):
        end = sign * half_l
        if sign * (us - end) > 0:  # the end facing the sensor: nothing of this vehicle lies beyond it
            continue
        t = sign * (u[near] - end)
        cand = near[t > 0]
        t = t[t > 0]
        order = np.argsort(t, kind="stable")
        cand, t = cand[order], t[order]
        last, n = 0.0, 0
        for tk in t:
            d = math.hypot(end + sign * last - us, v_side - vs)
            link = max(d * d * daz / h, cfg.face_tol_m)
            if tk - last > link:
                break
            last, n = tk, n + 1
        cand, t = cand[:n], t[:n]
        if n and fit.seen_length + t[-1] > max_length_m:
            steps = np.diff(np.r_[0.0, t])
            keep = int(np.argmax(steps))  # points before the widest step
            cand = cand[:keep][fit.seen_length + t[:keep] <= max_length_m]
        out.append(cand)
    return np.sort(np.concatenate(out)) if out else np.zeros(0, np.int64)


def open_ends_from_ranges(ranges: np.ndarray, ray: np.ndarray, *, margin_m: float = 0.5,
                          look: int = 2) -> tuple[bool, bool]:
    """Whether a cluster's (first, last) azimuth edge, counter-clockwise, is bounded by a nearer object.

    ranges (A, B) measured range per ray [m] (inf: no return), row = azimuth index counter-clockwise,
    column = beam; ray (n,) the flat ray index a * B + b of each of the cluster's points. An edge is open
    when, in one of the `look` azimuth columns beyond it, a beam the cluster uses at that edge returns
    more than `margin_m` nearer than the cluster there (the object continues behind an occluder); a
    farther return or none there is the object's own silhouette.
    """
    ranges = np.asarray(ranges, dtype=np.float64)
    if ranges.ndim != 2:
        raise ValueError(f"ranges: expected shape (A, B), got {ranges.shape}")
    a_n, b_n = ranges.shape
    ray = checks.int_array("ray", ray, (None,))
    if len(ray) == 0:
        return (False, False)
    if ray.min() < 0 or ray.max() >= a_n * b_n:
        raise ValueError(f"ray: indices must be in [0, {a_n * b_n}), got [{ray.min()}, {ray.max()}]")
    checks.positive("margin_m", margin_m, allow_zero=True)
    checks.positive_int("look", look)
    az, beam = ray // b_n, ray % b_n
    cols = np.unique(az)
    # first and last column counter-clockwise: the cluster starts after the widest empty arc
    gaps = np.diff(np.r_[cols, cols[0] + a_n])
    k = int(np.argmax(gaps))
    last, first = cols[k], cols[(k + 1) % len(cols)]
    out = []
    for edge, step in ((first, -1), (last, +1)):
        beams = beam[az == edge]
        here = ranges[edge, beams].min()
        nbr = ranges[(edge + step * np.arange(1, look + 1))[:, None] % a_n, beams[None, :]]
        out.append(bool(np.any(nbr < here - margin_m)))
    return out[0], out[1]
