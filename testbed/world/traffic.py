"""Random background traffic around the ego car (the scenario's ``[traffic]`` table).

Background vehicles are highway-env IDM cars and trucks (optionally MOBIL lane changes for cars) on the
carriageways of the road: the ego's and, on a motorway, the opposite one. They live in a *window* from
``window_behind_m`` behind to ``window_ahead_m`` ahead of the ego car, so the O(N^2) neighbour search of
highway-env never sees a 10 km road full of cars:

* at the start each lane of the window gets ``density * window length`` vehicles at uniform random
  positions, never closer than ``min_gap_m`` (bumper to bumper) to any vehicle, scripted ones and the ego
  included; a vehicle starts no faster than the speed at which IDM's desired gap to its leader,
  ``jam + v T + v (v - v_leader) / (2 sqrt(a b))``, fits in the gap (:func:`idm_fit_speed`), so nobody
  starts by braking hard, and a vehicle that would make a scripted follower brake is left out;
* every frame, a background vehicle whose position lies more than ``REMOVE_MARGIN_M`` outside the window
  (or off the road) is removed;
* every frame, vehicles enter at the window's two edges, per lane and vehicle kind, as a Poisson process
  with the rate that keeps the density: vehicles of speed ``v ~ U(speed range)`` at density ``rho`` cross an
  edge that moves at the ego's speed ``c`` at the rate ``rho * E[max(v - c, 0)]`` (from behind: faster than
  the ego; from ahead: ``rho * E[max(c - v, 0)]``, slower than the ego, and all of the opposite
  carriageway's traffic); an entering vehicle's speed is drawn with density proportional to ``|v - c|``.
  That rate assumes every vehicle keeps its speed; IDM car following does not (fast cars queue behind slow
  ones and the queue drifts out of the window), so the rate is also scaled by the density feedback
  ``rho W / max(n, 0.5)`` (clipped to [1/4, 4]), ``n`` the background vehicles now in the lane's part of
  the window, of length ``W``. An entry gets the same start-speed cap from its leader; an entry closer than
  ``min_gap_m`` to a vehicle, or inside the IDM desired gap of the vehicle behind it, waits for the next
  frame (at most ``MAX_PENDING`` per edge and kind).

Every vehicle gets a new integer id (``first_id``, ``first_id + 1``, ...; never reused), so a vehicle that
leaves and a vehicle that enters are distinct cars for scoring.

Positions along a carriageway are *chain coordinates* S [m]: the arc length along lane 0 of its chain of
road segments, in its driving direction.

Randomness: two named streams of the scenario seed (testbed/common/streams.py, the one table of every stream),
``traffic.jitter`` for the jitter of the scripted vehicles and ``traffic.background`` for the background traffic,
so switching on jitter does not change the traffic and no other consumer draws from them.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from highway_env.road.lane import StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle

from ..common import streams
from ..scenario.spec import TrafficSpec, VehicleSpec
from .stepping import BatchRoad, BumperGapIDM, LaneTable

IDM_C = 2.0 * float(np.sqrt(IDMVehicle.COMFORT_ACC_MAX * -IDMVehicle.COMFORT_ACC_MIN))  # 2 sqrt(a b) [m/s]
REMOVE_MARGIN_M = 20.0  # a vehicle is removed this far outside the window [m]
MAX_PENDING = 4  # entries waiting for room, per lane edge and vehicle kind
FEEDBACK_MAX = 4.0  # the density feedback scales the entry rate by at most this factor (or 1 / it)
PLACE_TRIES = 50  # random positions tried per vehicle at the start


def traffic_rngs(seed: int) -> tuple[np.random.Generator, np.random.Generator]:
    """(jitter, background traffic) generators: the streams ``traffic.jitter`` and ``traffic.background``."""
    return streams.generator(seed, "traffic.jitter"), streams.generator(seed, "traffic.background")


def jitter_specs(specs: tuple[VehicleSpec, ...], spec: TrafficSpec, road_length_m: float,
                 rng: np.random.Generator) -> tuple[VehicleSpec, ...]:
    """Scripted vehicles (``specs[1:]``; the ego ``specs[0]`` is kept) with start position and speed moved by
    U(-j, j) [m, m/s]; positions stay on the road, speeds >= 0. Unchanged (no draws) when both j are 0."""
    if spec.position_jitter_m == 0 and spec.speed_jitter_mps == 0:
        return specs
    out = [specs[0]]
    for v in specs[1:]:
        dx, dv = rng.uniform(-1.0, 1.0, size=2) * (spec.position_jitter_m, spec.speed_jitter_mps)
        speed = max(v.speed_mps + dv, 0.0)
        out.append(dataclasses.replace(v, position_m=float(np.clip(v.position_m + dx, 0.0, road_length_m)),
                                       speed_mps=float(speed)))
    return tuple(out)


class TrafficVehicle(BumperGapIDM):
    """IDM car or truck of the background traffic: IDM gaps bumper to bumper (``DISTANCE_WANTED`` [m], per
    instance), so a car does not run into an 18 m truck (testbed/world/stepping.py)."""

    HEIGHT = 1.5  # [m]


class TrafficRoad(BatchRoad):
    """highway-env ``Road`` stepped for all vehicles at once (testbed/world/stepping.py: the same numbers as
    highway-env's per-vehicle loop), with a vectorised neighbour search for the per-vehicle MOBIL decisions.

    ``Road.neighbour_vehicles`` projects every vehicle on the lane in a Python loop: O(N^2) Python calls per
    tick. Here the projections on a straight lane are one NumPy expression over the positions cached at the
    start of :meth:`act` (vehicles do not move while they decide), with highway-env's arithmetic (``np.dot`` of
    2-vectors), so the same vehicles are found (which of two vehicles at exactly the same distance is the
    neighbour aside); curved lanes and road objects fall back to it.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._pos: np.ndarray | None = None
        self._index: dict[int, int] = {}
        self._proj: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}

    def positions(self) -> np.ndarray:
        """(N, 2) vehicle centres [m]."""
        return np.array([v.position for v in self.vehicles], dtype=np.float64).reshape(-1, 2)

    def act(self) -> None:
        self._pos = self.positions()
        self._index = {id(v): i for i, v in enumerate(self.vehicles)}
        try:
            super().act()
        finally:
            self._pos, self._index, self._proj = None, {}, {}

    def _projection(self, lane_index: tuple, lane: StraightLane) -> tuple[np.ndarray, np.ndarray]:
        """Longitudinal coordinates (N,) [m] of every vehicle on ``lane`` and whether it is on it (N,) bool
        (``AbstractLane.on_lane`` with a 1 m margin); cached while the vehicles act."""
        if lane_index in self._proj:
            return self._proj[lane_index]
        pos = self._pos if self._pos is not None else self.positions()
        d0, d1 = pos[:, 0] - lane.start[0], pos[:, 1] - lane.start[1]
        s_v = d0 * lane.direction[0] + d1 * lane.direction[1]  # np.dot(delta, direction), as lane.py
        lat = d0 * lane.direction_lateral[0] + d1 * lane.direction_lateral[1]
        on = ((np.abs(lat) <= lane.width / 2 + 1.0)
              & (s_v >= -lane.VEHICLE_LENGTH) & (s_v < lane.length + lane.VEHICLE_LENGTH))
        if self._pos is not None:
            self._proj[lane_index] = (s_v, on)
        return s_v, on

    def neighbour_vehicles(self, vehicle, lane_index=None):
        """(front, rear) vehicle on ``lane_index`` (default: the vehicle's lane), as ``Road.neighbour_vehicles``."""
        lane_index = lane_index or vehicle.lane_index
        if not lane_index:
            return None, None
        lane = self.network.get_lane(lane_index)
        if type(lane) is not StraightLane or self.objects or self.neighbour_vehicles_connected_lanes:
            return super().neighbour_vehicles(vehicle, lane_index)
        s = lane.local_coordinates(vehicle.position)[0]
        s_v, on = self._projection(lane_index, lane)
        ahead = np.where(on & (s_v >= s), s_v, np.inf)
        behind = np.where(on & (s_v < s), s_v, -np.inf)
        me = self._index.get(id(vehicle)) if self._index else next(
            (i for i, v in enumerate(self.vehicles) if v is vehicle), None)
        if me is not None:
            ahead[me], behind[me] = np.inf, -np.inf
        i, k = int(np.argmin(ahead)), int(np.argmax(behind))
        front = self.vehicles[i] if np.isfinite(ahead[i]) else None
        rear = self.vehicles[k] if np.isfinite(behind[k]) else None
        return front, rear


