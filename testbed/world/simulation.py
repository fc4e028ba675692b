"""Traffic from highway-env, stepped headless at the sensor rate, as truth frames.

We build highway-env's own ``Road``/``RoadNetwork``/vehicle objects from a :class:`Scenario` and step
``road.act(); road.step(dt)`` directly (what ``AbstractEnv._simulate`` does per physics tick), without the
gym wrapper: its observation and reward code costs more than the traffic and is not needed. Nothing
random is drawn by highway-env here (no MOBIL randomisation, single-successor road graphs); the random
background traffic of ``[traffic]`` (``testbed/world/traffic.py``) draws from its own stream of the scenario seed,
so the same scenario and seed always give the same truth.

Vehicle ids: the ego is 0, the scripted vehicles 1..n in ``Scenario.all_vehicles()`` order, background
vehicles n+1, n+2, ... in spawn order (never reused). A frame holds the vehicles on the road at that time:
the ego first, then the scripted ones, then the background vehicles in the window.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Iterator

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import numpy as np
from highway_env.road.lane import AbstractLane, CircularLane, LineType, StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import RoadObject

from .roadside import clear_of_lanes, roadside_boxes
from ..scenario.spec import RoadsideSpec, RoadSpec, Scenario, TrafficSpec, VehicleSpec
from .stepping import BatchRoad
from .traffic import (BackgroundTraffic, Carriageway, TrafficNetwork, TrafficRoad, jitter_specs, make_carriageway,
                      traffic_rngs)

LANE_WIDTH = StraightLane.DEFAULT_WIDTH  # 4 m
FIRST_SEGMENT = ("a", "b")  # the ego's carriageway starts at node "a" (every road kind)
OPPOSITE_SEGMENT = ("B", "A")  # motorway: the opposite carriageway, from x = length_m back to x = 0


@dataclass(frozen=True)
class TruthFrame:
    """Simulator truth at one sensor frame. K vehicles (ego included, at index 0); K varies with background
    traffic.

    ids (K,) int64 stable vehicle ids; xy (K, 2) centre [m]; heading (K,) [rad]; velocity (K, 2) [m/s];
    size (K, 3) length, width, height [m]; lane (K,) int64 current lane index; crashed (K,) bool.
    """

    frame: int
    time: float
    ids: np.ndarray
    names: tuple[str, ...]
    xy: np.ndarray
    heading: np.ndarray
    velocity: np.ndarray
    size: np.ndarray
    lane: np.ndarray
    crashed: np.ndarray

    @property
    def ego_pose(self) -> np.ndarray:
        """(3,) x, y, yaw of the ego car (the sensor carrier)."""
        return np.array([self.xy[0, 0], self.xy[0, 1], self.heading[0]])

    def boxes(self, exclude_ego: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Vehicle boxes for the LiDAR: ((K, 7) [cx, cy, L, W, H, yaw, z_bottom], (K,) ids)."""
        s = slice(1, None) if exclude_ego else slice(None)
        n = len(self.ids[s])
        boxes = np.column_stack([self.xy[s], self.size[s], self.heading[s], np.zeros(n)])
        return boxes.reshape(n, 7), self.ids[s]


class GapFollower(IDMVehicle):
    """Keeps a bumper-to-bumper gap to the vehicle ahead (PD law on gap and relative speed).

    Without a vehicle ahead it cruises at its target speed like IDM.
    """

    GAP_GAIN = 0.5  # [1/s^2]
    SPEED_GAIN = 1.2  # [1/s]

    def __init__(self, *args, gap_m: float, **kwargs):
        super().__init__(*args, **kwargs)
        self.gap_m = gap_m

    def acceleration(self, ego_vehicle, front_vehicle=None, rear_vehicle=None) -> float:
        if ego_vehicle is not self or front_vehicle is None:
            return super().acceleration(ego_vehicle, front_vehicle, rear_vehicle)
        d = self.lane_distance_to(front_vehicle) - (self.LENGTH + front_vehicle.LENGTH) / 2
        dv = front_vehicle.speed - self.speed
        acc = self.GAP_GAIN * (d - self.gap_m) + self.SPEED_GAIN * dv
        return float(np.clip(acc, self.COMFORT_ACC_MIN, self.COMFORT_ACC_MAX))


