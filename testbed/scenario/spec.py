"""Scenario files: typed, frozen, strict (``scenarios/*.toml``).

A scenario says everything a run needs: the road, the roadside objects, the vehicles and their scripted
behaviours, the ego car that carries the LiDAR, the sensor and perception settings, the tracker and the
scoring. ``load_scenario(path)`` raises :class:`~testbed.config.strict.ConfigError` (one line naming the dotted
key and the allowed values) on any malformed file. See ``docs/scenarios.md`` for every key.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roadtrack.sensors import LidarConfig, PerceptionConfig

from ..config import (ConfigError, field, find_file, from_dict, non_negative, positive, read_toml_file, shipped_dir,
                      shipped_names, to_dict)
from .env import EnvSpec, check_env_scenario
from ..config.limits import at_most, check_folder_name, check_frames, check_scenario, seed_field
from .moving import MovingTestSpec

SCENARIO_DIR = shipped_dir("scenario")
"""The shipped scenarios' folder (testbed/config/files.py, :func:`~testbed.config.files.shipped_dir`)."""

BEHAVIOURS = ("idm", "hold_speed", "follow")
ROAD_KINDS = ("straight", "curved", "u_turn", "motorway")
PIPELINES = ("full", "thesis")
RECORD_LEVELS = ("full", "default", "light", "tracks")
"""What a run's recording keeps, most first (testbed/recording/levels.py says what each level holds)."""
LANE_WIDTH_M = 4.0  # highway-env's StraightLane.DEFAULT_WIDTH (testbed/world/simulation.py LANE_WIDTH): lanes' spacing


@dataclass(frozen=True)
class LaneChange:
    """Scripted lane change: at ``at_s`` seconds the vehicle steers to lane ``lane`` (0 = rightmost)."""

    at_s: float = field(doc="time of the manoeuvre [s]", **non_negative(), **at_most("duration_s"))
    lane: int = field(doc="target lane index", **non_negative())


@dataclass(frozen=True)
class VehicleSpec:
    """One vehicle. ``position_m`` is the longitudinal position along the road's first segment [m]."""

    name: str = field("", doc="label shown in the viewer (default car<ID>)")
    lane: int = field(0, doc="start lane, 0 = first lane of the segment", **non_negative())
    position_m: float = field(0.0, doc="longitudinal start position along the first segment [m]")
    speed_mps: float = field(25.0, doc="initial speed [m/s]", **non_negative(), **at_most("speed_mps"))
    target_speed_mps: float | None = field(None, doc="cruise speed [m/s] (default: the initial speed)",
                                           **non_negative(), **at_most("speed_mps"))
    behaviour: str = field("idm", doc="idm: IDM car-following; hold_speed: cruise control ignoring "
                           "traffic; follow: keep gap_m to the car ahead", choices=BEHAVIOURS)
    gap_m: float | None = field(None, doc="bumper-to-bumper gap kept by behaviour 'follow' [m]", **positive(),
                               **at_most("road_length_m"))
    mobil: bool = field(False, doc="allow free MOBIL lane changes (behaviour idm)")
    lane_changes: tuple[LaneChange, ...] = field((), doc="scripted lane changes")
    length_m: float = field(5.0, doc="box length [m]", **positive(), **at_most("vehicle_size_m"))
    width_m: float = field(2.0, doc="box width [m]", **positive(), **at_most("vehicle_size_m"))
    height_m: float = field(1.6, doc="box height [m]", **positive(), **at_most("vehicle_size_m"))

    def __post_init__(self) -> None:
        if self.behaviour == "follow" and self.gap_m is None:
            raise ConfigError("gap_m", "behaviour 'follow' needs gap_m (> 0)")
        times = [c.at_s for c in self.lane_changes]
        if times != sorted(times):
            raise ConfigError("lane_changes", "must be in increasing at_s order")