class TrafficNetwork(RoadNetwork):
    """highway-env ``RoadNetwork`` whose closest-lane lookup (every vehicle, every tick) is one NumPy
    expression over all lanes when they are all straight; the same distance as
    ``AbstractLane.distance_with_heading`` (L1 distance to the lane + |heading error|), first minimum wins.
    Build it with :meth:`of` once the lanes are added."""

    @classmethod
    def of(cls, net: RoadNetwork) -> RoadNetwork:
        """``net`` itself if a lane is not straight, else a TrafficNetwork sharing its graph."""
        out = cls()
        out.graph = net.graph
        lanes = [(f, t, i, lane) for f, tos in net.graph.items() for t, ls in tos.items() for i, lane in enumerate(ls)]
        if not all(type(lane) is StraightLane for *_, lane in lanes):
            return net
        out._index = [(f, t, i) for f, t, i, _ in lanes]
        out._start = np.array([lane.start for *_, lane in lanes], dtype=np.float64)
        out._dir = np.array([lane.direction for *_, lane in lanes], dtype=np.float64)
        out._lat = np.array([lane.direction_lateral for *_, lane in lanes], dtype=np.float64)
        out._length = np.array([lane.length for *_, lane in lanes], dtype=np.float64)
        out._heading = np.array([lane.heading for *_, lane in lanes], dtype=np.float64)
        return out

    def get_closest_lane_index(self, position: np.ndarray, heading: float | None = None) -> tuple:
        delta = np.asarray(position, dtype=np.float64) - self._start
        s = np.einsum("ij,ij->i", delta, self._dir)
        d = np.abs(np.einsum("ij,ij->i", delta, self._lat)) + np.maximum(s - self._length, 0) + np.maximum(-s, 0)
        if heading is not None:
            d = d + np.abs((heading - self._heading + np.pi) % (2 * np.pi) - np.pi)
        return self._index[int(np.argmin(d))]


