"""Synthetic spinning LiDAR (Velodyne HDL-32E pattern) by ray casting boxes and a flat road with open3d.

The scene is cast in the *sensor* frame (origin below the sensor on the road, x along the sensor yaw):
the ray tensor is then a per-config constant, and float32 ray casting keeps millimetre precision however
far along the highway the car is. Hit points are returned in the world frame, in float64.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from sensors import _checks
from sensors._o3d import open3d

GROUND: int = -2
"""Source label of points that hit the ground plane (vehicle ids are >= 0, static objects -1)."""

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


@dataclass(frozen=True)
class LidarConfig:
    """Beam pattern and error model; defaults are the HDL-32E (32 beams, -30.67..+10.67 deg, 1-70 m)."""

    n_beams: int = 32
    elevation_min_deg: float = -30.67
    elevation_max_deg: float = 10.67
    azimuth_step_deg: float = 0.16  # 2250 azimuths -> 72,000 rays per turn
    min_range_m: float = 1.0
    max_range_m: float = 70.0
    mount_height_m: float = 1.9  # sensor height above the road (m)
    range_noise_std_m: float = 0.02  # Gaussian range noise, along the ray
    dropout: float = 0.02  # probability a ray returns nothing
    ground_half_size_m: float = 100.0  # ground plane square around the sensor

    def __post_init__(self) -> None:
        _checks.positive_int("LidarConfig.n_beams", self.n_beams)
        _checks.finite("LidarConfig.elevation_min_deg", self.elevation_min_deg)
        _checks.finite("LidarConfig.elevation_max_deg", self.elevation_max_deg)
        lo, hi = self.elevation_min_deg, self.elevation_max_deg
        if not (-90.0 < lo <= hi < 90.0):
            raise ValueError(f"LidarConfig.elevation_*_deg: need -90 < min <= max < 90, got {lo!r}, {hi!r}")
        _checks.positive("LidarConfig.azimuth_step_deg", self.azimuth_step_deg)
        if self.azimuth_step_deg > 360.0:
            raise ValueError(f"LidarConfig.azimuth_step_deg: expected 0 < step <= 360, got {self.azimuth_step_deg!r}")
        _checks.positive("LidarConfig.min_range_m", self.min_range_m, allow_zero=True)
        _checks.positive("LidarConfig.max_range_m", self.max_range_m)
        if self.min_range_m >= self.max_range_m:
            raise ValueError(f"LidarConfig.min_range_m: must be < max_range_m, got {self.min_range_m!r}")
        _checks.positive("LidarConfig.mount_height_m", self.mount_height_m)
        _checks.positive("LidarConfig.range_noise_std_m", self.range_noise_std_m, allow_zero=True)
        _checks.finite("LidarConfig.dropout", self.dropout)
        if not (0.0 <= self.dropout < 1.0):
            raise ValueError(f"LidarConfig.dropout: expected 0 <= dropout < 1, got {self.dropout!r}")
        _checks.positive("LidarConfig.ground_half_size_m", self.ground_half_size_m)

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
    origin: (3,) float64 sensor position, world frame [m].
    """

    points: np.ndarray
    source: np.ndarray
    origin: np.ndarray

    def __post_init__(self) -> None:
        pts = _checks.float_array("Scan.points", self.points, (None, 3))
        src = _checks.int_array("Scan.source", self.source, (len(pts),))
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "source", src)
        object.__setattr__(self, "origin", _checks.float_array("Scan.origin", self.origin, (3,)))


