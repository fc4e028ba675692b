"""KITTI-tracking sequences: the format's conventions as the testbed writes them (testbed.export.kitti) and the
replay of a sequence through our perception (``replay_frames``): the sensed frames of recorded scans.

Conventions (docs/formats.md, field by field):

* velodyne frame: KITTI's, x forward, y left, z up [m], origin at the LiDAR; our sensor sits at the ego car's
  centre ``mount_height_m`` above the road, so a point p (world) is ``R(-yaw) (p_xy - ego_xy)``,
  ``p_z - mount_height_m``. Intensity: 0 (the ray caster models no reflectance).
* camera (cam0..cam3, one camera): at the LiDAR's origin, KITTI's axes x right, y down, z forward:
  ``Tr_velo_cam`` = [[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0]], ``R_rect`` = identity, P0..P3 =
  K [I | 0] with KITTI's nominal intrinsics (:data:`K_CAM`), image 1242 x 375 px.
* IMU / GPS (oxts): the point on the road below the LiDAR, axes x forward, y left, z up:
  ``Tr_imu_velo`` = [I | (0, 0, -mount_height_m)].
* world <-> oxts: the world x, y are east, north [m] of a local tangent plane; world (0, 0) at
  (:data:`LAT0`, :data:`LON0`), altitude :data:`ALT0` + z; latitude and longitude by KITTI's Mercator
  projection (devkit ``latlonToMercator``, pykitti ``pose_from_oxts_packet``) with the scale cos(lat) of the
  sequence's first frame, so KITTI's tools give the ego's path relative to its first pose exactly.

Replay: the scans are turned back into our sensor's Scan (world points, each point's ray from its direction
in the scenario's beam pattern, the range image), then ``perceive_frame`` as in a live run. What it derives,
what it lacks: see :func:`replay_frames`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from roadtrack import sensors

from ..config import ConfigError
from ..scenario.spec import Scenario
from ..world.simulation import TruthFrame
from .frames import SensedFrame, occlusion_pd, pd_scan, perceive_frame, rng_streams

SEQUENCE = "0000"
"""The sequence an export writes (one run = one sequence)."""
SCENARIO_FILE = "roadtrack_scenario.json"
"""Beside the KITTI folders: the run's scenario (values only), so a replay gets the road, sensor and tracker."""
LAT0, LON0, ALT0 = 49.0, 8.4, 100.0
"""Geodetic position [deg, deg, m] of the world origin (a point near Karlsruhe, where KITTI was recorded)."""
EARTH_RADIUS_M = 6378137.0  # KITTI devkit's er
IMAGE_W, IMAGE_H = 1242, 375
K_CAM = np.array([[721.5377, 0.0, 609.5593], [0.0, 721.5377, 172.854], [0.0, 0.0, 1.0]])
"""KITTI's rectified camera intrinsics (tracking sequence 0000's P2 without its baseline) [px]."""
TR_VELO_CAM = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0]])
NEAR_M = 0.1
"""Near plane [m] of the 2-D projection: the part of a box in front of it is projected."""
TRUCK_MIN_LENGTH_M = 7.0
"""Vehicles at least this long are labelled Truck, the others Car."""
LABEL_FIELDS = ("frame", "track_id", "type", "truncated", "occluded", "alpha", "bbox_left", "bbox_top",
                "bbox_right", "bbox_bottom", "height", "width", "length", "x", "y", "z", "rotation_y")
OXTS_FIELDS = ("lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu", "ax", "ay", "az", "af",
               "al", "au", "wx", "wy", "wz", "wf", "wl", "wu", "pos_accuracy", "vel_accuracy", "navstat", "numsats",
               "posmode", "velmode", "orimode")
VISIBLE_FULLY, VISIBLE_PARTLY = 0.95, 0.5
"""Visible width fractions (sensors.occlusion.visibility) from which a label is occluded 0 (fully visible) and 1
(partly occluded); below: 2 (largely occluded); 3 (unknown) where no beam would reach the car."""