@dataclass(frozen=True)
class Carriageway:
    """A chain of road segments in driving order, with the lanes that carry background traffic.

    ``starts`` (n_segments + 1,): chain coordinate [m] of each segment's start along its lane 0, and the end.
    ``sign``: +1 for the ego's driving direction, -1 for the opposite carriageway.
    """

    segments: tuple[tuple[str, str], ...]
    starts: np.ndarray
    sign: float
    lanes: tuple[int, ...]

    @property
    def total(self) -> float:
        return float(self.starts[-1])


def chain(net: RoadNetwork, start: str) -> tuple[tuple[str, str], ...]:
    """Segments followed from node ``start`` (our road graphs have one successor per node)."""
    out, node = [], start
    while node in net.graph and len(out) < len(net.graph):
        nxt = next(iter(net.graph[node]))
        out.append((node, nxt))
        node = nxt
    return tuple(out)


def make_carriageway(net: RoadNetwork, start: str, sign: float, lanes: tuple[int, ...]) -> Carriageway:
    segments = chain(net, start)
    lengths = [net.get_lane((*seg, 0)).length for seg in segments]
    return Carriageway(segments, np.concatenate(([0.0], np.cumsum(lengths))), sign, tuple(lanes))


def chain_coordinate(net: RoadNetwork, cw: Carriageway, lane_index, position: np.ndarray) -> float | None:
    """S [m] of a vehicle on segment ``lane_index[:2]`` of ``cw`` (None: not on this carriageway)."""
    if lane_index is None or lane_index[:2] not in cw.segments:
        return None
    k = cw.segments.index(lane_index[:2])
    return float(cw.starts[k] + net.get_lane((*cw.segments[k], 0)).local_coordinates(position)[0])