def _motorway(net: RoadNetwork, spec: RoadSpec) -> None:
    """Two straight carriageways of ``spec.lanes`` lanes: a->b in +x (lane 0 at y = 0, the rightmost) and,
    beyond the median, B->A in -x (its lane 0 outermost, its lane ``lanes - 1`` next to the median)."""
    c, s, n = LineType.CONTINUOUS_LINE, LineType.STRIPED, LineType.NONE
    lanes, length = spec.lanes, spec.length_m
    fast_y = (lanes - 1) * LANE_WIDTH + LANE_WIDTH + spec.median_m  # centre of the opposite lane lanes-1
    for i in range(lanes):
        types = (c if i == 0 else s, c if i == lanes - 1 else n)
        net.add_lane(*FIRST_SEGMENT, StraightLane([0, i * LANE_WIDTH], [length, i * LANE_WIDTH], line_types=types,
                                                  speed_limit=spec.speed_limit_mps))
    for j in range(lanes):
        y = fast_y + (lanes - 1 - j) * LANE_WIDTH
        types = (c if j == 0 else s, c if j == lanes - 1 else n)
        net.add_lane(*OPPOSITE_SEGMENT, StraightLane([length, y], [0, y], line_types=types,
                                                     speed_limit=spec.speed_limit_mps))


def build_network(spec: RoadSpec) -> tuple[RoadNetwork, tuple[str, str]]:
    """Road network and the (from, to) nodes of its first segment."""
    net = RoadNetwork()
    c, s, n = LineType.CONTINUOUS_LINE, LineType.STRIPED, LineType.NONE
    if spec.kind == "motorway":
        _motorway(net, spec)
        return net, FIRST_SEGMENT
    if spec.kind == "u_turn":
        # Same construction as highway-env's u-turn-v0 (UTurnEnv._make_road), with a configurable length.
        length, radius = spec.length_m, 20.0
        offset = 2 * radius
        y_top = 2 * LANE_WIDTH + offset
        net.add_lane("a", "b", StraightLane([0, y_top - LANE_WIDTH], [length, y_top - LANE_WIDTH],
                                            line_types=(c, s), speed_limit=spec.speed_limit_mps))
        net.add_lane("a", "b", StraightLane([0, y_top], [length, y_top], line_types=(n, c),
                                            speed_limit=spec.speed_limit_mps))
        center = [length, LANE_WIDTH + radius]
        for lane, r in enumerate([radius, radius + LANE_WIDTH]):
            net.add_lane("b", "c", CircularLane(center, r, np.deg2rad(90), np.deg2rad(-90), clockwise=False,
                                                line_types=[[c, s], [n, c]][lane],
                                                speed_limit=spec.speed_limit_mps))
        net.add_lane("c", "d", StraightLane([length, LANE_WIDTH], [0, LANE_WIDTH], line_types=(c, s),
                                            speed_limit=spec.speed_limit_mps))
        net.add_lane("c", "d", StraightLane([length, 0], [0, 0], line_types=(n, c),
                                            speed_limit=spec.speed_limit_mps))
        return net, ("a", "b")
    lanes = spec.lanes
    for i in range(lanes):
        types = (c if i == 0 else s, c if i == lanes - 1 else n)
        net.add_lane("a", "b", StraightLane([0, i * LANE_WIDTH], [spec.length_m, i * LANE_WIDTH],
                                            line_types=types, speed_limit=spec.speed_limit_mps))
    if spec.kind == "straight":
        return net, ("a", "b")
    # curved: straight a->b, arc b->c, straight c->d. highway-env's "clockwise=True" means the phase grows,
    # i.e. a left (counter-clockwise) turn in our right-handed x-y frame.
    theta = np.deg2rad(spec.curve_angle_deg)
    left = theta > 0
    r0 = spec.curve_radius_m
    if left and r0 <= (lanes - 1) * LANE_WIDTH:
        raise ValueError("road.curve_radius_m must exceed the road width for a left turn")
    for i in range(lanes):
        types = (c if i == 0 else s, c if i == lanes - 1 else n)
        if left:
            center, r, phase0 = [spec.length_m, r0], r0 - i * LANE_WIDTH, -np.pi / 2
        else:
            center, r, phase0 = [spec.length_m, -r0], r0 + i * LANE_WIDTH, np.pi / 2
        arc = CircularLane(center, r, phase0, phase0 + theta, clockwise=left, line_types=types,
                           speed_limit=spec.speed_limit_mps)
        net.add_lane("b", "c", arc)
        start = arc.position(arc.length, 0.0)
        heading = theta
        end = start + spec.length_m * np.array([np.cos(heading), np.sin(heading)])
        net.add_lane("c", "d", StraightLane(start, end, line_types=types, speed_limit=spec.speed_limit_mps))
    return net, ("a", "b")


