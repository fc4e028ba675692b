"""Synthetic spinning LiDAR (Velodyne-like beam patterns) by ray casting boxes and a flat road.

The scene is cast in the *sensor* frame (origin below the sensor on the road, x along the nominal sensor
yaw): the ray table is then a per-config constant, and float32 ray casting keeps millimetre precision
however far along the highway the car is. Hit points are returned in the world frame, in float64.

Speed: the road z = 0 is intersected analytically (every downward ray, one division); only the rays that
can reach a box (its azimuth sector and elevation band, widened by the angular errors actually drawn) are
tested against it, by a compiled float64 ray / oriented-box slab test (sensors/raycast.py); each ray keeps
the nearer of the two hits. `scan(..., fast=False)` casts every ray at the full open3d mesh (ground +
boxes, float32) instead, the reference: the same points up to float32 precision (~1e-5 m at 70 m) and the
same labels, except for the odd ray grazing a box edge within that precision (tests/test_sensors_lidar.py
bounds how many).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from roadtrack.sensors import checks, raycast
from roadtrack.sensors.open3d_loader import open3d

GROUND: int = -2
"""Source label of points that hit the ground plane (vehicle ids are >= 0, static objects -1)."""

LIDAR_PRESETS: dict[str, dict[str, float]] = {
    # Velodyne HDL-32E: 32 beams, -30.67..+10.67 deg (1.33 deg apart), 0.16 deg at 10 Hz; 70 m kept (spec 100 m).
    "hdl32e": {"n_beams": 32, "elevation_min_deg": -30.67, "elevation_max_deg": 10.67, "azimuth_step_deg": 0.16,
               "max_range_m": 70.0, "ground_half_size_m": 100.0},
    # Velodyne VLP-16 (Puck): 16 beams, -15..+15 deg (2 deg apart), 0.2 deg at 10 Hz, 100 m.
    "vlp16": {"n_beams": 16, "elevation_min_deg": -15.0, "elevation_max_deg": 15.0, "azimuth_step_deg": 0.2,
              "max_range_m": 100.0, "ground_half_size_m": 100.0},
    # Velodyne HDL-64E: 64 beams, -24.9..+2.0 deg, 0.17 deg at 10 Hz (0.18 here: 2000 whole columns), 120 m.
    # Evenly spaced here (0.427 deg); the real sensor has two laser blocks with finer spacing in the upper block.
    "hdl64e": {"n_beams": 64, "elevation_min_deg": -24.9, "elevation_max_deg": 2.0, "azimuth_step_deg": 0.18,
               "max_range_m": 120.0, "ground_half_size_m": 120.0},
    # Velodyne VLS-128 (Alpha Prime): 128 beams, -25..+15 deg, 0.2 deg at 10 Hz, 200 m. Approximated by even
    # spacing (0.315 deg); the real sensor concentrates its beams (0.11 deg) around the horizon.
    "vls128": {"n_beams": 128, "elevation_min_deg": -25.0, "elevation_max_deg": 15.0, "azimuth_step_deg": 0.2,
               "max_range_m": 200.0, "ground_half_size_m": 200.0},
}
"""Beam pattern presets, name -> values of the LidarConfig pattern fields. Elevations are evenly spaced. The road
square reaches at least the max range, so the road does not end inside the sensor's reach."""

# Unit-box corners [x, y, z] with x, y in {-1/2, +1/2} and z in {0, 1}: bottom 0-3, top 4-7.
_CORNERS = np.array(
    [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [-1, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]], np.float64
) / 2.0
# 12 triangles, two per face; box k owns triangles [12 k, 12 k + 12) of the box part of the mesh.
_TRIANGLES = np.array(
    [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
     [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]], np.uint32
)
_N_GROUND_TRIANGLES = 2
_ANGLE_MARGIN = 1e-5  # [rad] widening of every candidate sector: covers float32 ray-casting round-off