@dataclass(frozen=True)
class ConvoySpec:
    """``count`` cars in one lane, ``gap_m`` bumper to bumper, the first (front) at ``front_position_m``."""

    count: int = field(5, doc="number of cars", **positive(), **at_most("vehicles"))
    lane: int = field(0, doc="lane", **non_negative())
    front_position_m: float = field(60.0, doc="longitudinal position of the front car [m]")
    gap_m: float = field(10.0, doc="bumper-to-bumper gap [m]", **positive(), **at_most("road_length_m"))
    speed_mps: float = field(22.0, doc="speed of every car [m/s]", **non_negative(), **at_most("speed_mps"))
    behaviour: str = field("follow", doc="behaviour of the followers (the front car holds speed)",
                           choices=BEHAVIOURS)
    length_m: float = field(5.0, doc="box length [m]", **positive(), **at_most("vehicle_size_m"))
    width_m: float = field(2.0, doc="box width [m]", **positive(), **at_most("vehicle_size_m"))
    height_m: float = field(1.6, doc="box height [m]", **positive(), **at_most("vehicle_size_m"))

    def vehicles(self) -> tuple[VehicleSpec, ...]:
        size = dict(length_m=self.length_m, width_m=self.width_m, height_m=self.height_m)
        pitch = self.gap_m + self.length_m
        out = [VehicleSpec(name=f"convoy{0}", lane=self.lane, position_m=self.front_position_m,
                           speed_mps=self.speed_mps, behaviour="hold_speed", **size)]
        for k in range(1, self.count):
            gap = self.gap_m if self.behaviour == "follow" else None
            out.append(VehicleSpec(name=f"convoy{k}", lane=self.lane,
                                   position_m=self.front_position_m - k * pitch, speed_mps=self.speed_mps,
                                   behaviour=self.behaviour, gap_m=gap, **size))
        return tuple(out)


@dataclass(frozen=True)
class RoadSpec:
    """Road geometry. ``curved``: straight, arc, straight; ``u_turn``: highway-env's U-turn road;
    ``motorway``: a straight carriageway of ``lanes`` lanes in +x and, beyond a median of ``median_m``, the
    opposite carriageway of ``lanes`` lanes in -x (its lane ``lanes - 1`` next to the median)."""

    kind: str = field("straight", doc="road geometry", choices=ROAD_KINDS)
    lanes: int = field(3, doc="lanes per direction (u_turn: always 2)", check=(lambda v: 1 <= v <= 8, "1..8"))
    length_m: float = field(2000.0, doc="length of each straight segment [m]", **positive(),
                            **at_most("road_length_m"))
    curve_radius_m: float = field(300.0, doc="curved: radius of the arc's first lane [m]", **positive(),
                                  **at_most("road_length_m"))
    curve_angle_deg: float = field(45.0, doc="curved: turn angle, > 0 turns left [deg]",
                                   check=(lambda v: 0 < abs(v) <= 180, "0 < |angle| <= 180"))
    speed_limit_mps: float = field(30.0, doc="speed limit [m/s]", **positive(), **at_most("speed_mps"))
    median_m: float = field(4.0, doc="motorway: width of the median between the carriageways' inner lane "
                            "edges [m]", **positive(), **at_most("offset_m"))

    def __post_init__(self) -> None:
        width = (self.lanes - 1) * LANE_WIDTH_M
        if self.kind == "curved" and self.curve_angle_deg > 0 and self.curve_radius_m <= width:
            raise ConfigError("curve_radius_m", f"{self.curve_radius_m:g} m is too small for a left turn of "
                              f"{self.lanes} lanes; allowed: > {width:g} m (the road width between the outer "
                              "lanes' centres)")


@dataclass(frozen=True)
class RoadsideSpec:
    """Static objects beside the road: they are what makes the LiDAR pipeline's clutter."""

    barriers: bool = field(True, doc="guard-rail segments along both road edges")
    barrier_offset_m: float = field(1.5, doc="distance from the road edge to the barriers [m]", **non_negative(),
                                     **at_most("offset_m"))
    post_spacing_m: float = field(40.0, doc="spacing of posts along both edges, 0 = none [m]", **non_negative(),
                                   **at_most("road_length_m"))
    trees_per_km: float = field(20.0, doc="trees (0.4 m trunk, crown from 2.2-3.5 m up) per km per side",
                                limit="roadside_objects", **non_negative())
    bushes_per_km: float = field(3.0, doc="bushes (0.8-2.5 m high) per km per side", limit="roadside_objects",
                                 **non_negative())
    signs_per_km: float = field(2.0, doc="sign panels per km per side", limit="roadside_objects", **non_negative())


def _speed_range() -> dict:
    return {"check": (lambda v: 0 <= v[0] <= v[1], "[min, max] with 0 <= min <= max"), **at_most("speed_mps")}


def _size_range() -> dict:
    return {"check": (lambda v: 0 < v[0] <= v[1], "[min, max] with 0 < min <= max"), **at_most("vehicle_size_m")}