def lane_points(lane: AbstractLane, s: np.ndarray, side: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (P, 2) [m] ``side`` lane widths to the left of the centre line at the arc lengths s (P,) [m], with
    the lane's heading (P,) [rad] and width (P,) [m] there: ``lane.position(s_i, side * lane.width_at(s_i))``.
    A StraightLane at once, with highway-env's own expression (start + s dir + lateral dir_lat, the same
    operations per element, so the same numbers); any other lane point by point."""
    s = np.asarray(s, dtype=np.float64)
    if type(lane) is StraightLane:
        width = np.full(len(s), float(lane.width))
        lateral = side * width
        pts = lane.start + s[:, None] * lane.direction + lateral[:, None] * lane.direction_lateral
        return pts.reshape(-1, 2), np.full(len(s), float(lane.heading)), width
    width = np.array([lane.width_at(si) for si in s], dtype=np.float64)
    pts = np.array([lane.position(si, side * w) for si, w in zip(s, width)], dtype=np.float64)
    return pts.reshape(-1, 2), np.array([lane.heading_at(si) for si in s], dtype=np.float64), width


def lane_polylines(net: RoadNetwork, step_m: float = 2.0) -> list[np.ndarray]:
    """Lane border lines (both sides of every lane), each (P, 2) [m], for drawing the road."""
    lines = []
    for lanes in net.graph.values():
        for lane_list in lanes.values():
            for lane in lane_list:
                s = np.arange(0.0, lane.length + step_m, step_m).clip(max=lane.length)
                for side in (-0.5, 0.5):
                    lines.append(lane_points(lane, s, side)[0])
    return lines


def lane_centres(net: RoadNetwork, step_m: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre lines of every lane, sampled every ``step_m``: points (P, 2) [m], heading (P,) [rad] and
    half width (P,) [m]."""
    pts, heads, half = [np.zeros((0, 2))], [np.zeros(0)], [np.zeros(0)]
    for lanes in net.graph.values():
        for lane_list in lanes.values():
            for lane in lane_list:
                p, h, w = lane_points(lane, np.append(np.arange(0.0, lane.length, step_m), lane.length), 0.0)
                pts.append(p)
                heads.append(h)
                half.append(w / 2)
    return np.concatenate(pts), np.concatenate(heads), np.concatenate(half)