@dataclass(frozen=True)
class LidarConfig:
    """Beam pattern and error model; defaults are the HDL-32E (32 beams, -30.67..+10.67 deg, 1-70 m).

    The pattern fields left at None take the values of `preset` (LIDAR_PRESETS); a value given explicitly
    overrides the preset: `LidarConfig(preset="vlp16", max_range_m=80.0)`. After construction every field
    holds its resolved value (so `dataclasses.replace(cfg, preset=...)` keeps the old pattern: build a new
    config to change presets).

    Error model, all drawn from the rng passed to `scan`, in this order: ego attitude (one pitch and one roll
    per scan), angular jitter (azimuth and elevation per ray), dropout (per ray), range noise (per ray).
    Attitude: the rays are cast from the tilted sensor, but the points are reported along the nominal (level)
    rays, as a stack without IMU correction sees them: the road appears tilted by the attitude error.
    Angular jitter likewise: each ray flies off its nominal direction, its range is reported along it.
    """

    PRESET_DEFAULTS: ClassVar[dict] = LIDAR_PRESETS["hdl32e"]  # what the None defaults below resolve to

    preset: str = "hdl32e"  # beam pattern: hdl32e, vlp16, hdl64e (64 beams), vls128 (128 beams)
    n_beams: int | None = None  # None = from the preset
    elevation_min_deg: float | None = None  # lowest beam; None = from the preset
    elevation_max_deg: float | None = None  # highest beam; None = from the preset
    azimuth_step_deg: float | None = None  # None = from the preset (HDL-32E: 0.16 -> 2250 azimuths, 72,000 rays)
    min_range_m: float = 1.0
    max_range_m: float | None = None  # None = from the preset
    mount_height_m: float = 1.9  # sensor height above the road (m)
    range_noise_std_m: float = 0.02  # Gaussian range noise, along the ray
    angle_jitter_deg: float = 0.0  # Gaussian jitter of each ray's azimuth and elevation (deg)
    pitch_std_deg: float = 0.0  # Gaussian ego pitch per scan (deg, ISO 8855: + = nose down), not corrected
    roll_std_deg: float = 0.0  # Gaussian ego roll per scan (deg, + = right side down), not corrected
    dropout: float = 0.02  # probability a ray returns nothing
    ground_half_size_m: float | None = None  # road square around the sensor; None = from the preset (>= max range)

    def __post_init__(self) -> None:
        if not isinstance(self.preset, str) or self.preset not in LIDAR_PRESETS:
            valid = ", ".join(sorted(LIDAR_PRESETS))
            raise ValueError(f"LidarConfig.preset: unknown preset {self.preset!r}; valid: {valid}")
        for name, value in LIDAR_PRESETS[self.preset].items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)
        checks.positive_int("LidarConfig.n_beams", self.n_beams)
        checks.finite("LidarConfig.elevation_min_deg", self.elevation_min_deg)
        checks.finite("LidarConfig.elevation_max_deg", self.elevation_max_deg)
        lo, hi = self.elevation_min_deg, self.elevation_max_deg
        if not (-90.0 < lo <= hi < 90.0):
            raise ValueError(f"LidarConfig.elevation_*_deg: need -90 < min <= max < 90, got {lo!r}, {hi!r}")
        checks.positive("LidarConfig.azimuth_step_deg", self.azimuth_step_deg)
        if self.azimuth_step_deg > 360.0:
            raise ValueError(f"LidarConfig.azimuth_step_deg: expected 0 < step <= 360, got {self.azimuth_step_deg!r}")
        checks.positive("LidarConfig.min_range_m", self.min_range_m, allow_zero=True)
        checks.positive("LidarConfig.max_range_m", self.max_range_m)
        if self.min_range_m >= self.max_range_m:
            raise ValueError(f"LidarConfig.min_range_m: must be < max_range_m, got {self.min_range_m!r}")
        checks.positive("LidarConfig.mount_height_m", self.mount_height_m)
        checks.positive("LidarConfig.range_noise_std_m", self.range_noise_std_m, allow_zero=True)
        for name in ("angle_jitter_deg", "pitch_std_deg", "roll_std_deg"):
            checks.positive(f"LidarConfig.{name}", getattr(self, name), allow_zero=True)
            if getattr(self, name) > 10.0:
                raise ValueError(f"LidarConfig.{name}: expected 0..10 deg, got {getattr(self, name)!r}")
        checks.finite("LidarConfig.dropout", self.dropout)
        if not (0.0 <= self.dropout < 1.0):
            raise ValueError(f"LidarConfig.dropout: expected 0 <= dropout < 1, got {self.dropout!r}")
        checks.positive("LidarConfig.ground_half_size_m", self.ground_half_size_m)

    @property
    def elevations_deg(self) -> np.ndarray:
        """(n_beams,) beam elevations, evenly spaced from min to max [deg]."""
        return np.linspace(self.elevation_min_deg, self.elevation_max_deg, self.n_beams)

    @property
    def azimuths_deg(self) -> np.ndarray:
        """(n_azimuths,) firing azimuths in the sensor frame, 0 along the sensor yaw [deg]."""
        return np.arange(int(np.floor(360.0 / self.azimuth_step_deg + 1e-9))) * self.azimuth_step_deg

    @property
    def n_rays(self) -> int:
        return self.n_beams * len(self.azimuths_deg)