def _lane_list() -> dict:
    return {"check": (lambda v: all(i >= 0 for i in v), "a list of lane indices >= 0")}


def _share() -> dict:
    return {"check": (lambda v: 0 <= v <= 1, "in [0, 1]")}


@dataclass(frozen=True)
class TrafficSpec:
    """Random background traffic around the ego car, drawn from the scenario seed (``testbed/world/traffic.py``).

    Give ``count`` or ``density_per_km_lane``, not both (an error); with neither (the default) there is no
    background traffic and the scenario runs exactly as scripted. Traffic lives in a window from
    ``window_behind_m`` behind to ``window_ahead_m`` ahead of the ego car: a vehicle leaving it is removed,
    and new vehicles (each with a new id) enter at its edges at the rate that keeps the density.
    ``hold_speed`` vehicles ignore traffic and run into slower cars ahead: in traffic, script cars with
    ``idm`` or ``follow``.
    """

    count: int = field(0, doc="background vehicles in the window at the start; the density this makes is "
                       "kept afterwards", **non_negative(), **at_most("vehicles"))
    density_per_km_lane: float = field(0.0, doc="background vehicles per km per lane, kept in the window",
                                       limit="vehicles", **non_negative())
    lanes: tuple[int, ...] | None = field(None, doc="lanes of the ego's carriageway with traffic (default: "
                                          "all)", **_lane_list())
    opposite_lanes: tuple[int, ...] | None = field(None, doc="motorway: lanes of the opposite carriageway "
                                                   "with traffic (default: all, [] = none)", **_lane_list())
    speed_mps: tuple[float, float] = field((22.0, 33.0), doc="range of car speeds [m/s]", **_speed_range())
    mobil_share: float = field(0.0, doc="share of cars that change lanes by MOBIL (trucks keep their lane)",
                               **_share())
    idm_spread: float = field(0.0, doc="relative spread s: each vehicle's IDM time gap, jam distance and "
                              "target speed (relative to its start speed) are scaled by U(1 - s, 1 + s)",
                              check=(lambda v: 0 <= v < 1, "in [0, 1)"))
    truck_share: float = field(0.0, doc="share of trucks among the vehicles of truck_lanes", **_share())
    truck_lanes: tuple[int, ...] | None = field(None, doc="lanes (of either carriageway) where trucks drive "
                                                "(default: all)", **_lane_list())
    truck_speed_mps: tuple[float, float] = field((22.0, 25.0), doc="range of truck speeds [m/s]",
                                                 **_speed_range())
    car_length_m: tuple[float, float] = field((4.2, 5.0), doc="range of car lengths [m]", **_size_range())
    car_width_m: tuple[float, float] = field((1.75, 2.0), doc="range of car widths [m]", **_size_range())
    car_height_m: tuple[float, float] = field((1.4, 1.7), doc="range of car heights [m]", **_size_range())
    truck_length_m: tuple[float, float] = field((12.0, 18.75), doc="range of truck lengths [m]",
                                                **_size_range())
    truck_width_m: tuple[float, float] = field((2.45, 2.55), doc="range of truck widths [m]", **_size_range())
    truck_height_m: tuple[float, float] = field((3.4, 4.0), doc="range of truck heights [m]", **_size_range())
    min_gap_m: float = field(8.0, doc="least bumper-to-bumper gap to any vehicle when a vehicle is spawned "
                             "(which also starts no faster than its IDM gap to the leader allows) [m]",
                             **positive(), **at_most("road_length_m"))
    window_behind_m: float = field(300.0, doc="traffic is kept from this far behind the ego car [m]",
                                   **positive(), **at_most("road_length_m"))
    window_ahead_m: float = field(400.0, doc="to this far ahead of the ego car [m]", **positive(),
                                  **at_most("road_length_m"))
    position_jitter_m: float = field(0.0, doc="scripted vehicles (not the ego) start U(-j, j) from their "
                                     "position_m [m]", **non_negative(), **at_most("road_length_m"))
    speed_jitter_mps: float = field(0.0, doc="scripted vehicles (not the ego) start U(-j, j) from their "
                                    "speed_mps (and cruise at it unless target_speed_mps is set) [m/s]",
                                    **non_negative(), **at_most("speed_mps"))

    def __post_init__(self) -> None:
        if self.count > 0 and self.density_per_km_lane > 0:
            raise ConfigError("density_per_km_lane", "give count or density_per_km_lane, not both")

    @property
    def enabled(self) -> bool:
        """Whether there is background traffic."""
        return self.count > 0 or self.density_per_km_lane > 0


