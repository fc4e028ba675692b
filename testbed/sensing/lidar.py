"""The LiDAR as a sensor of the sensing loop (:data:`LIDAR`, registered as ``lidar``): ray-cast scan, perception,
the scenario's added clutter, visibility (LiDAR points per vehicle, centre in range) and the occlusion-aware P_D.
Its data fills the SensedFrame's scan, perception, detections and pd_scan; it draws from the streams ``lidar``
(noise, dropout, attitude) and ``clutter`` (testbed/common/streams.py)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from roadtrack import sensors

from ..scenario.spec import Scenario
from ..world.roadside import boxes_near
from .sensor import SensingContext, Sensor

PD_RANGE_STEP_M = 0.002
"""Range resolution [m] of the image the occlusion-aware P_D reads (the HDL-32E reports ranges in 2 mm steps)."""

def pd_scan(scan: sensors.Scan, is_ground: np.ndarray) -> sensors.Scan:
    """What the occlusion-aware P_D reads of ``scan``: no points, and its range image with the returns the
    perception called ground removed (inf: a ground return lies beyond where any ray the P_D counts enters a box,
    so it never blocks; sensors/occlusion.py) and the rest rounded to :data:`PD_RANGE_STEP_M`. Small enough to
    cache (about 20 kB a frame compressed on the highway benchmark, against 80 kB with the ground)."""
    return scan.image_only(sensors.quantised_ranges(scan, is_ground, PD_RANGE_STEP_M))  # compiled: numpy's rounding



TRUCK_BOX_M = (15.4, 2.5, 3.5)
"""(length, width, height) [m] of the truck box of the occlusion-aware P_D: the box fit's truck prior
(sensors/boxfit.py); the rear face of a 12-18.75 m truck lies within the 2 m margin of its entry."""


def occlusion_pd(scn: Scenario, road: sensors.RoadMap):
    """The occlusion-aware P_D per scan: ``occlusion_pd(scn, road)(scan)`` is ``pd(xy, nominal, trucks=None)``,
    a function of positions xy (T, 2) [m] (a tracker's predicted ones), the tracker's nominal P_D and optionally
    trucks (T,) bool, giving (T,).

    Within the sensor's range: ``nominal`` where the range image shows a car-sized box at the position (heading
    along the road) in view, near 0 (at least ``sensor.occlusion_pd_floor``) in the shadow of a nearer object or
    where no beam reaches a car (sensors/occlusion.py): a hidden car's track coasts without losing score. Beyond
    the range: ``nominal``, so a track leaving the sensor's reach loses score and is deleted as without this input
    (a P_D of 0 there would keep it forever).

    ``trucks`` marks the tracks whose last associated detection was truck-long, or that were started on one
    (testbed.tracking.builtin truck_tracks, trackers StepInfo.born_from); their P_D is that of a truck-sized box (:data:`TRUCK_BOX_M`). With the car box a truck's own
    rear face, 6-9 m before its centre and so nearer than a car box's entry, "blocked" the view of it: a truck
    20 m behind, hit by 1000 points a scan, got P_D 0 and its track was never updated. (A truck box for every
    track would not do: the car just ahead of a hidden car then lies at the box's entry and no longer hides it.)"""
    lidar = scn.sensor.lidar
    configs: dict[float, sensors.OcclusionConfig] = {}
    perception = scn.sensor.perception
    edge_on = scn.sensor.occlusion_pd_edge_on and perception.vehicle_like and perception.shape_filter
    edge_on_top = perception.min_height_m if edge_on else 0.0  # the perception's edge-on test (sensors/perception.py)

    def for_scan(scan: sensors.Scan):
        def pd_of(xy: np.ndarray, nominal: float, trucks: np.ndarray | None = None) -> np.ndarray:
            nominal = float(nominal)
            cfg = configs.get(nominal)
            if cfg is None:
                cfg = configs[nominal] = sensors.OcclusionConfig.from_lidar(
                    lidar, pd_nominal=nominal, min_points=scn.sensor.perception.cluster.min_points,
                    full_points=scn.sensor.occlusion_pd_full_points, edge_on_top_m=edge_on_top)
            xy = np.asarray(xy, dtype=np.float64)[:, :2]
            heading = road.heading_at(xy) if len(xy) else None
            size = sensors.CAR_BOX_M
            if trucks is not None and np.any(trucks):  # one call, each track's own box
                size = np.where(np.asarray(trucks, dtype=bool)[:, None], TRUCK_BOX_M, sensors.CAR_BOX_M)
            occ = sensors.detection_probability(scan, xy, cfg, size_m=size, heading=heading)
            beyond = np.hypot(xy[:, 0] - scan.origin[0], xy[:, 1] - scan.origin[1]) > lidar.max_range_m
            return np.where(beyond, nominal, np.maximum(occ, min(scn.sensor.occlusion_pd_floor, nominal)))

        return pd_of

    return for_scan


def sense_frame(truth, static: np.ndarray, scn: Scenario, rngs: dict, watch, road: sensors.RoadMap | None):
    """One frame's LiDAR scan, perception and detections (plus the scenario's added clutter); ``watch``: a
    Stopwatch charged raycast and perception, or None (:func:`frame_scan`, then :func:`perceive_frame`)."""
    off, scan = frame_scan(truth, static, scn, rngs)
    if watch is not None:
        watch.lap("raycast")
    perc, dets = perceive_frame(scan, off, truth.xy[0], scn, rngs, road)
    if watch is not None:
        watch.lap("perception")
    return scan, perc, dets


def frame_scan(truth, static: np.ndarray, scn: Scenario, rngs: dict) -> tuple[bool, sensors.Scan]:
    """(whether the whole sensor is off, the frame's LiDAR scan), drawn from ``rngs["lidar"]``.

    ``sensor.outages``: the named vehicles are left out of the ray-cast scene; while the whole sensor is off the
    scan is cast (so the noise streams stay aligned with a run without the outage) and then emptied."""
    off, hidden = scn.sensor.outage_at(truth.time)
    scan = scan_frame(truth, static, scn.sensor.lidar, rngs["lidar"], hidden=hidden)
    return off, (empty_scan(scan) if off else scan)


def perceive_frame(scan: sensors.Scan, off: bool, ego_xy: np.ndarray, scn: Scenario, rngs: dict,
                   road: sensors.RoadMap | None) -> tuple[sensors.PerceptionResult, sensors.Detections]:
    """The perception of ``scan`` and the detections a tracker gets: perception's, then the scenario's added
    clutter around ``ego_xy`` (2,) [m] drawn from ``rngs["clutter"]`` (drawn and dropped while the sensor is
    ``off``). A live run and a replay of recorded scans (testbed.sensing.kitti) both come through here."""
    perc = sensors.perceive(scan, scn.sensor.perception, road)
    dets = perc.detections
    clutter = scn.sensor.clutter
    if clutter.density_per_m2 > 0:
        extra = sensors.clutter_detections(rngs["clutter"], clutter.density_per_m2, ego_xy, clutter.radius_m)
        dets = dets if off else dets.concat(extra)
    return perc, dets


def empty_scan(scan: sensors.Scan) -> sensors.Scan:
    """``scan`` with no points and a range image of inf (no ray returned): a sensor outage. The occlusion-aware
    P_D of such a scan is nominal everywhere in range (nothing hides anything)."""
    return scan.image_only(np.full_like(scan.ranges, np.inf))


def scan_frame(truth, static: np.ndarray, cfg: sensors.LidarConfig, rng: np.random.Generator,
          hidden: frozenset[str] = frozenset()) -> sensors.Scan:
    """One LiDAR turn from the ego car at the vehicles (ego left out) and roadside boxes within reach; the
    vehicles named in ``hidden`` are left out of the scene (a forced loss: no return, no shadow)."""
    reach = cfg.max_range_m + 10.0
    boxes, ids = truth.boxes()
    cars = boxes_near(boxes, truth.xy[0], reach)  # a car beyond the LiDAR's reach returns no point
    if hidden:
        cars &= np.array([n not in hidden for n in truth.names[1:]], dtype=bool)
    near = boxes_near(static, truth.xy[0], reach)
    scene_boxes = np.vstack([boxes[cars], static[near]])
    scene_ids = np.concatenate([ids[cars], np.full(int(near.sum()), -1, dtype=np.int64)])
    return sensors.scan(cfg, truth.ego_pose, scene_boxes, scene_ids, rng)


def visibility(truth, scan, max_range_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per vehicle of ``truth`` (K,): LiDAR points that hit it (int64) and whether its centre lies
    within ``max_range_m`` of the sensor (bool)."""
    src = scan.source[scan.source >= 0]
    n_points = np.zeros(len(truth.ids), dtype=np.int64)
    if len(src) and src.max() <= 4 * (len(src) + len(truth.ids)):  # ids 0..n (testbed/world/simulation.py)
        counts = np.bincount(src)  # a short table
        ids = np.asarray(truth.ids, dtype=np.int64)
        known = (ids >= 0) & (ids < len(counts))
        n_points[known] = counts[ids[known]]
    elif len(src):  # large ids (a replayed recording's labels): by the sorted distinct ids
        ids, counts = np.unique(src, return_counts=True)
        at = np.minimum(np.searchsorted(ids, truth.ids), len(ids) - 1)
        hit = ids[at] == truth.ids
        n_points[hit] = counts[at[hit]]
    in_range = np.hypot(*(truth.xy - scan.origin[:2]).T) <= max_range_m
    return n_points, in_range




class LidarData(NamedTuple):
    """One LiDAR frame: the scan (sensors.Scan), its sensors.PerceptionResult, the detections the tracker gets
    (sensors.Detections, with the added clutter) and the scan the occlusion-aware P_D reads (:func:`pd_scan`)."""

    scan: sensors.Scan
    perception: sensors.PerceptionResult
    detections: sensors.Detections
    pd_scan: sensors.Scan


def sense_lidar(ctx: SensingContext, truth, rngs: dict) -> LidarData:
    """:func:`sense_frame` of ``truth`` and its :func:`pd_scan`."""
    scan, perc, dets = sense_frame(truth, ctx.static, ctx.scn, rngs, ctx.watch, ctx.road)
    return LidarData(scan, perc, dets, pd_scan(scan, perc.is_ground))


def lidar_visibility(ctx: SensingContext, truth, data: LidarData) -> tuple[np.ndarray, np.ndarray]:
    """:func:`visibility` of ``truth`` in the frame's scan within the LiDAR's range."""
    return visibility(truth, data.scan, ctx.scn.sensor.lidar.max_range_m)


def lidar_pd(ctx: SensingContext):
    """The occlusion-aware P_D per frame (``f(data) -> pd``), or None when the scenario has it off."""
    if not ctx.scn.sensor.occlusion_pd:
        return None
    pd_for = occlusion_pd(ctx.scn, ctx.road)
    return lambda data: pd_for(data.pd_scan)


LIDAR = Sensor("lidar", sense_lidar, lidar_visibility, lidar_pd, streams=("lidar", "clutter"),
               doc="ray-cast LiDAR (sensor.lidar), perception (sensor.perception), added clutter (sensor.clutter)")