@dataclass(frozen=True)
class Scan:
    """One full turn of the sensor.

    points: (N, 3) float64 hit points, world frame [m].
    source: (N,) int64 truth label per point: id of the box hit (vehicle >= 0, static object -1) or GROUND.
    origin: (3,) float64 sensor position x, y and mount height, world frame [m].
    ranges: (A, B) float64 range image [m]: the measured range of each ray, row = azimuth index (sensor frame,
        0 along the nominal sensor yaw, counter-clockwise), column = beam (lowest elevation first); inf where
        the ray returned nothing (miss, dropout, outside [min_range, max_range]). Default: shape (0, 0).
    ray: (N,) int64 flat ray index a * B + b of each point (-1 = unknown, the default).
    azimuths: (A,) float64 nominal firing azimuths [rad]; elevations: (B,) float64 beam elevations [rad].
    pose: (3,) float64 nominal sensor x, y [m], yaw [rad], world frame: point = origin + R(yaw) u(a, b) * range,
        u the unit vector at azimuth a and elevation b. Default: (origin x, origin y, 0).
    """

    points: np.ndarray
    source: np.ndarray
    origin: np.ndarray
    ranges: np.ndarray | None = None
    ray: np.ndarray | None = None
    azimuths: np.ndarray | None = None
    elevations: np.ndarray | None = None
    pose: np.ndarray | None = None

    def __post_init__(self) -> None:
        pts = checks.float_array("Scan.points", self.points, (None, 3))
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "source", checks.int_array("Scan.source", self.source, (len(pts),)))
        origin = checks.float_array("Scan.origin", self.origin, (3,))
        object.__setattr__(self, "origin", origin)
        ranges = np.zeros((0, 0)) if self.ranges is None else np.asarray(self.ranges, dtype=np.float64)
        if ranges.ndim != 2:
            raise ValueError(f"Scan.ranges: expected shape (A, B), got {ranges.shape}")
        if not np.all(ranges >= 0.0):  # NaN >= 0 is false: one pass for NaN and negative ranges
            raise ValueError("Scan.ranges: expected ranges >= 0 or inf, got NaN or a negative value")
        object.__setattr__(self, "ranges", ranges)
        a, b = ranges.shape
        ray = np.full(len(pts), -1, np.int64) if self.ray is None else self.ray
        ray = checks.int_array("Scan.ray", ray, (len(pts),))
        if np.any(ray < -1) or (ranges.size and np.any(ray >= ranges.size)):
            raise ValueError(f"Scan.ray: expected indices in [-1, {ranges.size}), got {ray.min()}..{ray.max()}")
        object.__setattr__(self, "ray", ray)
        for name, n in (("azimuths", a), ("elevations", b)):
            value = getattr(self, name)
            value = np.zeros(0) if value is None else value
            object.__setattr__(self, name, checks.float_array(f"Scan.{name}", value, (n if ranges.size else None,)))
        pose = np.array([origin[0], origin[1], 0.0]) if self.pose is None else self.pose
        object.__setattr__(self, "pose", checks.float_array("Scan.pose", pose, (3,)))

    def image_only(self, ranges: np.ndarray) -> "Scan":
        """This scan's origin, pose and beam geometry with no points and the range image ``ranges`` (A, B) [m]
        of this scan's shape, >= 0 or inf (e.g. a rounded copy of its own, or inf everywhere: nothing returned).
        Only the new image is checked, the rest was when this scan was made (a Scan's check of a whole turn costs
        about a tenth of a millisecond; the loop makes one such scan a frame for the occlusion-aware P_D)."""
        ranges = np.asarray(ranges, dtype=np.float64)
        if ranges.shape != self.ranges.shape:
            raise ValueError(f"Scan.image_only: expected a range image of shape {self.ranges.shape}, "
                             f"got {ranges.shape}")
        if not np.all(ranges >= 0.0):  # NaN >= 0 is false, as in __post_init__
            raise ValueError("Scan.image_only: expected ranges >= 0 or inf, got NaN or a negative value")
        out = object.__new__(Scan)
        out.__dict__.update(points=np.zeros((0, 3)), source=np.zeros(0, np.int64), origin=self.origin, ranges=ranges,
                            ray=np.zeros(0, np.int64), azimuths=self.azimuths, elevations=self.elevations,
                            pose=self.pose)  # every field, as __init__ sets them (nothing else of this scan)
        return out


