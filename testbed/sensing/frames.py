"""The one sensing loop: ``sense(scenario)`` yields, per frame, the truth, the LiDAR scan, the perception's result,
the detections (with the scenario's added clutter), the cars' visibility and the occlusion-aware P_D.

Random streams derive from the scenario seed (``SeedSequence(seed).spawn``), one per consumer (:data:`STREAMS`), so
switching on added clutter does not change the LiDAR noise.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

import sensors

from ..world.roadside import boxes_near
from ..scenario.spec import Scenario
from ..world.simulation import lane_centres, roadside_objects

STREAMS = ("roadside", "lidar", "clutter")
PD_RANGE_STEP_M = 0.002
"""Range resolution [m] of the image the occlusion-aware P_D reads (the HDL-32E reports ranges in 2 mm steps)."""


@dataclass(frozen=True, eq=False)
class SensedFrame:
    """One frame of sensing.

    truth: the simulator's frame (testbed.world.simulation.Frame: ids, names, xy, velocity, heading, size, ...; row 0 the
    ego). scan: the LiDAR turn (sensors.Scan). perception: its sensors.PerceptionResult. detections: the
    sensors.Detections the tracker gets (perception's, then the added clutter). visibility: (n_points (K,) int64
    LiDAR points on each vehicle of truth, in_range (K,) bool centre within the LiDAR's range). pd: the
    occlusion-aware P_D ``pd(xy (T, 2), nominal, trucks=None) -> (T,)``, or None when the scenario has it off.
    pd_scan: the scan ``pd`` reads (:func:`pd_scan`: no points, the range image without ground returns in 2 mm
    steps), the same whether sensed live or read from a sensing cache. road: the perception's lane map
    (sensors.RoadMap), the same live or cached, or None.
    """

    truth: object
    scan: sensors.Scan
    perception: sensors.PerceptionResult
    detections: sensors.Detections
    visibility: tuple[np.ndarray, np.ndarray]
    pd: Callable[..., np.ndarray] | None
    pd_scan: sensors.Scan | None = None
    road: sensors.RoadMap | None = None

    @property
    def index(self) -> int:
        return int(self.truth.frame)

    @property
    def time(self) -> float:
        return float(self.truth.time)


def sense(scn: Scenario, policy: Callable | None = None, watch=None) -> Iterator[SensedFrame]:
    """The frames of ``scn`` sensed one by one (the scenario's traffic, its ego driven by ``policy`` for a scenario
    with ``[env]``). ``watch``: a Stopwatch charged per stage (simulation, raycast, perception), or None."""
    rngs = rng_streams(scn.seed)
    sim, static, road = sensing_setup(scn, rngs, policy)
    yield from sense_simulation(scn, sim, static, road, rngs, watch)


def sense_simulation(scn: Scenario, sim, static: np.ndarray, road: sensors.RoadMap, rngs: dict,
                     watch=None) -> Iterator[SensedFrame]:
    """:func:`sense` on a simulation already set up (:func:`sensing_setup`), e.g. to log its road first."""
    pd_for = occlusion_pd(scn, road) if scn.sensor.occlusion_pd else None
    reach = scn.sensor.lidar.max_range_m
    for truth in sim.frames():
        if watch is not None:
            watch.lap("simulation")
        scan, perc, dets = sense_frame(truth, static, scn, rngs, watch, road)
        bare = pd_scan(scan, perc.is_ground)
        yield SensedFrame(truth, scan, perc, dets, visibility(truth, scan, reach),
                          pd_for(bare) if pd_for is not None else None, bare, road)


def pd_scan(scan: sensors.Scan, is_ground: np.ndarray) -> sensors.Scan:
    """What the occlusion-aware P_D reads of ``scan``: no points, and its range image with the returns the
    perception called ground removed (inf: a ground return lies beyond where any ray the P_D counts enters a box,
    so it never blocks; sensors/occlusion.py) and the rest rounded to :data:`PD_RANGE_STEP_M`. Small enough to
    cache (about 20 kB a frame compressed on the highway benchmark, against 80 kB with the ground)."""
    ranges = scan.ranges / PD_RANGE_STEP_M  # rounded in place below: inf stays inf, so no finite mask is needed
    if len(scan.ray) and ranges.size:
        ground_rays = scan.ray[is_ground & (scan.ray >= 0)]
        ranges.reshape(-1)[ground_rays] = np.inf
    np.rint(ranges, out=ranges)
    ranges *= PD_RANGE_STEP_M
    return sensors.Scan(points=np.zeros((0, 3)), source=np.zeros(0, dtype=np.int64), origin=scan.origin,
                        ranges=ranges, ray=np.zeros(0, dtype=np.int64), azimuths=scan.azimuths,
                        elevations=scan.elevations, pose=scan.pose)


def rng_streams(seed: int) -> dict[str, np.random.Generator]:
    """Independent generators, one per consumer, derived from the scenario seed."""
    seqs = np.random.SeedSequence(seed).spawn(len(STREAMS))
    return {name: np.random.default_rng(s) for name, s in zip(STREAMS, seqs)}


def sensing_setup(scn: Scenario, rngs: dict[str, np.random.Generator], policy: Callable | None = None):
    """The traffic source of ``scn`` (a highway-env environment with ``[env]``, its ego driven by ``policy`` when
    given, else our scripted traffic), its roadside boxes (K, 7) drawn from ``rngs["roadside"]`` and the
    perception's road map."""
    from ..world.envsource import make_simulation

    sim = make_simulation(scn, policy)
    centres = lane_centres(sim.network)  # sampled once for the roadside objects and the road map
    static = roadside_objects(sim.network, scn.roadside, rngs["roadside"], centres)
    return sim, static, road_map(sim.network, centres)


def road_map(network, centres: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> sensors.RoadMap:
    """The perception's road map (lane centre lines and half widths) of a highway-env road network; ``centres``:
    its lane_centres when the caller has them already."""
    return sensors.RoadMap(*(centres if centres is not None else lane_centres(network)))


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

    ``trucks`` marks the tracks whose last associated detection was truck-long (testbed.tracking.builtin
    truck_tracks); their P_D is that of a truck-sized box (:data:`TRUCK_BOX_M`). With the car box a truck's own
    rear face, 6-9 m before its centre and so nearer than a car box's entry, "blocked" the view of it: a truck
    20 m behind, hit by 1000 points a scan, got P_D 0 and its track was never updated. (A truck box for every
    track would not do: the car just ahead of a hidden car then lies at the box's entry and no longer hides it.)"""
    lidar = scn.sensor.lidar
    configs: dict[float, sensors.OcclusionConfig] = {}

    def for_scan(scan: sensors.Scan):
        def pd_of(xy: np.ndarray, nominal: float, trucks: np.ndarray | None = None) -> np.ndarray:
            nominal = float(nominal)
            cfg = configs.get(nominal)
            if cfg is None:
                cfg = configs[nominal] = sensors.OcclusionConfig.from_lidar(
                    lidar, pd_nominal=nominal, min_points=scn.sensor.perception.cluster.min_points,
                    full_points=scn.sensor.occlusion_pd_full_points)
            xy = np.asarray(xy, dtype=np.float64)[:, :2]
            heading = road.heading_at(xy) if len(xy) else None
            occ = sensors.detection_probability(scan, xy, cfg, heading=heading)
            if trucks is not None and np.any(trucks):
                trucks = np.asarray(trucks, dtype=bool)
                occ[trucks] = sensors.detection_probability(scan, xy[trucks], cfg, size_m=TRUCK_BOX_M,
                                                            heading=None if heading is None else heading[trucks])
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
    return sensors.Scan(points=np.zeros((0, 3)), source=np.zeros(0, dtype=np.int64), origin=scan.origin,
                        ranges=np.full_like(scan.ranges, np.inf), ray=np.zeros(0, dtype=np.int64),
                        azimuths=scan.azimuths, elevations=scan.elevations, pose=scan.pose)


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
    ids, counts = np.unique(scan.source[scan.source >= 0], return_counts=True)
    n_points = np.zeros(len(truth.ids), dtype=np.int64)
    if len(ids):
        at = np.minimum(np.searchsorted(ids, truth.ids), len(ids) - 1)
        hit = ids[at] == truth.ids
        n_points[hit] = counts[at[hit]]
    in_range = np.hypot(*(truth.xy - scan.origin[:2]).T) <= max_range_m
    return n_points, in_range


