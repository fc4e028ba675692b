"""Occlusion-aware detection probability and occluder shadows, from one scan's range image.

The tracker predicts where each target is; `detection_probability` asks the scan whether the LiDAR could
have seen a vehicle there. It casts the sensor's own rays (the nominal pattern `Scan.azimuths`,
`Scan.elevations` from `Scan.pose` at height `Scan.origin[2]`) at a box of the assumed size standing on the
road at each predicted position, and compares, ray by ray, where the box would have been hit with what the
ray really returned (`Scan.ranges`):

  * expected: the ray crosses the box footprint (2-D slab test per azimuth column) and enters the box
    (3-D) at a height >= min_hit_height_m (lower hits are eaten by ground removal), at a slant range in
    [min_range_m, max_range_m];
  * blocked: it returned from nearer than the box: horizontal return distance < t_hit - margin_m
    (t_hit: horizontal distance at which it would enter the box; the margin absorbs prediction error);
  * clear: anything else - a return from the box itself, from beyond it, or no return at all (inf).

The visible fraction v is the share of the target's width that is seen: of the azimuth columns holding an
expected ray, those holding a clear one. Width rather than rays: a car seen over a nearer car's roof shows
few rays but its whole width and clusters; a sliver at a shadow's edge fails the perception's extent test.
With C clear rays,

    P_D = pd_nominal * clip((v - visible_lo) / (visible_hi - visible_lo), 0, 1) * c   if C >= min_points
    P_D = 0                                                                           otherwise,

with c = clip((C - min_points + 1) / (full_points - min_points + 1), 0, 1) when full_points > min_points (the few
rays of a car at the edge of the beams' reach make a detection only sometimes), else c = 1,

and, with edge_on_top_m > 0, times clip((w_end - edge_on_lo_m) / (edge_on_hi_m - edge_on_lo_m), 0, 1) for a
target seen low (every clear ray enters it below edge_on_top_m), w_end the width across the line of sight of the
columns whose clear ray enters its front or rear face: perception's edge-on test (sensors/perception.py) drops a
low object narrow across the line of sight, or a thin line along it, which is what a far car shows when a nearer
object hides its rear and only its side is seen. Measured at the true positions (highway_benchmark seed 0 and
dense_motorway seed 0, full length, 385 (frame, car) pairs of such cars): the P_D without this term said 0.74,
perception detected 15-21 % of them; 0.84-0.88 against 28-45 % at 0.5-0.8 m of end face seen; right from 1.2 m.

So P_D is 0 out of range, where no beam reaches an object of that height between min_hit_height_m and its
top (a 1.5 m car beyond ~69 m for the HDL-32E at 1.9 m), in a full shadow, and when fewer rays than the
clustering's min_points could land on it.

Uncorrected ego pitch and roll tilt the true rays off the nominal ones the range image is indexed by
(`attitude_tol_deg`, set by `OcclusionConfig.from_lidar`): then a blocked ray whose return may be the
road tells nothing, and a return of any ray of the window lying on the footprint counts as a clear ray
(`_attitude_tolerant`).

Checked against the scan's truth (a car is detectable when >= 5 of the scan's points are on it) on seeded
three-lane traffic: 98 % agreement for the HDL-32E at the true positions, 95 % with 0.5 m prediction
error (tests/test_sensors_occlusion.py). The assumed size matters: a car taller than size_m[2] seen over a
nearer roof shows rays this model does not expect.

Cost: windows wider than max_columns azimuth columns (near targets) are subsampled evenly, each sample
standing for its share, so a call is O(K * max_columns * B); about 0.3-0.5 ms for 30 targets on the
HDL-32E image (2250 x 32).

`shadows` turns the range image into polygons of the ground hidden behind nearer objects, for display.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from roadtrack.sensors import checks, occlusion_jit
from roadtrack.sensors.lidar import LidarConfig, Scan


@dataclass(frozen=True)
class OcclusionConfig:
    """Settings of detection_probability and shadows; lengths in metres, heights above the road."""

    pd_nominal: float = 0.95  # P_D of a fully visible target in range
    min_range_m: float = 1.0  # sensor range limits (slant, along the ray); set from the LidarConfig
    max_range_m: float = 70.0  # (from_lidar does it); defaults are the HDL-32E's
    min_hit_height_m: float = 0.3  # a ray entering the target lower than this does not count (ground removal)
    margin_m: float = 2.0  # a return nearer than the target's entry point by more than this blocks the ray;
    # 2 m, not 1: a predicted position 1 m too far would otherwise see the target's own face as a blocker
    visible_lo: float = 0.1  # visible fraction (of the target's width) at which P_D starts to rise from 0 ...
    visible_hi: float = 0.4  # ... and reaches pd_nominal (linear in between)
    min_points: int = 5  # fewer clear rays than this: no cluster (ClusterConfig.min_points)
    full_points: int = 0  # clear rays at which P_D reaches pd_nominal, rising linearly from min_points - 1;
    # 0 (or <= min_points): a step at min_points. Perception misses most cars of 5-8 points (ground removal,
    # the vehicle screen): measured P_D 0.05 / 0.54-0.61 / 0.83-0.91 / 0.93-0.97 at 5-6 / 7-8 / 9-10 / 11-12
    # points on dense_motorway (2 seeds, 180 s), which 11 fits (scenario key sensor.occlusion_pd_full_points)
    edge_on_top_m: float = 0.0  # a target whose clear rays all enter below this height (perception's min_height_m)
    # is seen low, and perception's edge-on test drops a low object narrow across the line of sight: its P_D
    # ramps with the seen width of its front or rear face from edge_on_lo_m to edge_on_hi_m; 0 = off
    edge_on_lo_m: float = 0.3  # end-face width seen [m] at which the P_D of a low target starts to rise ...
    edge_on_hi_m: float = 1.1  # ... and reaches the rest of the rule's (measured: module docstring)
    attitude_tol_deg: float = 0.0  # elevation error of the true rays (uncorrected ego pitch/roll); 0 = level
    max_columns: int = 32  # azimuth columns sampled per target
    shadow_max_height_m: float = 4.0  # shadows: returns above this (bridges, tree crowns) cast none
    shadow_jump_m: float = 1.5  # shadows: a jump larger than this between adjacent columns starts a new object
    shadow_min_columns: int = 3  # shadows: objects narrower than this many columns cast none (poles, noise)
    shadow_max_vertices: int = 24  # shadows: vertices per polygon edge (near edge, far edge) at most

    def __post_init__(self) -> None:
        for name in ("pd_nominal", "visible_lo", "visible_hi"):
            value = getattr(self, name)
            checks.finite(f"OcclusionConfig.{name}", value)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"OcclusionConfig.{name}: expected 0 <= value <= 1, got {value!r}")
        for name in ("edge_on_top_m", "edge_on_lo_m", "edge_on_hi_m"):
            checks.positive(f"OcclusionConfig.{name}", getattr(self, name), allow_zero=True)
        if not self.edge_on_lo_m < self.edge_on_hi_m:
            raise ValueError(f"OcclusionConfig.edge_on_lo_m: must be < edge_on_hi_m, got {self.edge_on_lo_m!r}")
        if not self.visible_lo < self.visible_hi:
            raise ValueError(f"OcclusionConfig.visible_lo: must be < visible_hi, got {self.visible_lo!r}")
        checks.positive("OcclusionConfig.min_range_m", self.min_range_m, allow_zero=True)
        checks.positive("OcclusionConfig.max_range_m", self.max_range_m)
        if self.min_range_m >= self.max_range_m:
            raise ValueError(f"OcclusionConfig.min_range_m: must be < max_range_m, got {self.min_range_m!r}")
        checks.positive("OcclusionConfig.min_hit_height_m", self.min_hit_height_m, allow_zero=True)
        checks.positive("OcclusionConfig.margin_m", self.margin_m, allow_zero=True)
        checks.positive_int("OcclusionConfig.min_points", self.min_points, allow_zero=True)
        checks.positive_int("OcclusionConfig.full_points", self.full_points, allow_zero=True)
        checks.positive_int("OcclusionConfig.max_columns", self.max_columns)
        checks.positive("OcclusionConfig.attitude_tol_deg", self.attitude_tol_deg, allow_zero=True)
        if self.attitude_tol_deg >= 45.0:
            raise ValueError(f"OcclusionConfig.attitude_tol_deg: expected 0 <= tol < 45, got {self.attitude_tol_deg!r}")
        checks.positive("OcclusionConfig.shadow_max_height_m", self.shadow_max_height_m)
        checks.positive("OcclusionConfig.shadow_jump_m", self.shadow_jump_m)
        checks.positive_int("OcclusionConfig.shadow_min_columns", self.shadow_min_columns)
        checks.positive_int("OcclusionConfig.shadow_max_vertices", self.shadow_max_vertices)
        if self.shadow_max_vertices < 2:
            raise ValueError(f"OcclusionConfig.shadow_max_vertices: expected >= 2, got {self.shadow_max_vertices!r}")

    @staticmethod
    def from_lidar(lidar: LidarConfig, **overrides) -> "OcclusionConfig":
        """Defaults with the sensor's range limits and an attitude tolerance of 3 sigma of its pitch, roll
        and angular jitter; `overrides` are OcclusionConfig fields."""
        if not isinstance(lidar, LidarConfig):
            raise TypeError(f"lidar: expected LidarConfig, got {type(lidar).__name__}")
        tilt = max(lidar.pitch_std_deg, lidar.roll_std_deg)
        fields = {"min_range_m": lidar.min_range_m, "max_range_m": lidar.max_range_m,
                  "attitude_tol_deg": 3.0 * float(np.hypot(tilt, lidar.angle_jitter_deg))}
        fields.update(overrides)
        return OcclusionConfig(**fields)


CAR_BOX_M = (4.6, 1.8, 1.5)
"""The default target box (length, width, height) [m]: a car."""


def detection_probability(
    scan: Scan,
    xy: np.ndarray,
    cfg: OcclusionConfig = OcclusionConfig(),
    *,
    size_m: tuple[float, float, float] | np.ndarray = CAR_BOX_M,
    heading: np.ndarray | None = None,
) -> np.ndarray:
    """(K,) probability in [0, 1] that a vehicle at each predicted position is detected in this scan.

    scan: a Scan with its range image (`ranges` (A, B), `azimuths`, `elevations`, `pose`, `origin`).
    xy: (K, 2) predicted target centres, world frame [m].
    size_m: assumed target (length, width, height) [m], bottom on the road: (3,) for every target or (K, 3)
        one per target (a position's P_D does not depend on the other positions or sizes asked with it).
    heading: (K,) target headings, world frame [rad]; None = each target seen end-on (its long axis along
        the line of sight, as a car ahead or behind in the sensor's lane), the narrowest silhouette.
    See the module docstring for the rule; the counts behind it are `visibility`.
    """
    vis = visibility(scan, xy, cfg, size_m=size_m, heading=heading)
    ramp = np.clip((vis.visible_fraction - cfg.visible_lo) / (cfg.visible_hi - cfg.visible_lo), 0.0, 1.0)
    lo = max(cfg.min_points, 1)
    if cfg.full_points > lo:  # few rays: a detection only sometimes (module docstring)
        ramp = ramp * np.clip((vis.clear_rays - lo + 1) / (cfg.full_points - lo + 1), 0.0, 1.0)
    if cfg.edge_on_top_m > 0:  # seen low: only the front or rear face's width across the line of sight counts
        low = vis.seen_top < cfg.edge_on_top_m
        end = _seen_width(scan, np.asarray(xy, dtype=np.float64).reshape(-1, 2), vis.clear_end_columns)  # (K,) [m]
        ramp = np.where(low, ramp * np.clip((end - cfg.edge_on_lo_m) / (cfg.edge_on_hi_m - cfg.edge_on_lo_m),
                                            0.0, 1.0), ramp)
    return np.where(vis.clear_rays >= lo, cfg.pd_nominal * ramp, 0.0)


def quantised_ranges(scan: Scan, drop: np.ndarray, step_m: float) -> np.ndarray:
    """(A, B) the scan's range image [m] rounded to multiples of step_m [m] (np.rint(ranges / step_m) * step_m),
    with inf at the rays of the points marked by drop (N,) bool (e.g. the returns the perception called ground: a
    ray that returns nothing never blocks). Compiled (occlusion_jit.quantised_ranges), bit for bit numpy's."""
    drop = np.asarray(drop)
    if drop.dtype != bool or drop.shape != (len(scan.points),):
        raise ValueError(f"drop: expected a ({len(scan.points)},) bool mask, got dtype {drop.dtype}, shape {drop.shape}")
    if not (np.isfinite(step_m) and step_m > 0):
        raise ValueError(f"step_m: expected a step > 0 [m], got {step_m!r}")
    if scan.ranges.size == 0:  # no image (a Scan checks its rays against the image only when there is one)
        return scan.ranges.copy()
    return occlusion_jit.quantised_ranges(np.ascontiguousarray(scan.ranges, np.float64), scan.ray, drop,
                                          float(step_m))


def _seen_width(scan: Scan, xy: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(K,) width [m] across the line of sight spanned by ``columns`` (K,) adjacent azimuth columns at each
    target's range: (columns - 1) azimuth steps."""
    d = np.hypot(xy[:, 0] - scan.pose[0], xy[:, 1] - scan.pose[1])
    return np.maximum(columns - 1, 0) * _azimuth_step(scan.azimuths) * d


class Visibility(NamedTuple):
    """What the scan's rays would see of a target at each position: (K,) float64 counts (estimates when a
    window is wider than max_columns columns, which are then subsampled)."""

    rays: np.ndarray  # rays that would hit the target: in range, entering it above min_hit_height_m
    clear_rays: np.ndarray  # of these, the rays not blocked by a nearer return
    columns: np.ndarray  # azimuth columns holding at least one such ray: the target's width in columns
    clear_columns: np.ndarray  # columns holding at least one clear ray: the width seen
    clear_end_columns: np.ndarray  # of these, the columns whose clear ray enters the box's front or rear face
    seen_top: np.ndarray  # highest entry height of a clear ray [m] above the road (0 without one)

    @property
    def visible_fraction(self) -> np.ndarray:
        """(K,) clear_columns / columns: the share of the target's width the sensor sees (0 when columns
        is 0). Width, not rays: a car seen over a nearer car's roof shows few rays but its full width."""
        return np.divide(self.clear_columns, self.columns, out=np.zeros_like(self.columns), where=self.columns > 0)


def visibility(
    scan: Scan,
    xy: np.ndarray,
    cfg: OcclusionConfig = OcclusionConfig(),
    *,
    size_m: tuple[float, float, float] | np.ndarray = CAR_BOX_M,
    heading: np.ndarray | None = None,
) -> Visibility:
    """Rays and columns of this scan that would hit a vehicle at each position, and how many are clear.

    Arguments as detection_probability; see the module docstring for expected, blocked and clear rays.
    """
    if not isinstance(scan, Scan):
        raise TypeError(f"scan: expected Scan, got {type(scan).__name__}")
    if not isinstance(cfg, OcclusionConfig):
        raise TypeError(f"cfg: expected OcclusionConfig, got {type(cfg).__name__}")
    xy = checks.float_array("xy", xy, (None, 2))
    length, width, height = _size(size_m, len(xy))  # floats, or (K, 1) columns: one size per target
    if heading is not None:
        heading = checks.float_array("heading", heading, (len(xy),))
    ranges, azimuths, elevations = _range_image(scan)
    if len(xy) == 0:
        return Visibility(*np.zeros((6, 0)))

    x0, y0, yaw = scan.pose
    h = float(scan.origin[2])

    # Line-of-sight frame of each target: sensor at the origin, target centre at (d, 0).
    dx, dy = xy[:, 0] - x0, xy[:, 1] - y0
    d = np.hypot(dx, dy)
    los = np.arctan2(dy, dx)  # world azimuth of the target centre
    beta = np.zeros(len(xy)) if heading is None else heading - los  # box axis relative to the line of sight
    cb, sb = np.cos(beta), np.sin(beta)

    col, weight, t_in, t_out, crosses, end = _footprint_columns(d, los, cb, sb, length / 2, width / 2, azimuths, yaw,
                                                          cfg.max_columns)  # 2-D: the footprint's columns

    window = _beam_window(elevations, h, height, cfg, t_in, t_out, crosses)  # 3-D: the beams that can hit
    if window is None:
        return Visibility(*np.zeros((6, len(xy))))
    beams, tz_in, cos_e, lo_t, hi_t = window

    # (K, C, b): t_hit = horizontal distance where the ray enters the box; expected when it enters before
    # leaving the footprint, within the height and range limits; clear unless a nearer return blocks it.
    per_target = np.ndim(height) > 0  # sizes (K, 1): tz_in (K, B) and hi_t (K, b) get the column axis
    if cfg.attitude_tol_deg == 0:  # compiled, ray by ray (sensors/occlusion_jit.py)
        counts = occlusion_jit.ray_counts(
            col, t_in, t_out, crosses, end, np.ascontiguousarray(np.atleast_2d(tz_in[..., beams])),
            np.ascontiguousarray(np.atleast_2d(hi_t)), lo_t, cos_e, np.tan(elevations[beams]),
            np.ascontiguousarray(ranges), int(beams.start), float(cfg.margin_m), h)
        return Visibility(*(c * weight for c in counts[:5]), seen_top=counts[5])
    return _tolerant_counts(cfg, ranges, elevations, h, height, per_target, col, weight, t_in, t_out, crosses, end,
                            beams, tz_in, cos_e, lo_t, hi_t)


def _tolerant_counts(cfg: OcclusionConfig, ranges, elevations, h: float, height, per_target: bool, col, weight, t_in,
                     t_out, crosses, end, beams, tz_in, cos_e, lo_t, hi_t) -> Visibility:
    """visibility's ray and column counts in numpy, for a sensor with an attitude tolerance (the compiled
    occlusion_jit.ray_counts has none): the window's (K, C, b) rays, expected and clear (module docstring)."""
    n_az = ranges.shape[0]
    tz_b = tz_in[:, None, beams] if per_target else tz_in[beams]
    hi_t = hi_t[:, None, :] if per_target else hi_t
    t_hit = np.maximum(t_in[..., None], tz_b)
    expected = t_hit <= np.minimum(t_out[..., None], hi_t)
    expected &= t_hit >= lo_t
    expected &= crosses[..., None]
    r = ranges[np.mod(col, n_az), beams]  # (K, C, b) measured slant ranges (only the window's rows gathered)
    r_h = r * cos_e  # horizontal distance of each return
    clear = r_h + cfg.margin_m >= t_hit
    if cfg.attitude_tol_deg > 0:
        expected, clear = _attitude_tolerant(cfg, expected, clear, r, r_h, np.sin(elevations[beams]), h,
                                             height[..., None] if per_target else height, t_in, t_out, crosses)
    clear &= expected
    clear_col = clear.any(axis=2)
    z_hit = h + t_hit * np.tan(elevations[beams])  # (K, C, b) height where each ray enters the box

    return Visibility(
        rays=expected.sum(axis=(1, 2)) * weight,
        clear_rays=clear.sum(axis=(1, 2)) * weight,
        columns=expected.any(axis=2).sum(axis=1) * weight,
        clear_columns=clear_col.sum(axis=1) * weight,
        clear_end_columns=(clear_col & end).sum(axis=1) * weight,
        seen_top=np.where(clear, z_hit, 0.0).max(axis=(1, 2), initial=0.0),
    )


def shadows(scan: Scan, cfg: OcclusionConfig = OcclusionConfig(), *, is_ground: np.ndarray | None = None
            ) -> list[np.ndarray]:
    """Polygons (P, 2) world xy [m] of the regions hidden behind nearer objects, for display.

    Per azimuth column, the nearest return of an object is the smallest horizontal distance among the
    returns with a height in [min_hit_height_m, shadow_max_height_m] (the floor raised by the road's apparent
    tilt, r tan(attitude_tol_deg) at distance r) and, when `is_ground` (N,) bool per scan point is given,
    not labelled ground. Adjacent columns whose nearest objects are within
    shadow_jump_m of each other form one object; an object spanning at least shadow_min_columns columns
    casts a wedge from its near edge out to max_range_m along the same azimuths. Each polygon is the near
    edge (in azimuth order, at most shadow_max_vertices points) followed by the far edge reversed.
    """
    if not isinstance(scan, Scan):
        raise TypeError(f"scan: expected Scan, got {type(scan).__name__}")
    if not isinstance(cfg, OcclusionConfig):
        raise TypeError(f"cfg: expected OcclusionConfig, got {type(cfg).__name__}")
    ranges, azimuths, elevations = _range_image(scan)
    n_az, n_beams = ranges.shape
    h = float(scan.origin[2])
    with np.errstate(invalid="ignore"):  # inf * 0 where no return: filtered by isfinite
        z = h + ranges * np.sin(elevations)  # reported height of each return
        r_h = ranges * np.cos(elevations)  # its horizontal distance
        floor = cfg.min_hit_height_m + r_h * np.tan(np.deg2rad(cfg.attitude_tol_deg))  # above a tilted road
        obj = np.isfinite(ranges) & (z >= floor) & (z <= cfg.shadow_max_height_m)
    if is_ground is not None:
        is_ground = np.asarray(is_ground)
        if is_ground.dtype != bool or is_ground.shape != (len(scan.points),):
            raise ValueError(f"is_ground: expected a bool array of shape ({len(scan.points)},), got "
                             f"{is_ground.dtype} {is_ground.shape}")
        ray = scan.ray[is_ground]
        if np.any(ray < 0):
            raise ValueError("is_ground: marks points without a ray index (scan.ray == -1)")
        ground_ray = np.zeros(n_az * n_beams, bool)
        ground_ray[ray] = True
        obj &= ~ground_ray.reshape(n_az, n_beams)
    near = np.where(obj, r_h, np.inf).min(axis=1)  # (A,)
    near[near >= cfg.max_range_m] = np.inf
    hit = np.isfinite(near)
    if not hit.any():
        return []

    with np.errstate(invalid="ignore"):
        joined = hit & np.roll(hit, 1) & (np.abs(near - np.roll(near, 1)) <= cfg.shadow_jump_m)  # joins a - 1
    if joined.all():  # one object all around the sensor
        starts = np.array([0])
    else:
        starts = np.flatnonzero(hit & ~joined)
    # Walk the columns from a start so that no run wraps past the end of the array.
    order = np.roll(np.arange(n_az), -int(starts[0]))
    run_id = np.cumsum(np.isin(order, starts)) - 1
    keep = hit[order]
    cols, run_id = order[keep], run_id[keep]
    bounds = np.flatnonzero(np.diff(run_id)) + 1
    polygons = []
    c, s = np.cos(scan.pose[2]), np.sin(scan.pose[2])
    for run in np.split(cols, bounds):
        if len(run) < cfg.shadow_min_columns:
            continue
        pick = run[np.unique(np.linspace(0, len(run) - 1, min(len(run), cfg.shadow_max_vertices)).round().astype(int))]
        a = np.concatenate([azimuths[pick], azimuths[pick][::-1]])  # near edge, then far edge back
        r = np.concatenate([near[pick], np.full(len(pick), cfg.max_range_m)])
        u, v = r * np.cos(a), r * np.sin(a)
        polygons.append(np.stack([scan.pose[0] + c * u - s * v, scan.pose[1] + s * u + c * v], -1))
    return polygons


def _beam_window(elevations: np.ndarray, h: float, height, cfg: OcclusionConfig, t_in, t_out, crosses):
    """The contiguous beams that can hit some target of ``height`` [m] (a float, or (K, 1) per target; sensor
    at ``h`` [m]), or None.

    Returns (beams slice, tz_in (B,) or (K, B) horizontal distance where each beam enters [0, height], cos of
    those beams' elevations (b,), lo_t (b,) and hi_t (b,) or (K, b) bounds on a ray's entry point: above
    min_hit_height_m, below the box top, within the sensor's range)."""
    # 3-D: the ray is within [0, height] for horizontal distances [tz_in, tz_out] (per beam); keep the
    # beams that can reach some target at all (upward beams above a low target never do), contiguous: the
    # conditions are monotone in elevation (sensors/occlusion_jit.py)
    tan_e = np.tan(elevations)
    per_target = np.ndim(height) > 0
    half = np.ascontiguousarray((height / 2)[:, 0]) if per_target else np.array([height / 2])
    tz_in, tz_out, b0, b1 = occlusion_jit.beam_window(tan_e, h, half, t_in, t_out, crosses,
                                                      float(np.tan(np.deg2rad(cfg.attitude_tol_deg))))
    if b1 == 0:
        return None
    beams = slice(b0, b1)
    cos_e = np.cos(elevations[beams])
    # bounds on the entry point t_hit: lo_t (b,), hi_t (1 or K, b)
    lo_t, hi_t = occlusion_jit.beam_bounds(tan_e[beams], cos_e, tz_out, b0, h, float(cfg.min_hit_height_m),
                                           float(cfg.min_range_m), float(cfg.max_range_m))
    return beams, (tz_in if per_target else tz_in[0]), cos_e, lo_t, (hi_t if per_target else hi_t[0])


def _footprint_columns(d, los, cb, sb, hl, hw, azimuths: np.ndarray, yaw: float, max_columns: int):
    """The azimuth columns whose rays cross each target's footprint, and where (horizontal distances).

    d, los, cb, sb: (K,) range, world bearing, cos and sin of the box axis relative to the line of sight;
    hl, hw: half length and width [m], floats or (K, 1) per target. Returns col (K, C) unwrapped column indices
    (at most max_columns sampled per target), weight (K,) columns each sample stands for, t_in and t_out (K, C)
    entry and exit distances of each column's ray through the footprint, crosses (K, C) whether it crosses it in front of
    the sensor, end (K, C) whether it enters through the box's front or rear face (not a side)."""
    az0, step = azimuths[0], _azimuth_step(azimuths)
    # Angular window: the footprint corners' bearings relative to the line of sight.
    kx, ky = hl * np.array([1.0, 1.0, -1.0, -1.0]), hw * np.array([1.0, -1.0, 1.0, -1.0])  # (4,) or (K, 4)
    cx = d[:, None] + cb[:, None] * kx - sb[:, None] * ky
    cy = sb[:, None] * kx + cb[:, None] * ky
    rel = np.arctan2(cy, cx)  # (K, 4); > pi/2 in magnitude only when the sensor is (nearly) inside the box
    # the window [centre + lo, centre + hi] in columns (the nearest column when narrower than one), at most
    # max_columns of its columns sampled evenly: col (K, C), weight (K,) columns per sample, valid (K, C)
    col, weight, valid_col = occlusion_jit.footprint_columns(rel, los, float(yaw), float(az0), step, max_columns)

    # 2-D slab intersection of each column's ray with the footprint (box frame: centre at the origin).
    phi = az0 + col * step + yaw - los[:, None]  # ray bearing relative to the line of sight (K, C)
    ux, uy = np.cos(phi), np.sin(phi)
    ox, oy = -d * cb, d * sb  # sensor position in the box frame: R(-beta) @ (-d, 0)
    # (K,) per target, always a fresh writable array: numba compiles a read-only one (a broadcast float's view when
    # K = 1) as another signature, which the warm-up's runs did not reach (a truck's per-target size did)
    hl, hw = (np.array(np.broadcast_to(a, (len(d), 1))[:, 0], dtype=np.float64) for a in (hl, hw))
    # per column: the ray in the box frame, the slabs |x| <= hl and |y| <= hw; crosses: t_in > 0 (else the sensor is
    # inside the footprint); end: the x slab (along the box's axis) entered last, through a front or rear face
    t_in, t_out, crosses, end = occlusion_jit.footprint_slabs(ox, oy, cb, sb, ux, uy, hl, hw, valid_col)
    return col, weight, t_in, t_out, crosses, end


def _attitude_tolerant(cfg, expected, clear, r, r_h, sin_e, h, height, t_in, t_out, crosses):
    """Expected and clear rays (K, C, b) when the true rays may be tilted by up to attitude_tol_deg from the
    nominal ones the range image is indexed by (uncorrected ego pitch and roll). At horizontal distance t
    a return's true height is its reported height +- delta = t tan(tol), so:
      * a blocked expected ray whose return may be the road (reported height < delta + min_hit_height_m)
        tells nothing - the tilted ray met the road before the target - and leaves both counts;
      * any other ray of the window whose return lies in the footprint's distance range
        [t_in - margin_m, t_out] at a height that may be on the target ([min_hit_height_m - delta,
        height + delta]) is a clear ray on it, whatever the nominal geometry expected.
    """
    with np.errstate(invalid="ignore"):  # inf * 0 where no return; those compare False
        z = h + r * sin_e  # reported height of each return
        delta = r_h * np.tan(np.deg2rad(cfg.attitude_tol_deg))
        road = ~clear & (z < delta + cfg.min_hit_height_m)
        on_target = (r_h >= t_in[..., None] - cfg.margin_m) & (r_h <= t_out[..., None])
        on_target &= (z >= cfg.min_hit_height_m - delta) & (z <= height + delta)
    on_target &= crosses[..., None]
    return (expected & ~road) | on_target, clear | on_target


def _slab(o, u, half: float) -> tuple[np.ndarray, np.ndarray]:
    """Ray o + t u (1-D, broadcast) against the slab |x| <= half: t interval [t_in, t_out], empty if
    t_in > t_out; u == 0 gives (-inf, inf) inside the slab and an empty interval outside."""
    ta, tb = (-half - o) / u, (half - o) / u
    t_in, t_out = np.minimum(ta, tb), np.maximum(ta, tb)
    parallel = u == 0
    if np.any(parallel):
        inside = np.broadcast_to(np.abs(o) <= half, np.shape(parallel))
        t_in = np.where(parallel, np.where(inside, -np.inf, np.inf), t_in)
        t_out = np.where(parallel, np.where(inside, np.inf, -np.inf), t_out)
    return t_in, t_out


def _size(size_m, k: int) -> tuple:
    """(length, width, height) [m] as floats from a (3,) size, or as (K, 1) columns from a (K, 3) one."""
    if np.ndim(size_m) == 2:
        size = checks.float_array("size_m", size_m, (k, 3))
        if np.any(size <= 0):
            raise ValueError(f"size_m: expected (length, width, height) > 0 [m], got min {size.min()!r}")
        return size[:, 0:1], size[:, 1:2], size[:, 2:3]
    try:
        size = tuple(float(v) for v in size_m)
    except (TypeError, ValueError):
        raise ValueError(f"size_m: expected (length, width, height) [m], got {size_m!r}") from None
    if len(size) != 3 or not all(np.isfinite(size)) or min(size) <= 0:
        raise ValueError(f"size_m: expected (length, width, height) > 0 [m], got {size_m!r}")
    return size


def _range_image(scan: Scan) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scan's (A, B) range image, (A,) azimuths and (B,) elevations, checked."""
    ranges = np.asarray(scan.ranges, dtype=np.float64)
    if ranges.ndim != 2 or 0 in ranges.shape:
        raise ValueError(f"scan.ranges: expected a non-empty (A, B) range image, got shape {ranges.shape}")
    azimuths = np.asarray(scan.azimuths, dtype=np.float64)
    elevations = np.asarray(scan.elevations, dtype=np.float64)
    if azimuths.shape != ranges.shape[:1] or elevations.shape != ranges.shape[1:]:
        raise ValueError(f"scan.azimuths, scan.elevations: expected shapes {ranges.shape[:1]} and "
                         f"{ranges.shape[1:]}, got {azimuths.shape} and {elevations.shape}")
    return ranges, azimuths, elevations


def _azimuth_step(azimuths: np.ndarray) -> float:
    """Spacing of the (evenly spaced, increasing) azimuth columns [rad]; one column: the full turn."""
    if len(azimuths) == 1:
        return 2 * np.pi
    step = (azimuths[-1] - azimuths[0]) / (len(azimuths) - 1)
    if not step > 0 or abs(azimuths[1] - azimuths[0] - step) > 1e-9 * max(1.0, step):
        raise ValueError("scan.azimuths: expected evenly spaced, increasing azimuths")
    return float(step)