def scan(
    cfg: LidarConfig,
    sensor_xy_yaw: np.ndarray,
    boxes: np.ndarray,
    box_ids: np.ndarray,
    rng: np.random.Generator,
    *,
    fast: bool = True,
) -> Scan:
    """Cast one turn of rays at the boxes and the road plane z = 0.

    cfg: beam pattern and error model.
    sensor_xy_yaw: (3,) nominal sensor x, y [m] and yaw [rad], world frame; the sensor is at height
        cfg.mount_height_m and its azimuth 0 points along yaw.
    boxes: (K, 7) [cx, cy, length, width, height, yaw, z_bottom] world frame [m, rad]; sizes > 0.
        Leave out the box of the car carrying the sensor (its roof would return points).
    box_ids: (K,) int64 id per box, vehicles >= 0, static roadside objects -1.
    rng: draws, in this order and only for the errors switched on: the ego pitch and roll (2 normals), the
        azimuth and elevation jitter (2 normals per ray), one dropout uniform and one range-noise normal per
        ray (not per hit), so a change in the scene does not reshuffle the noise of the other rays.
    fast: intersect the road analytically and cast only the rays that can reach a box (see the module
        docstring); False casts every ray at the full mesh (the reference; same result up to float32).
    Returns the Scan: hits with measured range in [min_range_m, max_range_m], in ray order
    (azimuth-major, then beam from lowest elevation), with the range image of the turn.
    """
    if not isinstance(cfg, LidarConfig):
        raise TypeError(f"cfg: expected LidarConfig, got {type(cfg).__name__}")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: expected numpy.random.Generator, got {type(rng).__name__}")
    pose = checks.float_array("sensor_xy_yaw", sensor_xy_yaw, (3,))
    boxes = checks.float_array("boxes", boxes, (None, 7))
    box_ids = checks.int_array("box_ids", box_ids, (len(boxes),))
    if np.any(boxes[:, 2:5] <= 0.0):
        raise ValueError("boxes: length, width and height (columns 2-4) must be > 0")
    if np.any(box_ids < -1):
        raise ValueError("box_ids: must be >= -1 (vehicles >= 0, static objects -1)")

    o3d = open3d()  # also for a box-free scene: a missing open3d fails the same way whatever the traffic
    pat = _pattern(cfg)
    n_rays = len(pat.dirs)
    attitude = _draw_attitude(cfg, rng)
    jitter = np.deg2rad(cfg.angle_jitter_deg) * rng.standard_normal((2, n_rays)) if cfg.angle_jitter_deg > 0 else None
    u_drop = rng.random(n_rays) if cfg.dropout > 0.0 else None
    noise = cfg.range_noise_std_m * rng.standard_normal(n_rays) if cfg.range_noise_std_m > 0.0 else None

    dirs = pat.dirs if attitude is None and jitter is None else _true_directions(pat, attitude, jitter)
    verts = _box_vertices(pose, boxes)
    if fast:
        w_az, w_el = _angular_error_bounds(cfg, attitude, jitter)
        reach = cfg.max_range_m + (max(0.0, -float(noise.min())) if noise is not None else 0.0) + 1e-3
        t, which = _cast_fast(o3d, cfg, pat, dirs, verts, w_az, w_el, reach)
    else:
        t, which = _cast_full(o3d, cfg, pat, dirs, verts)

    c, s = np.cos(pose[2]), np.sin(pose[2])
    empty = np.zeros(0)
    ranges, idx, points, source = raycast.assemble(
        t, which, empty if u_drop is None else u_drop, cfg.dropout, empty if noise is None else noise,
        cfg.min_range_m, cfg.max_range_m, pat.dirs, c, s, pose[0], pose[1], cfg.mount_height_m, box_ids, GROUND)
    ranges = ranges.reshape(len(pat.azimuths), len(pat.elevations))
    origin = np.array([pose[0], pose[1], cfg.mount_height_m])
    return Scan(points=points, source=source, origin=origin, ranges=ranges, ray=idx,
                azimuths=pat.azimuths, elevations=pat.elevations, pose=pose)