def chain_coordinates(net: RoadNetwork, cw: Carriageway, lane_indices: list, P: np.ndarray) -> np.ndarray:
    """:func:`chain_coordinate` of n vehicles at once: lane indices (n,), centres P (n, 2) [m]; S (n,) [m], nan
    where a vehicle is not on ``cw`` (the same numbers: stepping.LaneTable.coords is lane.local_coordinates)."""
    table = LaneTable.of(net)
    seg = {s: k for k, s in enumerate(cw.segments)}
    k = np.array([seg.get(tuple(li[:2]), -1) if li is not None else -1 for li in lane_indices], dtype=np.int64)
    out = np.full(len(k), np.nan)
    on = np.flatnonzero(k >= 0)
    if len(on):
        rows = np.array([table.row[(*cw.segments[k[i]], 0)] for i in on], dtype=np.int64)
        out[on] = cw.starts[k[on]] + table.coords(np.asarray(P, dtype=np.float64)[on].reshape(-1, 2), rows)[0]
    return out


def project(net: RoadNetwork, cw: Carriageway, position: np.ndarray) -> float:
    """S [m] of any point: its projection on the nearest segment's lane 0 of ``cw``."""
    best = None
    for k, seg in enumerate(cw.segments):
        lane = net.get_lane((*seg, 0))
        d = lane.distance(position)
        if best is None or d < best[0]:
            best = (d, float(cw.starts[k] + lane.local_coordinates(position)[0]))
    return best[1]


def locate(net: RoadNetwork, cw: Carriageway, lane_id: int, S: float) -> tuple[tuple, np.ndarray, float]:
    """(lane index, centre (2,) [m], heading [rad]) of lane ``lane_id`` at chain coordinate ``S``."""
    k = int(np.clip(np.searchsorted(cw.starts, S, side="right") - 1, 0, len(cw.segments) - 1))
    seg = cw.segments[k]
    point = net.get_lane((*seg, 0)).position(S - cw.starts[k], 0.0)
    lane = net.get_lane((*seg, lane_id))
    s = lane.local_coordinates(point)[0]
    return (*seg, lane_id), lane.position(s, 0.0), float(lane.heading_at(s))


def entry_flux(u_lo: float, u_hi: float) -> tuple[float, float, float]:
    """Entry rate per unit density of vehicles crossing an edge with relative speed u ~ U(u_lo, u_hi) [m/s].

    Returns ``(E[max(u, 0)], w0, w1)`` [m/s]: entering vehicles have ``w = u`` in ``[w0, w1]`` with density
    proportional to ``w`` (faster vehicles cross more often); ``(0, 0, 0)`` when none enters.
    """
    if u_hi <= 0:
        return 0.0, 0.0, 0.0
    w0 = max(u_lo, 0.0)
    if u_hi - u_lo <= 1e-12:
        return u_hi, u_hi, u_hi
    return (u_hi**2 - w0**2) / (2.0 * (u_hi - u_lo)), w0, u_hi


def idm_fit_speed(room: float, v_lead: float, time_wanted: float) -> float | None:
    """Highest speed v [m/s] whose IDM desired gap beyond the jam gap, ``v T + v (v - v_lead) / IDM_C``,
    fits in ``room`` [m] (bumper gap minus jam gap) behind a leader at ``v_lead`` [m/s]; None if room < 0.

    The larger root of ``v^2 / c + v (T - v_lead / c) - room = 0``.
    """
    if room < 0:
        return None
    b = time_wanted - v_lead / IDM_C
    return float(0.5 * IDM_C * (-b + np.sqrt(b * b + 4.0 * room / IDM_C)))


def sample_entry(rng: np.random.Generator, w0: float, w1: float) -> float:
    """Draw ``w`` in ``[w0, w1]`` with density proportional to ``w`` (inverse CDF) [m/s]."""
    return float(np.sqrt(w0**2 + rng.random() * (w1**2 - w0**2)))


@dataclass(frozen=True)
class Draw:
    """A background vehicle to spawn: kind, start speed [m/s], size (L, W, H) [m] and driver parameters."""

    truck: bool
    speed: float
    size: tuple[float, float, float]
    target_speed: float
    time_wanted: float
    jam_gap: float
    mobil: bool