@dataclass(frozen=True)
class ClutterSpec:
    """Optional Poisson clutter added on top of the pipeline's own (the papers' experiments)."""

    density_per_m2: float = field(0.0, doc="Poisson clutter density [1/m^2], 0 = none", limit="clutter_points",
                                  **non_negative())
    radius_m: float = field(70.0, doc="clutter disk radius around the sensor [m]", **positive(),
                            **at_most("lidar_range_m"))


@dataclass(frozen=True)
class RadarSpec:
    """The radar of ``sensor.extra = ["radar"]`` (testbed/sensing/radar.py): on the ego's centre, looking along its
    heading; per vehicle centre within range and field of view a detection [range, azimuth, range-rate] with
    probability ``pd``, Gaussian noise, and Poisson clutter uniform over range x azimuth x range-rate. It sees
    through other vehicles (no occlusion model) [D]."""

    range_m: float = field(160.0, doc="largest range [m]", **positive())
    fov_deg: float = field(90.0, doc="field of view [deg], centred on the ego's heading",
                           check=(lambda v: 0 < v <= 360, "in (0, 360]"))
    sigma_r_m: float = field(0.25, doc="range noise std [m]", **positive())
    sigma_az_deg: float = field(1.0, doc="azimuth noise std [deg]", **positive())
    sigma_rr_mps: float = field(0.1, doc="range-rate noise std [m/s]", **positive())
    pd: float = field(0.9, doc="detection probability of a vehicle within range and field of view",
                      check=(lambda v: 0 <= v <= 1, "in [0, 1]"))
    clutter_per_scan: float = field(1.0, doc="mean Poisson clutter detections per scan", **non_negative())
    max_range_rate_mps: float = field(50.0, doc="clutter range-rates are uniform in +-this [m/s]", **positive())


@dataclass(frozen=True)
class OutageSpec:
    """A forced sensor outage over [start_s, end_s): with ``vehicles = []`` the whole sensor returns nothing (no
    points, a range image of inf); with names, those vehicles are taken out of the ray-cast scene (no return from
    them, they hide nothing). The tracker is not told: its occlusion-aware P_D stays nominal (paper 002's forced
    loss, P_D = 0 while the filter keeps its P_D)."""

    start_s: float = field(doc="start of the outage [s]", **non_negative(), **at_most("duration_s"))
    end_s: float = field(doc="end of the outage [s] (exclusive; at or beyond duration_s: to the end of the run)",
                         **positive(), **at_most("duration_s"))
    vehicles: tuple[str, ...] = field((), doc="names of the scripted vehicles (not the ego) taken out of the "
                                      "scene; empty: the whole sensor is off")

    def __post_init__(self) -> None:
        if not self.start_s < self.end_s:
            raise ConfigError("end_s", f"{self.end_s:g} s is not after start_s = {self.start_s:g} s; allowed: "
                              "end_s > start_s")

    def active(self, time: float) -> bool:
        """Whether the outage covers time [s] (frames at start_s <= t < end_s, to 1 ns)."""
        return self.start_s - 1e-9 <= time < self.end_s - 1e-9