class _Pattern(NamedTuple):
    """The nominal rays of a config, sensor frame; R = A * B rays in azimuth-major order (read-only arrays)."""

    azimuths: np.ndarray  # (A,) [rad]
    elevations: np.ndarray  # (B,) [rad], ascending
    az: np.ndarray  # (R,) azimuth of each ray [rad]
    el: np.ndarray  # (R,) elevation of each ray [rad]
    dirs: np.ndarray  # (R, 3) float64 unit directions
    rays32: np.ndarray  # (R, 6) float32 open3d rays: origin (0, 0, mount height), direction
    t_ground: np.ndarray  # (R,) range to the road along each ray, inf when it misses the ground square [m]


@functools.lru_cache(maxsize=8)
def _pattern(cfg: LidarConfig) -> _Pattern:
    azimuths = np.deg2rad(cfg.azimuths_deg)
    elevations = np.deg2rad(cfg.elevations_deg)
    az, el = (g.ravel() for g in np.meshgrid(azimuths, elevations, indexing="ij"))  # like the firing sequence
    dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    pat = _Pattern(azimuths, elevations, az, el, dirs, _rays32(cfg, dirs), _ground_range(cfg, dirs))
    for a in pat:
        a.setflags(write=False)
    return pat


def _rays32(cfg: LidarConfig, dirs: np.ndarray) -> np.ndarray:
    """(R, 6) float32 open3d rays from the sensor, (0, 0, mount height), along `dirs` (R, 3)."""
    rays = np.empty((len(dirs), 6), np.float32)
    rays[:, :3] = (0.0, 0.0, cfg.mount_height_m)
    rays[:, 3:] = dirs
    return rays