def wrap(a):
    """Angles [rad] wrapped to [-pi, pi)."""
    return (np.asarray(a, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi


# --- geodetic ---------------------------------------------------------------------------------------------

def mercator(lat: np.ndarray, lon: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """KITTI's Mercator projection: (east, north) [m] of latitudes, longitudes [deg] at ``scale`` = cos(lat0)."""
    lat, lon = np.asarray(lat, np.float64), np.asarray(lon, np.float64)
    return (scale * EARTH_RADIUS_M * np.pi * lon / 180.0,
            scale * EARTH_RADIUS_M * np.log(np.tan((90.0 + lat) * np.pi / 360.0)))


def geodetic(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """World positions xy (F, 2) [m] (the ego's path, first frame first) as (lat (F,), lon (F,) [deg], the
    Mercator scale): world (0, 0) is (LAT0, LON0), the scale is cos of the first frame's latitude (solved by
    fixed-point iteration, as the scale depends on that latitude)."""
    xy = np.asarray(xy, np.float64)
    lat0 = LAT0
    for _ in range(8):
        scale = math.cos(math.radians(lat0))
        lat, lon = _inverse(xy, scale)
        lat0 = float(lat[0])
    scale = math.cos(math.radians(lat0))
    lat, lon = _inverse(xy, scale)
    return lat, lon, scale


def _inverse(xy: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    e0, n0 = mercator(LAT0, LON0, scale)
    sr = scale * EARTH_RADIUS_M
    lon = (xy[:, 0] + e0) * 180.0 / (np.pi * sr)
    lat = 360.0 / np.pi * np.arctan(np.exp((xy[:, 1] + n0) / sr)) - 90.0
    return lat, lon


def world_xy(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """(F, 2) world x, y [m] of an oxts path (lat, lon (F,) [deg], first frame first): inverse of :func:`geodetic`."""
    scale = math.cos(math.radians(float(lat[0])))
    e, n = mercator(lat, lon, scale)
    e0, n0 = mercator(LAT0, LON0, scale)
    return np.column_stack([e - e0, n - n0])


# --- frames -----------------------------------------------------------------------------------------------

def to_velo(points: np.ndarray, pose: np.ndarray, mount_height_m: float) -> np.ndarray:
    """World points (N, 3) [m] in the velodyne frame of a sensor at ``pose`` (x, y, yaw) ``mount_height_m`` above
    the road."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = points[:, 0] - pose[0], points[:, 1] - pose[1]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, points[:, 2] - mount_height_m])


def from_velo(points: np.ndarray, pose: np.ndarray, mount_height_m: float) -> np.ndarray:
    """Velodyne-frame points (N, 3) back to the world (inverse of :func:`to_velo`), float64."""
    p = np.asarray(points, np.float64)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.column_stack([pose[0] + c * p[:, 0] - s * p[:, 1], pose[1] + s * p[:, 0] + c * p[:, 1],
                            p[:, 2] + mount_height_m])


def velo_to_cam(p: np.ndarray) -> np.ndarray:
    """Velodyne-frame points (N, 3) in camera coordinates (x right, y down, z forward)."""
    return np.column_stack([-p[:, 1], -p[:, 2], p[:, 0]])


def cam_to_velo(p: np.ndarray) -> np.ndarray:
    return np.column_stack([p[:, 2], -p[:, 0], -p[:, 1]])


def calib_text(mount_height_m: float) -> str:
    """A KITTI-tracking calib file: P0..P3, R_rect, Tr_velo_cam, Tr_imu_velo (row-major, 12 / 9 values)."""
    p = np.hstack([K_CAM, np.zeros((3, 1))])
    tr_imu_velo = np.hstack([np.eye(3), [[0.0], [0.0], [-mount_height_m]]])
    rows = [*(f"P{i}: {_row(p)}" for i in range(4)), f"R_rect {_row(np.eye(3))}",
            f"Tr_velo_cam {_row(TR_VELO_CAM)}", f"Tr_imu_velo {_row(tr_imu_velo)}"]
    return "\n".join(rows) + "\n"


def _row(m: np.ndarray) -> str:
    return " ".join(f"{v:.12e}" for v in np.asarray(m, np.float64).reshape(-1))


def read_calib(path: Path) -> dict[str, np.ndarray]:
    """A calib file's matrices by key (``P2: ...`` and ``Tr_velo_cam ...`` forms both), (3, 4) or (3, 3)."""
    out = {}
    for n, line in enumerate(_lines(path), 1):
        parts = line.replace(":", " ", 1).split()
        if not parts:
            continue
        try:
            values = np.array([float(v) for v in parts[1:]])
        except ValueError:
            raise ConfigError(str(path), f"line {n}: not numbers after {parts[0]!r}") from None
        if values.size not in (9, 12):
            raise ConfigError(str(path), f"line {n}: {parts[0]} has {values.size} values, expected 9 or 12")
        out[parts[0]] = values.reshape(3, -1)
    return out


def box_corners_cam(loc: np.ndarray, hwl: np.ndarray, ry: float) -> np.ndarray:
    """(8, 3) corners in camera coordinates of a KITTI box: bottom centre ``loc``, (h, w, l), rotation_y."""
    h, w, l = hwl
    x = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * l / 2
    z = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * w / 2
    y = np.array([0, 0, 0, 0, -1, -1, -1, -1]) * h
    c, s = math.cos(ry), math.sin(ry)
    return np.column_stack([c * x + s * z + loc[0], y + loc[1], -s * x + c * z + loc[2]])


_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7))


def image_box(corners: np.ndarray) -> tuple[tuple[float, float, float, float], float]:
    """The 2-D box (left, top, right, bottom) [px] of a 3-D box's corners (8, 3) (camera coordinates) projected
    through P2 and clipped to the image, and its truncation: 1 - (area inside the image) / (area of the
    projection of the box's part in front of the near plane :data:`NEAR_M`). A box wholly behind that plane:
    (0, 0, 0, 0), truncation 1."""
    front = corners[:, 2] >= NEAR_M
    pts = [corners[front]]
    for a, b in _EDGES:  # where an edge crosses the near plane
        if front[a] != front[b]:
            t = (NEAR_M - corners[a, 2]) / (corners[b, 2] - corners[a, 2])
            pts.append((corners[a] + t * (corners[b] - corners[a]))[None])
    p = np.vstack(pts)
    if len(p) == 0:
        return (0.0, 0.0, 0.0, 0.0), 1.0
    uvw = p @ K_CAM.T
    u, v = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2]
    full = (u.min(), v.min(), u.max(), v.max())
    clip = (min(max(full[0], 0.0), IMAGE_W - 1.0), min(max(full[1], 0.0), IMAGE_H - 1.0),
            min(max(full[2], 0.0), IMAGE_W - 1.0), min(max(full[3], 0.0), IMAGE_H - 1.0))
    area = (full[2] - full[0]) * (full[3] - full[1])
    inside = max(clip[2] - clip[0], 0.0) * max(clip[3] - clip[1], 0.0)
    if full[2] < 0 or full[0] > IMAGE_W - 1 or full[3] < 0 or full[1] > IMAGE_H - 1:
        inside = 0.0
    return clip, float(np.clip(1.0 - inside / area, 0.0, 1.0)) if area > 0 else 1.0


def vehicle_type(length_m: float) -> str:
    return "Truck" if length_m >= TRUCK_MIN_LENGTH_M else "Car"


# --- reading a sequence -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Sequence:
    """A KITTI-tracking sequence on disk: root (velodyne/, oxts/, calib/, label_02/) and its name (0000)."""

    root: Path
    name: str

    @property
    def scans(self) -> list[Path]:
        return sorted((self.root / "velodyne" / self.name).glob("*.bin"))

    @property
    def labels(self) -> Path | None:
        f = self.root / "label_02" / f"{self.name}.txt"
        return f if f.is_file() else None

    @property
    def scenario_file(self) -> Path | None:
        f = self.root / SCENARIO_FILE
        return f if f.is_file() else None


def open_sequence(root: str | Path, name: str | None = None) -> Sequence:
    """The sequence ``name`` (default: the only one) of a KITTI-tracking folder; ConfigError (one line) when the
    folder holds none, several without ``name``, or lacks its oxts file or scans."""
    root = Path(root)
    velo = root / "velodyne"
    if not velo.is_dir():
        raise ConfigError(str(root), "not a KITTI-tracking folder: no velodyne/")
    names = sorted(p.name for p in velo.iterdir() if p.is_dir())
    if name is None:
        if len(names) != 1:
            raise ConfigError("--sequence", f"{root} holds {len(names)} sequences ({', '.join(names) or 'none'}); "
                                            "name one")
        name = names[0]
    if name not in names:
        raise ConfigError("--sequence", f"no sequence {name!r} in {root}; there are: {', '.join(names) or 'none'}")
    seq = Sequence(root, name)
    if not (root / "oxts" / f"{name}.txt").is_file():
        raise ConfigError(str(root), f"no oxts/{name}.txt (the ego's poses)")
    if not seq.scans:
        raise ConfigError(str(root), f"no scans in velodyne/{name}/")
    return seq


def _lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(str(path), f"cannot be read ({type(err).__name__})") from None


def read_oxts(path: Path) -> np.ndarray:
    """(F, 30) float64: one row of the 30 oxts values per frame."""
    rows = []
    for n, line in enumerate(_lines(path), 1):
        if not line.strip():
            continue
        try:
            values = [float(v) for v in line.split()]
        except ValueError:
            raise ConfigError(str(path), f"line {n}: not numbers") from None
        if len(values) != len(OXTS_FIELDS) or not np.all(np.isfinite(values)):
            raise ConfigError(str(path), f"line {n}: {len(values)} values, expected {len(OXTS_FIELDS)} finite ones")
        rows.append(values)
    if not rows:
        raise ConfigError(str(path), "no poses")
    return np.array(rows)


def read_labels(path: Path) -> dict[str, np.ndarray]:
    """The label file's columns (:data:`LABEL_FIELDS`; a results file's 18th, score, is ignored), DontCare rows
    dropped: frame, track_id int64, type str, the rest float64."""
    rows = []
    for n, line in enumerate(_lines(path), 1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) not in (17, 18):
            raise ConfigError(str(path), f"line {n}: {len(parts)} fields, expected 17 (or 18 with a score)")
        if parts[2] == "DontCare":
            continue
        try:
            rows.append((int(parts[0]), int(parts[1]), parts[2], *(float(v) for v in parts[3:17])))
        except ValueError:
            raise ConfigError(str(path), f"line {n}: a field is not a number") from None
    cols = list(zip(*rows)) if rows else [()] * 17
    out = {f: np.array(c, dtype=np.float64) for f, c in zip(LABEL_FIELDS[3:], cols[3:])}
    out["frame"] = np.array(cols[0], dtype=np.int64)
    out["track_id"] = np.array(cols[1], dtype=np.int64)
    out["type"] = np.array(cols[2], dtype=object)
    return out


def read_scan(path: Path) -> np.ndarray:
    """(N, 4) float32 x, y, z, intensity of a velodyne file."""
    data = np.fromfile(path, dtype="<f4")
    if data.size % 4:
        raise ConfigError(str(path), f"{data.size} float32 values, not a multiple of 4")
    return data.reshape(-1, 4)


def scan_of(velo: np.ndarray, pose: np.ndarray, lidar: sensors.LidarConfig) -> sensors.Scan:
    """Our Scan of a velodyne scan (N, 3 or 4) at ``pose`` (x, y, yaw): world points, each point's ray (azimuth
    column of its direction, nearest beam of ``lidar``'s pattern; the nearer of two points on one ray keeps
    it, the other gets ray -1) and the range image (the points' ranges, inf where no point). Source labels: -1."""
    p = np.asarray(velo[:, :3], np.float64)
    az = np.deg2rad(lidar.azimuths_deg)
    el = np.deg2rad(lidar.elevations_deg)
    ranges = np.full((len(az), len(el)), np.inf)
    ray = np.full(len(p), -1, np.int64)
    if len(p):
        r = np.linalg.norm(p, axis=1)
        step = 2.0 * np.pi / len(az) if len(az) > 1 else 2.0 * np.pi
        a = np.rint(np.mod(np.arctan2(p[:, 1], p[:, 0]) - az[0], 2.0 * np.pi) / step).astype(np.int64) % len(az)
        e = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))
        b = np.abs(e[:, None] - el[None, :]).argmin(axis=1)
        flat = a * len(el) + b
        order = np.lexsort((r, flat))  # per ray, nearest first
        first = order[np.r_[True, flat[order][1:] != flat[order][:-1]]]
        ray[first] = flat[first]
        ranges.reshape(-1)[flat[first]] = r[first]
    pts = from_velo(p, pose, lidar.mount_height_m)
    return sensors.Scan(points=pts, source=np.full(len(p), -1, np.int64),
                        origin=np.array([pose[0], pose[1], lidar.mount_height_m]), ranges=ranges, ray=ray,
                        azimuths=az, elevations=el, pose=np.asarray(pose, np.float64))


def ego_poses(seq: Sequence) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) x, y [m], yaw [rad] of the LiDAR (oxts pose composed with Tr_imu_velo's plane offset) and (F, 2)
    the ego's velocity [m/s] (oxts ve, vn), world frame."""
    ox = read_oxts(seq.root / "oxts" / f"{seq.name}.txt")
    xy = world_xy(ox[:, 0], ox[:, 1])
    yaw = ox[:, 5]
    calib_file = seq.root / "calib" / f"{seq.name}.txt"
    if calib_file.is_file():
        tr = read_calib(calib_file).get("Tr_imu_velo")
        if tr is not None:  # the LiDAR's place in the IMU frame: -R^T t
            off = -tr[:, :3].T @ tr[:, 3]
            c, s = np.cos(yaw), np.sin(yaw)
            xy = xy + np.column_stack([c * off[0] - s * off[1], s * off[0] + c * off[1]])
    return np.column_stack([xy, yaw]), np.column_stack([ox[:, 7], ox[:, 6]])


def label_truth(labels: dict[str, np.ndarray], frame: int, pose: np.ndarray, mount_height_m: float):
    """The labelled vehicles of ``frame`` in the world: rows (ids (K,), types (K,), xy (K, 2), heading (K,),
    size (K, 3) length, width, height)."""
    at = labels["frame"] == frame
    loc = np.column_stack([labels["x"][at], labels["y"][at], labels["z"][at]])
    velo = cam_to_velo(loc)
    xy = from_velo(velo, pose, mount_height_m)[:, :2]
    heading = wrap(-labels["rotation_y"][at] - np.pi / 2 + pose[2])
    size = np.column_stack([labels["length"][at], labels["width"][at], labels["height"][at]])
    return labels["track_id"][at], labels["type"][at], xy, heading, size


def points_in_boxes(points: np.ndarray, xy: np.ndarray, heading: np.ndarray, size: np.ndarray,
                    margin_m: float = 0.1, floor_m: float = 0.02) -> np.ndarray:
    """(N,) int64 index of the box each point lies in (-1 none): the footprint widened by ``margin_m``, from
    ``floor_m`` above the road (lower points may be the road beside the car) to the top + ``margin_m``."""
    out = np.full(len(points), -1, np.int64)
    for k in range(len(xy)):
        c, s = math.cos(heading[k]), math.sin(heading[k])
        dx, dy = points[:, 0] - xy[k, 0], points[:, 1] - xy[k, 1]
        along, across = c * dx + s * dy, -s * dx + c * dy
        inside = ((np.abs(along) <= size[k, 0] / 2 + margin_m) & (np.abs(across) <= size[k, 1] / 2 + margin_m)
                  & (points[:, 2] >= floor_m) & (points[:, 2] <= size[k, 2] + margin_m) & (out < 0))
        out[inside] = k
    return out


EGO_SIZE_M = (5.0, 2.0, 1.5)
"""(length, width, height) [m] given to the ego in a replay's truth: KITTI does not record the ego's size."""


def replay_frames(seq: Sequence, scn: Scenario, road: sensors.RoadMap | None) -> Iterator[SensedFrame]:
    """The sensed frames of a recorded sequence, through the live run's perception (testbed.sensing.perceive_frame).

    Derived from the files: the LiDAR pose per frame (oxts + Tr_imu_velo), the points in the world, each point's
    ray and the range image (from the point's direction in ``scn.sensor.lidar``'s beam pattern and its range), so
    the perception's scan-line links, open-end test, range-aware height bound and box-fit azimuth step and the
    occlusion-aware P_D (``scn.sensor.occlusion_pd``) work as live. With labels: the truth (position, heading and
    size from each box; velocity by central differences of a track's positions over the frame interval
    ``scn.dt``, one-sided at its ends, 0 for a track of one frame), each vehicle's LiDAR points (those inside
    its box, :func:`points_in_boxes`) and so the detections' provenance. From ``scn``: the beam pattern, the
    sensor's height above the road, the perception, the added clutter and the sensor outages (drawn from the
    scenario seed as live), and ``road`` (the lane map, when the caller has one: an exported run's road).
    Lacking: intensity (unused by our perception), per-point truth labels (replaced by the boxes), the ego's
    size (:data:`EGO_SIZE_M`), the vehicles' lanes (-1) and names (``Car<id>`` / ``Truck<id>``)."""
    lidar = scn.sensor.lidar
    h = lidar.mount_height_m
    poses, ego_v = ego_poses(seq)
    files = seq.scans
    if len(poses) < len(files):
        raise ConfigError(str(seq.root / "oxts" / f"{seq.name}.txt"),
                          f"{len(poses)} poses for {len(files)} scans")
    labels = read_labels(seq.labels) if seq.labels is not None else None
    velocity = _label_velocities(labels, poses, h, scn.dt) if labels is not None else None
    ego_id = int(labels["track_id"].max()) + 1 if labels is not None and len(labels["track_id"]) else 0
    rngs = rng_streams(scn.seed)
    pd_for = occlusion_pd(scn, road) if scn.sensor.occlusion_pd else None
    for f, path in enumerate(files):
        pose, t = poses[f], f * scn.dt
        scan = scan_of(read_scan(path), pose, lidar)
        if labels is not None:
            ids, types, xy, heading, size = label_truth(labels, f, pose, h)
            v = velocity[labels["frame"] == f]
        else:
            ids, types = np.zeros(0, np.int64), np.zeros(0, dtype=object)
            xy, heading, size, v = np.zeros((0, 2)), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 2))
        inside = points_in_boxes(scan.points, xy, heading, size)
        source = np.where(inside >= 0, ids[np.maximum(inside, 0)] if len(ids) else -1, -1).astype(np.int64)
        scan = sensors.Scan(points=scan.points, source=source, origin=scan.origin, ranges=scan.ranges,
                            ray=scan.ray, azimuths=scan.azimuths, elevations=scan.elevations, pose=scan.pose)
        off, _ = scn.sensor.outage_at(t)
        perc, dets = perceive_frame(scan, off, pose[:2], scn, rngs, road)
        truth = TruthFrame(frame=f, time=t, ids=np.r_[ego_id, ids].astype(np.int64),
                           names=("ego", *(f"{ty}{i}" for ty, i in zip(types, ids))),
                           xy=np.vstack([pose[:2], xy]), heading=np.r_[pose[2], heading],
                           velocity=np.vstack([ego_v[f], v]), size=np.vstack([EGO_SIZE_M, size]),
                           lane=np.full(len(ids) + 1, -1, np.int64), crashed=np.zeros(len(ids) + 1, bool))
        n_points = np.r_[0, np.bincount(inside[inside >= 0], minlength=len(ids))].astype(np.int64)
        in_range = np.hypot(*(truth.xy - pose[:2]).T) <= lidar.max_range_m
        bare = pd_scan(scan, perc.is_ground)
        yield SensedFrame(truth, scan, perc, dets, (n_points, in_range),
                          pd_for(bare) if pd_for is not None else None, bare, road)


def _label_velocities(labels: dict, poses: np.ndarray, h: float, dt: float) -> np.ndarray:
    """(L,) rows of the labels: each row's world velocity (L, 2) [m/s] by central differences along its track."""
    n = len(labels["frame"])
    xy = np.zeros((n, 2))
    for f in np.unique(labels["frame"]):
        at = labels["frame"] == f
        if f >= len(poses):
            raise ConfigError("label_02", f"labels of frame {f}, past the {len(poses)} poses")
        xy[at] = label_truth(labels, int(f), poses[f], h)[2]
    v = np.zeros((n, 2))
    for tid in np.unique(labels["track_id"]):
        rows = np.flatnonzero(labels["track_id"] == tid)
        rows = rows[np.argsort(labels["frame"][rows], kind="stable")]
        if len(rows) < 2:
            continue
        fr = labels["frame"][rows].astype(np.float64)
        v[rows] = np.column_stack([np.gradient(xy[rows, 0], fr * dt), np.gradient(xy[rows, 1], fr * dt)])
    return v