@dataclass(frozen=True)
class SensorSpec:
    """The LiDAR and its perception stack. ``pipeline = "thesis"`` presets every perception key the file
    does not set to the thesis's plain pipeline (no map ROI, fixed 0.8 m height bound, no fragment
    merging or vehicle splitting, L-shape centres), and switches off occlusion-aware P_D and the
    moving-object test unless the file sets them."""

    pipeline: str = field("full", doc="full: the production-like stack (map ROI, range-aware height bound, "
                          "merged fragments, vehicle box centres, occlusion-aware P_D, moving-object test); "
                          "thesis: the thesis's plain pipeline", choices=PIPELINES)
    lidar: LidarConfig = field(LidarConfig(), doc="beam pattern (preset hdl32e, vlp16, hdl64e, vls128), "
                               "mounting, noise, dropout, attitude noise")
    perception: PerceptionConfig = field(PerceptionConfig(), doc="ground segmentation, clustering, selection, "
                                         "box fit")
    occlusion_pd: bool = field(True, doc="give the tracker a per-track P_D from each scan's range image: near 0 "
                               "in the shadow of a nearer object or beyond the beams' reach (sensors/occlusion.py)")
    occlusion_pd_floor: float = field(0.0, doc="least P_D the occlusion-aware input gives a track within range "
                                      "(0: a hidden track coasts without losing score; 0.2: it is dropped after "
                                      "about 6 s hidden with the default score management)",
                                      check=(lambda v: 0 <= v <= 1, "in [0, 1]"))
    occlusion_pd_full_points: int = field(11, doc="LiDAR rays on a car at which the occlusion-aware P_D reaches the "
                                          "tracker's nominal P_D, rising linearly from the clustering's min_points "
                                          "(perception detects few-point cars only sometimes; 11 fits the P_D "
                                          "measured on dense_motorway, docs/perception.md: its break-ups 1.15 -> "
                                          "0.97 %, 3 seeds); 0: a step at min_points",
                                          check=(lambda v: 0 <= v <= 1000, "in [0, 1000]"))
    occlusion_pd_edge_on: bool = field(True, doc="the occlusion-aware P_D of a car seen low (its visible rays all "
                                       "below perception's min_height_m, i.e. far away) ramps with the seen width "
                                       "of its front or rear face from 0.3 to 1.1 m, as perception's edge-on test "
                                       "drops a low object narrow across the line of sight (a car's side seen "
                                       "along it): measured P_D 0.15-0.21 where the P_D said 0.74 (issue 29)")
    clutter: ClutterSpec = field(ClutterSpec(), doc="added Poisson clutter")
    extra: tuple[str, ...] = field((), doc="further sensors by name, sensed beside the LiDAR (testbed/sensing/"
                                   "registry.py, plug-ins of the entry point group roadtrack.sensors); their data "
                                   "is in each sensed frame's others (default: none)")
    radar: RadarSpec = field(RadarSpec(), doc="the radar's settings, used when sensor.extra names \"radar\"")
    outages: tuple[OutageSpec, ...] = field((), doc="forced sensor outages (default: none), e.g. "
                                            "[{ start_s = 8.0, end_s = 20.0, vehicles = [\"right\"] }]: the "
                                            "named cars vanish from the scan, or with vehicles = [] the whole "
                                            "sensor (no points, no added clutter) while the tracker keeps its "
                                            "nominal P_D (paper 002's forced loss; docs/trackloss.md)")

    def outage_at(self, time: float) -> tuple[bool, frozenset[str]]:
        """(whole sensor off, names of the vehicles out of the scene) at time [s]."""
        on = [o for o in self.outages if o.active(time)]
        return any(not o.vehicles for o in on), frozenset(n for o in on for n in o.vehicles)


@dataclass(frozen=True)
class TrackerSpec:
    """A tracker: a named preset plus three typed parameter tables (listed under "Tracker parameters" by
    `testbed keys`). Keys are validated against the filter, associator and manager the name selects."""

    name: str = field("jpda-kf", doc="[<wrapper>-]<associator>-<filter>, a preset that fills the tables below, "
                      "see `testbed trackers`")
    filter: dict[str, Any] = field({}, doc="filter parameters (motion and measurement models, SVSF layers, IMM "
                                   "modes); see Tracker parameters below")
    associator: dict[str, Any] = field({}, doc="associator parameters (gate, P_D, clutter density, JPDA method)")
    management: dict[str, Any] = field({}, doc="track management: kind (score or m_of_n), initiation, "
                                       "confirmation, deletion, coasting, duplicate pruning")
    stitch_s: float = field(0.0, doc="track-to-track stitching of the built-in trackers: a newly confirmed track "
                            "takes the label of a confirmed track deleted at most this many seconds before when it "
                            "lies in that track's constant-velocity prediction (testbed/tracking/stitch.py); the "
                            "run counts the stitches (scores.json stitched_tracks); 0: off",
                            check=(lambda v: 0 <= v <= 60, "in [0, 60]"))
    box: bool = field(False, doc="box tracking: each track of a built-in tracker also estimates its bird's-eye-view "
                      "box (heading, length, width) from the perception's fitted boxes (trackers/box.py); "
                      "tracks.parquet gets heading, length, width, the recording the track boxes, scores.json "
                      "box-overlap (BEV IoU) HOTA, MOTA, IDF1 beside the centre-distance ones")
    sensors: tuple[str, ...] = field(("lidar",), doc="the sensors the built-in tracker takes, in update order: the "
                                     "first runs the whole step (life cycle, births), each further one a sequential "
                                     "update of the same frame (Tracker.update); names from lidar and sensor.extra "
                                     "(e.g. [\"radar\"] or [\"lidar\", \"radar\"]; a radar needs a KF-, EKF- or "
                                     "IMM-based tracker)", check=(lambda v: len(v) >= 1 and len(set(v)) == len(v),
                                                                  "one name or more, each once"))

    def build(self, name: str | None = None):
        """The trackers.Tracker of this spec; ParamError on bad parameters. ``name`` overrides the preset
        (``--tracker``): the tables' keys that the other tracker does not have are then left out (they were
        validated against this spec's own tracker when the scenario was loaded)."""
        from roadtrack.trackers import make_tracker

        return make_tracker(name or self.name, filter=self.filter, associator=self.associator,
                            management=self.management, lenient=name is not None and name != self.name)