def _ground_range(cfg: LidarConfig, dirs: np.ndarray) -> np.ndarray:
    """(R,) distance along unit rays `dirs` (R, 3) from the sensor to the road z = 0 inside the ground square,
    inf for rays that do not point down or land outside it [m]."""
    t = np.full(len(dirs), np.inf)
    down = np.flatnonzero(dirs[:, 2] < 0.0)
    t_down = cfg.mount_height_m / -dirs[down, 2]
    half = cfg.ground_half_size_m
    on_square = (np.abs(t_down * dirs[down, 0]) <= half) & (np.abs(t_down * dirs[down, 1]) <= half)
    t[down[on_square]] = t_down[on_square]
    return t


def _draw_attitude(cfg: LidarConfig, rng: np.random.Generator) -> np.ndarray | None:
    """(3, 3) rotation from the tilted sensor frame to the level one, R_y(pitch) R_x(roll); None when level."""
    if cfg.pitch_std_deg == 0.0 and cfg.roll_std_deg == 0.0:
        return None
    pitch, roll = np.deg2rad([cfg.pitch_std_deg, cfg.roll_std_deg]) * rng.standard_normal(2)
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    r_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])  # + pitch: the forward beams point down
    r_x = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])  # + roll: the right beams point down
    return r_y @ r_x


def _true_directions(pat: _Pattern, attitude: np.ndarray | None, jitter: np.ndarray | None) -> np.ndarray:
    """(R, 3) unit directions the rays actually fly along, level sensor frame: jittered, then tilted."""
    if jitter is None:
        dirs = pat.dirs
    else:
        az, el = pat.az + jitter[0], pat.el + jitter[1]
        dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
    return dirs if attitude is None else dirs @ attitude.T


def _angular_error_bounds(cfg: LidarConfig, attitude: np.ndarray | None,
                          jitter: np.ndarray | None) -> tuple[float, float]:
    """Largest azimuth and elevation difference [rad] between any true ray and its nominal direction.

    The jitter moves azimuth and elevation by at most its largest draw; a rotation by angle delta moves a
    direction by at most delta on the sphere: elevation by <= delta, azimuth by <= asin(sin delta / cos phi)
    at latitude |phi| < 90 deg - delta (the longitude half-width of a spherical cap), any azimuth otherwise.
    """
    j_az = float(np.abs(jitter[0]).max()) if jitter is not None else 0.0
    j_el = float(np.abs(jitter[1]).max()) if jitter is not None else 0.0
    if attitude is None:
        return j_az, j_el
    delta = float(np.arccos(np.clip((np.trace(attitude) - 1.0) / 2.0, -1.0, 1.0)))
    phi = np.deg2rad(max(abs(cfg.elevation_min_deg), abs(cfg.elevation_max_deg))) + j_el
    if delta >= np.pi / 2 - phi:
        return 2 * np.pi, j_el + delta
    return j_az + float(np.arcsin(np.sin(delta) / np.cos(phi))), j_el + delta