def roadside_objects(net: RoadNetwork, spec: RoadsideSpec, rng: np.random.Generator,
                     centres: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The roadside boxes ``(K, 7)`` of a road network (testbed/world/roadside.py), none of them on a lane;
    ``centres``: the network's :func:`lane_centres` when the caller has them already."""
    boxes = roadside_boxes(road_edges(net), spec, rng)
    return boxes[clear_of_lanes(boxes, *(centres if centres is not None else lane_centres(net)))]


def road_edges(net: RoadNetwork, step_m: float = 1.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Outer road edges: list of (points (P, 2), outward unit normals (P, 2)) [m]."""
    edges = []
    for lanes in net.graph.values():
        for lane_list in lanes.values():
            for idx, sign in ((0, -1.0), (len(lane_list) - 1, 1.0)):
                lane: AbstractLane = lane_list[idx]
                pts, heads, _ = lane_points(lane, np.arange(0.0, lane.length, step_m), sign / 2)
                normal = sign * np.column_stack([-np.sin(heads), np.cos(heads)])
                edges.append((pts.reshape(-1, 2), normal.reshape(-1, 2)))
    return edges


def carriageways(net: RoadNetwork, road: RoadSpec, spec: TrafficSpec) -> list[Carriageway]:
    """The carriageways with background traffic: the ego's (chain from node "a") and the motorway's opposite."""
    n_lanes = 2 if road.kind == "u_turn" else road.lanes
    out = [make_carriageway(net, FIRST_SEGMENT[0], 1.0, spec.lanes if spec.lanes is not None else range(n_lanes))]
    if road.kind == "motorway":
        lanes = spec.opposite_lanes if spec.opposite_lanes is not None else range(n_lanes)
        out.append(make_carriageway(net, OPPOSITE_SEGMENT[0], -1.0, lanes))
    return [cw for cw in out if cw.lanes]


def _make_vehicle(road: Road, spec: VehicleSpec, first: tuple[str, str]):
    lane_index = (*first, spec.lane)
    lane = road.network.get_lane(lane_index)
    pos, heading = lane.position(spec.position_m, 0.0), lane.heading_at(spec.position_m)
    target = spec.target_speed_mps if spec.target_speed_mps is not None else spec.speed_mps
    common = dict(heading=heading, speed=spec.speed_mps, target_lane_index=lane_index, target_speed=target)
    if spec.behaviour == "hold_speed":
        v = ControlledVehicle(road, pos, **common)
    elif spec.behaviour == "follow":
        v = GapFollower(road, pos, enable_lane_change=False, gap_m=spec.gap_m, **common)
    else:
        v = IDMVehicle(road, pos, enable_lane_change=spec.mobil, **common)
    if spec.target_speed_mps is None and spec.speed_mps == 0:
        v.target_speed = 0.0
    v.LENGTH, v.WIDTH = spec.length_m, spec.width_m  # instance attributes: collisions and IDM gaps use them
    v.diagonal = np.sqrt(v.LENGTH**2 + v.WIDTH**2)
    v.HEIGHT = spec.height_m  # [m], read into the truth like LENGTH and WIDTH
    return v


def velocities(vs: list) -> np.ndarray:
    """Each vehicle's ``velocity`` (n, 2) [m/s]: highway-env's speed * (cos, sin)(heading), for all at once when
    none overrides it (NumPy's cos and sin give the same bits for an array as for a scalar), else one by one."""
    if all(type(v).velocity is Vehicle.velocity and type(v).direction is RoadObject.direction for v in vs):
        speed = np.array([v.speed for v in vs], dtype=np.float64)
        heading = np.array([v.heading for v in vs], dtype=np.float64)
        return speed[:, None] * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    return np.array([v.velocity for v in vs], dtype=np.float64).reshape(-1, 2)


class Simulation:
    """Scripted highway-env traffic for one scenario, plus the optional background traffic of ``[traffic]``;
    iterate :meth:`frames` for truth at the sensor rate."""

    def __init__(self, scenario: Scenario):
        self.scenario = scenario
        self.network, first = build_network(scenario.road)
        spec = scenario.traffic
        # np_random is only used by highway-env to break ties between several successor lanes; our road
        # graphs have one successor per lane, but seed it anyway. Both roads step all vehicles at once with
        # highway-env's numbers (stepping.py); TrafficRoad adds the vectorised neighbour search of MOBIL.
        road_cls = TrafficRoad if spec.enabled else BatchRoad
        if spec.enabled:
            self.network = TrafficNetwork.of(self.network)
        self.road = road_cls(network=self.network, np_random=np.random.RandomState(scenario.seed))
        jitter_rng, traffic_rng = traffic_rngs(scenario.seed)
        self.specs = jitter_specs(scenario.all_vehicles(), spec, scenario.road.length_m, jitter_rng)
        for i, vspec in enumerate(self.specs):
            v = _make_vehicle(self.road, vspec, first)
            v.truth_id, v.truth_name = i, vspec.name or ("ego" if i == 0 else f"car{i}")
            self.road.vehicles.append(v)
        self.scripted = tuple(self.road.vehicles)
        self._changes = [list(vspec.lane_changes) for vspec in self.specs]
        self.traffic: BackgroundTraffic | None = None
        if spec.enabled:
            cws = carriageways(self.network, scenario.road, spec)
            self.traffic = BackgroundTraffic(self.road, spec, cws, self.scripted[0], traffic_rng, len(self.specs))
            self.traffic.populate()

    @property
    def vehicles(self) -> list:
        """The vehicles on the road now: ego, scripted, background (highway-env objects)."""
        return self.road.vehicles

    def _truth(self, frame: int, time: float) -> TruthFrame:
        vs = self.road.vehicles
        return TruthFrame(
            frame=frame, time=time, ids=np.array([v.truth_id for v in vs], dtype=np.int64),
            names=tuple(v.truth_name for v in vs),
            xy=np.array([v.position for v in vs], dtype=np.float64).reshape(-1, 2),
            heading=np.array([v.heading for v in vs], dtype=np.float64),
            velocity=velocities(vs),
            size=np.array([[v.LENGTH, v.WIDTH, v.HEIGHT] for v in vs], dtype=np.float64).reshape(-1, 3),
            lane=np.array([v.lane_index[2] for v in vs], dtype=np.int64),
            crashed=np.array([v.crashed for v in vs], dtype=bool),
        )

    def _apply_scripts(self, time: float) -> None:
        for v, changes in zip(self.scripted, self._changes):
            while changes and changes[0].at_s <= time + 1e-9:
                lane = changes.pop(0).lane
                v.target_lane_index = (v.lane_index[0], v.lane_index[1], lane)

    def frames(self) -> Iterator[TruthFrame]:
        """Truth at t = 0, dt, 2 dt, ... duration (``scenario.n_frames`` frames)."""
        scn = self.scenario
        dt = scn.dt / scn.physics_substeps
        for k in range(scn.n_frames):
            time = k * scn.dt
            if k > 0:
                for sub in range(scn.physics_substeps):
                    self._apply_scripts((k - 1) * scn.dt + sub * dt)
                    self.road.act()
                    self.road.step(dt)
                if self.traffic is not None:
                    self.traffic.update(scn.dt)
            yield self._truth(k, time)