@dataclass(frozen=True)
class ScoringSpec:
    match_distance_m: float = field(3.0, doc="track-to-truth association distance [m]", **positive(),
                                     **at_most("lidar_range_m"))
    correct_fraction: float = field(0.5, doc="a confirmed track is correct when matched to one vehicle for "
                                    "at least this fraction of its confirmed life",
                                    check=(lambda v: 0 < v <= 1, "in (0, 1]"))
    visible_min_points: int = field(1, doc="a vehicle is visible in a frame when at least this many LiDAR "
                                    "points hit it (cars seen, visible-truth MOT metrics)", **positive())
    similarity_scale_m: float | None = field(None, doc="MOT metrics: distance [m] at which the similarity "
                                             "1 - d / scale reaches 0, so a CLEAR / Identity match (HOTA at "
                                             "alpha 0.5) needs d <= scale / 2 (default: match_distance_m)",
                                             **positive(), **at_most("lidar_range_m"))


@dataclass(frozen=True)
class RecordSpec:
    level: str = field("default", doc="what the recording keeps: full (every LiDAR point, the truth-coloured "
                       "copy, occlusion shadows), default (the point cloud thinned: every ground_decimation-th "
                       "ground point, up to about 256 points per vehicle or detection, every 8th other object point), "
                       "light (no point cloud), tracks (truth and tracks only); testbed run --record overrides it",
                       choices=RECORD_LEVELS)
    lidar_every: int = field(1, doc="log the point cloud every N frames (0 = never)", **non_negative())
    max_lidar_frames: int = field(1200, doc="log the point cloud on at most this many frames: a longer run logs "
                                  "it every ceil(frames / N)-th frame (if more than lidar_every), so that the web "
                                  "viewer can hold the recording (0 = no limit)", **non_negative())
    ground_decimation: int = field(16, doc="the default level logs every Nth ground point (full: all)",
                                   **positive())