def _cast_full(o3d, cfg: LidarConfig, pat: _Pattern, dirs: np.ndarray, verts: np.ndarray):
    """Every ray at the full mesh. Returns t (R,) float64 range to the first hit (inf: none) and which (R,)
    int64 box index hit (-1: the road or nothing)."""
    rays = pat.rays32 if dirs is pat.dirs else _rays32(cfg, dirs)
    vertices, triangles = _mesh(verts, cfg.ground_half_size_m)
    ans = _raycaster(o3d, vertices, triangles).cast_rays(o3d.core.Tensor(rays))
    t = ans["t_hit"].numpy().astype(np.float64)
    prim = ans["primitive_ids"].numpy().astype(np.int64)
    on_box = np.isfinite(t) & (prim >= _N_GROUND_TRIANGLES)
    which = np.where(on_box, (prim - _N_GROUND_TRIANGLES) // len(_TRIANGLES), -1)
    return t, which


def _cast_fast(o3d, cfg: LidarConfig, pat: _Pattern, dirs: np.ndarray, verts: np.ndarray, w_az: float,
               w_el: float, reach: float):
    """Road hits analytically, boxes by a compiled slab test of their candidate rays only (sensors/raycast.py);
    the outputs of _cast_full up to float32 round-off (its mesh holds the same boxes in float32)."""
    t = pat.t_ground.copy() if dirs is pat.dirs else _ground_range(cfg, dirs)
    which = np.full(len(t), -1, np.int64)
    sectors = _candidates(cfg, pat, verts, w_az, w_el, reach)
    if len(sectors[0]) == 0:
        return t, which
    raycast.cast_boxes(np.ascontiguousarray(dirs), float(cfg.mount_height_m), t, which, _slab_boxes(verts),
                        *sectors, len(pat.azimuths), len(pat.elevations))
    return t, which


def _slab_boxes(verts: np.ndarray) -> np.ndarray:
    """(K, 8) [cx, cy, ux, uy, half length, half width, z bottom, z top] of the boxes with corners verts
    (K, 8, 3) (_box_vertices), sensor frame: the footprint centre, the unit vector from corner 0 to 1."""
    e1, e2 = verts[:, 1, :2] - verts[:, 0, :2], verts[:, 3, :2] - verts[:, 0, :2]
    length, width = np.hypot(e1[:, 0], e1[:, 1]), np.hypot(e2[:, 0], e2[:, 1])
    centre = 0.5 * (verts[:, 0, :2] + verts[:, 2, :2])
    return np.column_stack([centre, e1 / length[:, None], 0.5 * length, 0.5 * width, verts[:, 0, 2], verts[:, 4, 2]])


def _candidates(cfg: LidarConfig, pat: _Pattern, verts: np.ndarray, w_az: float, w_el: float, reach: float):
    """The candidate rays of each box: (active, b0, b1, i0, i1, wrap, every), see raycast.cast_boxes.

    active (K',) int64 the boxes within reach whose elevation band holds a beam; per box (K,) the beam
    range [b0, b1), the azimuth index range [i0, i1], and [0, wrap] when wrap >= 0 (the sector passes
    azimuth 0), or every azimuth when `every`.

    A ray can hit box k only if its true azimuth lies in the sector the box footprint covers seen from the
    sensor (all azimuths when the sensor is above or inside the footprint) and its true elevation e lets it
    pass between the box bottom and top somewhere over the footprint's horizontal distances
    [rho_min, rho_max]: its height h + rho tan(e) is monotone in rho, so
    min over rho of (z_bottom - h) / rho <= tan(e) <= max over rho of (z_top - h) / rho.
    The nominal pattern is tested against that sector and band widened by the scan's largest angular errors
    (w_az, w_el) plus a float32 margin. A box whose nearest point is beyond `reach` (max range + the largest
    negative range noise) can only return points that are dropped, and is left out.
    """
    n_az = len(pat.azimuths)
    if len(verts) == 0:
        none = np.zeros(0, np.int64)
        return none, none, none, none, none, none, np.zeros(0, bool)
    h = cfg.mount_height_m
    foot = verts[:, :4, :2]  # (K, 4, 2) footprint corners; the sensor is at xy = 0
    e1, e2 = foot[:, 1] - foot[:, 0], foot[:, 3] - foot[:, 0]  # the two edge vectors from corner 0
    s1 = np.clip(np.einsum("kd,kd->k", -foot[:, 0], e1) / np.einsum("kd,kd->k", e1, e1), 0.0, 1.0)
    s2 = np.clip(np.einsum("kd,kd->k", -foot[:, 0], e2) / np.einsum("kd,kd->k", e2, e2), 0.0, 1.0)
    rho_min = np.linalg.norm(foot[:, 0] + s1[:, None] * e1 + s2[:, None] * e2, axis=1)
    rho_max = np.linalg.norm(foot, axis=2).max(axis=1)

    z_bottom, z_top = verts[:, 0, 2] - h, verts[:, 4, 2] - h  # relative to the sensor
    with np.errstate(divide="ignore", invalid="ignore"):
        tan_lo = np.where(z_bottom < 0.0, z_bottom / rho_min, z_bottom / rho_max)
        tan_hi = np.where(z_top > 0.0, z_top / rho_min, z_top / rho_max)
    margin = _ANGLE_MARGIN
    b0 = np.searchsorted(pat.elevations, np.arctan(tan_lo) - w_el - margin, "left")
    b1 = np.searchsorted(pat.elevations, np.arctan(tan_hi) + w_el + margin, "right")

    centre = foot.mean(axis=1)
    ref = np.arctan2(centre[:, 1], centre[:, 0])
    off = (np.arctan2(foot[..., 1], foot[..., 0]) - ref[:, None] + np.pi) % (2 * np.pi) - np.pi
    lo = ref + off.min(axis=1) - w_az - margin
    span = off.max(axis=1) - off.min(axis=1) + 2 * (w_az + margin)
    every = (rho_min < 1e-6) | (span >= 2 * np.pi)  # sensor inside (or on) the footprint, or a wide error
    step = np.deg2rad(cfg.azimuth_step_deg)
    lo = lo % (2 * np.pi)
    hi = lo + span
    i0 = np.ceil(lo / step).astype(np.int64)
    i1 = np.minimum(np.floor(hi / step).astype(np.int64), n_az - 1)
    wrap = np.floor((hi - 2 * np.pi) / step).astype(np.int64)  # >= 0: the sector passes azimuth 0

    active = np.flatnonzero((b0 < b1) & (rho_min <= reach))
    return active, b0.astype(np.int64), b1.astype(np.int64), i0, i1, wrap, every


def _box_vertices(pose: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(K, 8, 3) float64 box corners in the sensor frame (origin on the road below the sensor, x along yaw):
    bottom 0-3, top 4-7, as _CORNERS."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dx, dy = boxes[:, 0] - pose[0], boxes[:, 1] - pose[1]
    cx, cy = c * dx + s * dy, -s * dx + c * dy  # box centres in the sensor frame
    yaw = boxes[:, 5] - pose[2]
    lx = _CORNERS[None, :, 0] * boxes[:, 2:3]  # (K, 8)
    ly = _CORNERS[None, :, 1] * boxes[:, 3:4]
    cb, sb = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    box_v = np.empty((len(boxes), 8, 3))
    box_v[..., 0] = cx[:, None] + cb * lx - sb * ly
    box_v[..., 1] = cy[:, None] + sb * lx + cb * ly
    box_v[..., 2] = boxes[:, 6:7] + _CORNERS[None, :, 2] * boxes[:, 4:5]
    return box_v


def _mesh(box_v: np.ndarray, ground_half_size: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (K, 8, 3), after the ground square of that half size if given, as one mesh: vertices float32
    (4 + 8K or 8K, 3), triangles uint32 (2 + 12K or 12K, 3), ground triangles first, then 12 per box."""
    parts_v, parts_t, base = [], [], 0
    if ground_half_size is not None:
        h = ground_half_size
        parts_v.append(np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]]))
        parts_t.append(np.array([[0, 1, 2], [0, 2, 3]], np.uint32))
        base = 4
    parts_v.append(box_v.reshape(-1, 3))
    first_vertex = base + 8 * np.arange(len(box_v), dtype=np.uint32)
    parts_t.append((_TRIANGLES[None] + first_vertex[:, None, None]).reshape(-1, 3))
    return np.concatenate(parts_v).astype(np.float32), np.concatenate(parts_t)


def _raycaster(o3d, vertices: np.ndarray, triangles: np.ndarray):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
    return scene