def scan(
    cfg: LidarConfig,
    sensor_xy_yaw: np.ndarray,
    boxes: np.ndarray,
    box_ids: np.ndarray,
    rng: np.random.Generator,
) -> Scan:
    """Cast one turn of rays at the boxes and the road plane z = 0.

    cfg: beam pattern and error model.
    sensor_xy_yaw: (3,) sensor x, y [m] and yaw [rad], world frame; the sensor is at height
        cfg.mount_height_m and its azimuth 0 points along yaw.
    boxes: (K, 7) [cx, cy, length, width, height, yaw, z_bottom] world frame [m, rad]; sizes > 0.
        Leave out the box of the car carrying the sensor (its roof would return points).
    box_ids: (K,) int64 id per box, vehicles >= 0, static roadside objects -1.
    rng: draws one dropout uniform and one range-noise normal per ray (not per hit), so a change
        in the scene does not reshuffle the noise of the other rays.
    Returns the Scan: hits with measured range in [min_range_m, max_range_m], in ray order
    (azimuth-major, then beam from lowest elevation).
    """
    if not isinstance(cfg, LidarConfig):
        raise TypeError(f"cfg: expected LidarConfig, got {type(cfg).__name__}")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: expected numpy.random.Generator, got {type(rng).__name__}")
    pose = _checks.float_array("sensor_xy_yaw", sensor_xy_yaw, (3,))
    boxes = _checks.float_array("boxes", boxes, (None, 7))
    box_ids = _checks.int_array("box_ids", box_ids, (len(boxes),))
    if np.any(boxes[:, 2:5] <= 0.0):
        raise ValueError("boxes: length, width and height (columns 2-4) must be > 0")
    if np.any(box_ids < -1):
        raise ValueError("box_ids: must be >= -1 (vehicles >= 0, static objects -1)")

    o3d = open3d()
    dirs, rays = _rays(cfg)
    vertices, triangles = _scene_mesh(cfg, pose, boxes)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))
    ans = scene.cast_rays(rays)

    t_hit = ans["t_hit"].numpy()
    keep = np.isfinite(t_hit)
    if cfg.dropout > 0.0:
        keep &= rng.random(len(t_hit)) >= cfg.dropout
    r = t_hit.astype(np.float64)
    if cfg.range_noise_std_m > 0.0:
        r += cfg.range_noise_std_m * rng.standard_normal(len(t_hit))
    keep &= (r >= cfg.min_range_m) & (r <= cfg.max_range_m)

    idx = np.flatnonzero(keep)
    p = np.take(dirs, idx, axis=0)  # unit directions of the kept rays, sensor frame
    p *= np.take(r, idx)[:, None]  # -> points relative to the sensor
    c, s = np.cos(pose[2]), np.sin(pose[2])
    points = p @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # rotate by yaw into the world frame
    points += (pose[0], pose[1], cfg.mount_height_m)

    source_of_triangle = np.concatenate(
        [np.full(_N_GROUND_TRIANGLES, GROUND, np.int64), np.repeat(box_ids, len(_TRIANGLES))]
    )
    source = np.take(source_of_triangle, np.take(ans["primitive_ids"].numpy(), idx))
    origin = np.array([pose[0], pose[1], cfg.mount_height_m])
    return Scan(points=points, source=source, origin=origin)


@functools.lru_cache(maxsize=8)
def _rays(cfg: LidarConfig):
    """Unit ray directions (R, 3) float64 in the sensor frame and the open3d (R, 6) float32 ray tensor."""
    el = np.deg2rad(cfg.elevations_deg)
    az = np.deg2rad(cfg.azimuths_deg)
    A, E = np.meshgrid(az, el, indexing="ij")  # azimuth-major, like the firing sequence
    dirs = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    dirs.setflags(write=False)
    rays = np.empty((len(dirs), 6), np.float32)
    rays[:, :3] = (0.0, 0.0, cfg.mount_height_m)
    rays[:, 3:] = dirs
    return dirs, open3d().core.Tensor(rays)


def _scene_mesh(cfg: LidarConfig, pose: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ground square + all boxes as one mesh in the sensor frame: vertices (4 + 8K, 3) float32,
    triangles (2 + 12K, 3) uint32, ground triangles first, then 12 per box in box order."""
    h = cfg.ground_half_size_m
    ground_v = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    ground_t = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)

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
    box_t = _TRIANGLES[None] + (4 + 8 * np.arange(len(boxes), dtype=np.uint32))[:, None, None]

    vertices = np.concatenate([ground_v, box_v.reshape(-1, 3)]).astype(np.float32)
    triangles = np.concatenate([ground_t, box_t.reshape(-1, 3)])
    return vertices, triangles