def _apportion(total: int, weights: np.ndarray) -> np.ndarray:
    """Split ``total`` into integers proportional to ``weights`` (largest remainder)."""
    if weights.sum() <= 0:
        return np.zeros(len(weights), dtype=np.int64)
    q = total * weights / weights.sum()
    n = np.floor(q).astype(np.int64)
    n[np.argsort(-(q - n), kind="stable")[: total - int(n.sum())]] += 1
    return n


class BackgroundTraffic:
    """Background vehicles of ``spec`` on ``carriageways`` around ``ego`` (see the module docstring).

    Call :meth:`populate` once, then :meth:`update` once per frame. ``first_id``: id of the first vehicle.
    """

    def __init__(self, road: Road, spec: TrafficSpec, carriageways: list[Carriageway], ego,
                 rng: np.random.Generator, first_id: int):
        self.road, self.spec, self.cws, self.ego, self.rng = road, spec, carriageways, ego, rng
        self.next_id = first_id
        self.streams = [(k, j) for k, cw in enumerate(carriageways) for j in cw.lanes]
        self.rho = spec.density_per_km_lane / 1000.0  # [1/m] per lane
        self.pending: dict[tuple, list[Draw]] = {}

    def windows(self) -> list[tuple[float, float]]:
        """(lo, hi) chain coordinates [m] of the window on each carriageway (may reach beyond the road)."""
        sp, out = self.spec, []
        for cw in self.cws:
            s = project(self.road.network, cw, self.ego.position)
            back, ahead = sp.window_behind_m, sp.window_ahead_m
            out.append((s - back, s + ahead) if cw.sign > 0 else (s - ahead, s + back))
        return out

    def truck_share(self, lane_id: int) -> float:
        lanes = self.spec.truck_lanes
        return self.spec.truck_share if lanes is None or lane_id in lanes else 0.0

    def draw(self, truck: bool, speed: float) -> Draw:
        """Size and driver of a vehicle of start speed ``speed`` [m/s] (always 7 draws)."""
        sp, r = self.spec, self.rng
        ranges = (sp.truck_length_m, sp.truck_width_m, sp.truck_height_m) if truck else (
            sp.car_length_m, sp.car_width_m, sp.car_height_m)
        size = tuple(float(r.uniform(lo, hi)) for lo, hi in ranges)
        f = r.uniform(1.0 - sp.idm_spread, 1.0 + sp.idm_spread, size=3)
        mobil = bool(r.random() < sp.mobil_share) and not truck
        return Draw(truck, speed, size, speed * float(f[2]), IDMVehicle.TIME_WANTED * float(f[0]),
                    TrafficVehicle.DISTANCE_WANTED * float(f[1]), mobil)

    def populate(self) -> None:
        """Fill every lane of the window (the part on the road) at the start."""
        wins = self.windows()
        spans = [tuple(np.clip(wins[k], 0.0, self.cws[k].total)) for k, _ in self.streams]
        length = np.array([hi - lo for lo, hi in spans], dtype=np.float64)
        if self.spec.count > 0:
            self.rho = self.spec.count / max(float(length.sum()), 1.0)
            counts = _apportion(self.spec.count, length)
        else:
            expected = self.rho * length
            counts = np.floor(expected).astype(np.int64) + (self.rng.random(len(expected)) < expected % 1.0)
        for (k, j), (lo, hi), n in zip(self.streams, spans, counts):
            self._populate_lane(k, j, float(lo), float(hi), int(n))

    def _populate_lane(self, k: int, j: int, lo: float, hi: float, n: int) -> None:
        """``n`` vehicles at uniform positions S in [lo, hi] [m] of lane ``j``, then speeds made safe."""
        sp, r = self.spec, self.rng
        occupied = [[s, length, speed, None] for s, length, speed, _ in self._occupants(k, j)]
        share = self.truck_share(j)
        for _ in range(n):
            truck = bool(r.random() < share)
            d = self.draw(truck, float(r.uniform(*(sp.truck_speed_mps if truck else sp.speed_mps))))
            for _ in range(PLACE_TRIES):
                s = float(r.uniform(lo, hi))
                if all(abs(s - o[0]) >= 0.5 * (d.size[0] + o[1]) + sp.min_gap_m for o in occupied):
                    occupied.append([s, d.size[0], d.speed, d])
                    break
        occupied.sort(key=lambda o: -o[0])  # front first: a capped speed caps the followers too
        for lead, o in zip(occupied, occupied[1:]):
            if o[3] is not None:
                room = lead[0] - o[0] - 0.5 * (lead[1] + o[1]) - o[3].jam_gap
                o[2] = min(o[2], idm_fit_speed(max(room, 0.0), lead[2], o[3].time_wanted))
        for i, (s, _, speed, d) in enumerate(occupied):
            follower = occupied[i + 1] if i + 1 < len(occupied) else None
            if d is None or (follower is not None and follower[3] is None and not self._room_for(
                    follower[2], follower[0], follower[1], s, d.size[0], speed)):
                continue  # a scripted vehicle (or nothing: d is None) right behind that would brake hard
            self._spawn(k, j, s, dataclasses.replace(d, speed=speed))

    def update(self, dt: float) -> None:
        """Remove the vehicles outside the window, then let new ones enter at its edges (once per frame).

        ``dt``: time since the last update [s].
        """
        wins = self.windows()
        counts = self._remove(wins)
        for k, j in self.streams:
            cw, (lo, hi) = self.cws[k], wins[k]
            c = cw.sign * self.ego.speed  # the window's speed along the carriageway [m/s]
            share = self.truck_share(j)
            want = self.rho * (min(hi, cw.total) - max(lo, 0.0))
            feedback = float(np.clip(want / max(counts.get((k, j), 0), 0.5), 1.0 / FEEDBACK_MAX, FEEDBACK_MAX))
            for edge, s in (("low", max(lo, 0.0)), ("high", hi)):
                if not 0.0 <= s <= cw.total:
                    continue
                self._enter(k, j, edge, s, c, False, (1.0 - share) * feedback * dt, self.spec.speed_mps)
                self._enter(k, j, edge, s, c, True, share * feedback * dt, self.spec.truck_speed_mps)

    def _enter(self, k: int, j: int, edge: str, s: float, c: float, truck: bool, exposure: float,
               speeds: tuple[float, float]) -> None:
        """Poisson entries of one kind at one edge (chain coordinate ``s`` [m]); ``exposure`` = share *
        feedback * dt [s]."""
        a, b = speeds
        mean_u, w0, w1 = entry_flux(a - c, b - c) if edge == "low" else entry_flux(c - b, c - a)
        queue = self.pending.setdefault((k, j, edge, truck), [])
        for _ in range(int(self.rng.poisson(self.rho * mean_u * exposure))):
            w = sample_entry(self.rng, w0, w1)
            queue.append(self.draw(truck, c + w if edge == "low" else c - w))
        del queue[MAX_PENDING:]
        while queue:
            speed = self._entry_speed(k, j, s, queue[0])
            if speed is None:
                break
            self._spawn(k, j, s, dataclasses.replace(queue.pop(0), speed=speed))

    def _occupants(self, k: int, j: int) -> list[tuple[float, float, float, float]]:
        """(S [m], length [m], speed [m/s], IDM time gap [s]) of every vehicle in, or changing into, lane ``j``
        of carriageway ``k``."""
        cw, net, out = self.cws[k], self.road.network, []
        for v in self.road.vehicles:
            target = getattr(v, "target_lane_index", None) or v.lane_index
            if j in (v.lane_index[2], target[2]):
                s = chain_coordinate(net, cw, v.lane_index, v.position)
                if s is not None:
                    out.append((s, float(v.LENGTH), float(v.speed), float(getattr(v, "TIME_WANTED", 1.5))))
        return out

    def _entry_speed(self, k: int, j: int, s: float, d: Draw) -> float | None:
        """Start speed [m/s] for ``d`` at ``s`` in lane ``j``, or None when there is no room.

        Every vehicle in the lane must be at least ``min_gap_m`` away (bumper to bumper); a vehicle ahead
        caps the start speed (:func:`idm_fit_speed`); the new vehicle must not be inside the IDM desired gap
        of a vehicle behind it.
        """
        sp, speed, behind = self.spec, d.speed, []
        for s_o, length, v_o, t_o in self._occupants(k, j):
            gap = abs(s_o - s) - 0.5 * (length + d.size[0])
            if gap < sp.min_gap_m:
                return None
            if s_o >= s:
                speed = min(speed, idm_fit_speed(max(gap - d.jam_gap, 0.0), v_o, d.time_wanted))
            else:
                behind.append((s_o, length, v_o, t_o))
        if not all(self._room_for(v_o, s_o, length, s, d.size[0], speed, t_o) for s_o, length, v_o, t_o in behind):
            return None
        return speed

    @staticmethod
    def _room_for(v_f: float, s_f: float, length_f: float, s: float, length: float, speed: float,
                  time_wanted: float = IDMVehicle.TIME_WANTED) -> bool:
        """Whether a follower (speed ``v_f`` [m/s] at ``s_f`` [m], length [m]) has its IDM desired gap
        (jam gap ``TrafficVehicle.DISTANCE_WANTED``) to a vehicle at ``s`` moving at ``speed``."""
        room = s - s_f - 0.5 * (length + length_f) - TrafficVehicle.DISTANCE_WANTED
        fit = idm_fit_speed(room, speed, time_wanted)
        return fit is not None and v_f <= fit

    def _remove(self, wins: list[tuple[float, float]]) -> dict[tuple[int, int], int]:
        """Drop background vehicles more than REMOVE_MARGIN_M outside their window or the road; return the
        number of background vehicles inside the window per (carriageway, lane)."""
        net, vs = self.road.network, self.road.vehicles
        cw_of = np.array([v.carriageway if isinstance(v, TrafficVehicle) else -1 for v in vs], dtype=np.int64)
        S = np.full(len(vs), np.nan)  # every background vehicle's chain coordinate on its carriageway [m]
        for k, cw in enumerate(self.cws):
            mine = np.flatnonzero(cw_of == k).tolist()
            if mine:
                S[mine] = chain_coordinates(net, cw, [vs[i].lane_index for i in mine], [vs[i].position for i in mine])
        lo = np.array([max(lo, 0.0) for lo, _ in wins], dtype=np.float64)[np.maximum(cw_of, 0)]  # window on the road
        hi = np.array([min(hi, cw.total) for cw, (_, hi) in zip(self.cws, wins)], dtype=np.float64)[np.maximum(cw_of, 0)]
        near = (lo - REMOVE_MARGIN_M <= S) & (S <= hi + REMOVE_MARGIN_M)  # False for nan: off the carriageway
        counts: dict[tuple[int, int], int] = {}
        for i in np.flatnonzero(near & (lo <= S) & (S <= hi)).tolist():
            key = (int(cw_of[i]), vs[i].lane_index[2])
            counts[key] = counts.get(key, 0) + 1
        self.road.vehicles[:] = [v for v, keep in zip(vs, ((cw_of < 0) | near).tolist()) if keep]
        return counts

    def _spawn(self, k: int, j: int, s: float, d: Draw) -> TrafficVehicle:
        """Add vehicle ``d`` on lane ``j`` of carriageway ``k`` at chain coordinate ``s`` [m], with a new id."""
        lane_index, pos, heading = locate(self.road.network, self.cws[k], j, s)
        v = TrafficVehicle(self.road, pos, heading=heading, speed=d.speed, target_lane_index=lane_index,
                           target_speed=d.target_speed, enable_lane_change=d.mobil)
        v.LENGTH, v.WIDTH, v.HEIGHT = d.size
        v.diagonal = float(np.hypot(v.LENGTH, v.WIDTH))
        v.TIME_WANTED, v.DISTANCE_WANTED = d.time_wanted, d.jam_gap
        v.truth_id = self.next_id
        v.truth_name = f"{'truck' if d.truck else 'car'}{self.next_id}"
        v.carriageway = k
        self.next_id += 1
        self.road.vehicles.append(v)
        return v