@dataclass(frozen=True)
class Scenario:
    name: str = field(doc="scenario name, also its output folder runs/<name> (letters, digits, '.', '_', '-')",
                      validate=check_folder_name)
    description: str = field("", doc="one-line description")
    seed: int = field(0, doc="master seed: every random stream derives from it", **seed_field())
    duration_s: float = field(20.0, doc="simulated time [s]", **positive(), **at_most("duration_s"))
    rate_hz: float = field(10.0, doc="sensor (and tracker) rate [Hz]", **positive(), **at_most("rate_hz"))
    physics_substeps: int = field(1, doc="highway-env physics ticks per sensor frame", **positive(),
                                  **at_most("physics_substeps"))
    road: RoadSpec = field(RoadSpec(), doc="road")
    roadside: RoadsideSpec = field(RoadsideSpec(), doc="roadside objects")
    ego: VehicleSpec = field(VehicleSpec(name="ego"), doc="the car carrying the LiDAR")
    vehicles: tuple[VehicleSpec, ...] = field((), doc="other vehicles")
    convoy: ConvoySpec | None = field(None, doc="optional convoy, added after `vehicles`")
    traffic: TrafficSpec = field(TrafficSpec(), doc="random background traffic (default: none)")
    env: EnvSpec | None = field(None, doc="a registered highway-env environment as the traffic source, instead of road, ego, vehicles, convoy and traffic (testbed/world/envsource.py)")
    sensor: SensorSpec = field(SensorSpec(), doc="sensor")
    moving_test: MovingTestSpec = field(MovingTestSpec(), doc="moving-object test at track level: static "
                                        "objects are tracked but not reported (testbed/tracking/moving.py)")
    tracker: TrackerSpec = field(TrackerSpec(), doc="tracker")
    scoring: ScoringSpec = field(ScoringSpec(), doc="scoring")
    record: RecordSpec = field(RecordSpec(), doc="recording")

    def __post_init__(self) -> None:
        check_frames(self.duration_s, self.rate_hz)

    @property
    def dt(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def n_frames(self) -> int:
        return int(round(self.duration_s * self.rate_hz)) + 1

    def all_vehicles(self) -> tuple[VehicleSpec, ...]:
        """Ego first (id 0), then ``vehicles``, then the convoy: the index is the vehicle id."""
        extra = self.convoy.vehicles() if self.convoy is not None else ()
        return (self.ego, *self.vehicles, *extra)


def apply_overrides(data: dict, overrides: dict[str, Any]) -> dict:
    """Return a copy of ``data`` with dotted keys set, e.g. ``{"sensor.clutter.density_per_m2": 1e-2}``.

    List items are addressed by index (``vehicles.0.speed_mps``).
    """
    out = copy.deepcopy(data)
    for dotted, value in overrides.items():
        node: Any = out
        parts = dotted.split(".")
        for i, part in enumerate(parts[:-1]):
            key: Any = int(part) if isinstance(node, list) and part.isdigit() else part
            try:
                node = node[key]
            except (KeyError, IndexError, TypeError):
                if isinstance(node, dict):
                    node[key] = {}
                    node = node[key]
                else:
                    raise ConfigError(".".join(parts[: i + 1]), "cannot be addressed") from None
        last = parts[-1]
        if isinstance(node, list) and last.isdigit():
            node[int(last)] = value
        elif isinstance(node, dict):
            node[last] = value
        else:
            raise ConfigError(dotted, "cannot be addressed")
    return out


def _validate(scn: Scenario) -> Scenario:
    from roadtrack.trackers import ParamError, parse_tracker_name

    try:
        parse_tracker_name(scn.tracker.name)
    except ValueError as err:
        raise ConfigError("tracker.name", str(err).splitlines()[0]) from None
    try:
        scn.tracker.build()
    except ParamError as err:
        raise ConfigError(f"tracker.{err.path}", str(err).split(": ", 1)[-1]) from None
    except (ValueError, TypeError, ArithmeticError) as err:
        raise ConfigError("tracker", str(err).splitlines()[0] if str(err) else type(err).__name__) from None
    check_scenario(scn)  # sizes first: all_vehicles() builds every convoy car
    if scn.env is not None:
        check_env_scenario(scn)  # the spec's checks; building the env is testbed.world.check_world
    lanes = 2 if scn.road.kind == "u_turn" else scn.road.lanes
    paths = ["ego"] + [f"vehicles[{i}]" for i in range(len(scn.vehicles))]
    if scn.convoy is not None:
        paths += ["convoy"] * scn.convoy.count
    for where, v in zip(paths, scn.all_vehicles()):
        used = [v.lane] + [c.lane for c in v.lane_changes]
        if max(used) >= lanes:
            raise ConfigError(f"{where}.lane", f"lane {max(used)} does not exist; allowed: 0..{lanes - 1}")
        if not 0 <= v.position_m <= scn.road.length_m:
            key = "front_position_m" if where == "convoy" else "position_m"
            raise ConfigError(f"{where}.{key}", f"{v.position_m} m is off the road; allowed: 0..{scn.road.length_m}")
    _validate_traffic(scn.traffic, scn.road, lanes)
    _validate_outages(scn)
    if scn.env is None:
        _check_overlaps(scn, paths)
    return scn


def _check_overlaps(scn: Scenario, paths: list[str]) -> None:
    """Refuse scripted vehicles whose boxes overlap at t = 0 (highway-env would crash them all at frame 0).

    Vehicles start on the first segment, lane k at ``k * LANE_WIDTH_M`` across and ``position_m`` along;
    ``traffic.position_jitter_m`` may move every vehicle but the ego by up to j along the road.
    """
    specs = scn.all_vehicles()
    names = list(paths)
    if scn.convoy is not None:
        first = len(paths) - scn.convoy.count
        names[first:] = [f"convoy[{k}]" for k in range(scn.convoy.count)]
    jitter = scn.traffic.position_jitter_m
    for i, a in enumerate(specs):
        for j in range(i + 1, len(specs)):
            b = specs[j]
            room = 0.5 * (a.length_m + b.length_m) + jitter * ((i > 0) + 1)
            if abs(a.lane - b.lane) * LANE_WIDTH_M >= 0.5 * (a.width_m + b.width_m) or \
                    abs(a.position_m - b.position_m) >= room:
                continue
            key = "convoy.gap_m" if names[j].startswith("convoy") and names[i].startswith("convoy") else \
                ("convoy.front_position_m" if names[j].startswith("convoy") else f"{names[j]}.position_m")
            extra = f" + {(i > 0) + 1} x traffic.position_jitter_m" if jitter > 0 else ""
            raise ConfigError(key, f"{names[j]} (lane {b.lane}, position_m {b.position_m:g}) overlaps {names[i]} "
                              f"(lane {a.lane}, position_m {a.position_m:g}) at the start: every car would crash at "
                              f"frame 0; allowed: centres at least {room:g} m apart along the road (half their "
                              f"lengths{extra}), or lanes far enough apart")


def _validate_outages(scn: Scenario) -> None:
    """Vehicle names of ``sensor.outages`` against the scripted vehicles' truth names (ego left out)."""
    names = [v.name or f"car{i}" for i, v in enumerate(scn.all_vehicles())][1:] if scn.env is None else []
    for i, outage in enumerate(scn.sensor.outages):
        for j, name in enumerate(outage.vehicles):
            if name not in names:
                allowed = ", ".join(names) if names else "none (an env scenario has no scripted vehicles)"
                raise ConfigError(f"sensor.outages[{i}].vehicles[{j}]", f"{name!r} is not a scripted vehicle; "
                                  f"allowed: {allowed}")


def _validate_traffic(spec: TrafficSpec, road: RoadSpec, lanes: int) -> None:
    """Lane lists of ``[traffic]`` against the road (``lanes`` lanes per carriageway)."""
    if spec.opposite_lanes and road.kind != "motorway":
        raise ConfigError("traffic.opposite_lanes", f"road.kind {road.kind!r} has no opposite carriageway; "
                          "allowed: [] (or road.kind = 'motorway')")
    for key in ("lanes", "opposite_lanes", "truck_lanes"):
        bad = [i for i in getattr(spec, key) or () if i >= lanes]
        if bad:
            raise ConfigError(f"traffic.{key}", f"lane {bad[0]} does not exist; allowed: 0..{lanes - 1}")


def parse_scenario(data: dict) -> Scenario:
    """Build and validate a :class:`Scenario` from a TOML dict."""
    return _validate(from_dict(Scenario, apply_pipeline_preset(data)))


def apply_pipeline_preset(data: dict) -> dict:
    """``data`` with the keys of ``sensor.pipeline``'s preset filled in where the file does not set them.

    ``thesis``: the perception keys of ``PerceptionConfig.thesis()`` that differ from the full pipeline's
    defaults, ``sensor.occlusion_pd = false`` and ``moving_test.enabled = false``."""
    sensor = data.get("sensor")
    if not isinstance(sensor, dict) or sensor.get("pipeline") != "thesis":
        return data
    out = copy.deepcopy(data)
    sensor = out["sensor"]
    full, thesis = to_dict(PerceptionConfig()), to_dict(PerceptionConfig.thesis())
    perception = sensor.setdefault("perception", {})
    if isinstance(perception, dict):
        for key, value in thesis.items():
            if value != full[key]:
                perception.setdefault(key, value)
    sensor.setdefault("occlusion_pd", False)
    moving = out.setdefault("moving_test", {})
    if isinstance(moving, dict):
        moving.setdefault("enabled", False)
    return out


def read_toml(path: str | Path) -> dict:
    """The TOML dict of a scenario file (a path, or the name of a shipped scenario); a missing, unreadable,
    non-UTF-8 or malformed file is a one-line ConfigError naming it."""
    return read_toml_file(find_file(path, "scenario"))


def load_scenario(path: str | Path, overrides: dict[str, Any] | None = None) -> Scenario:
    """Load ``path`` (a file, or the name of a shipped scenario), with optional dotted-key overrides."""
    data = read_toml(path)
    if overrides:
        data = apply_overrides(data, overrides)
    return parse_scenario(data)


def list_scenarios() -> list[str]:
    """The shipped scenarios' names, sorted (a one-line ConfigError if the installation has none)."""
    return shipped_names("scenario")

