"""highway-env's traffic tick, ``Road.act()`` then ``Road.step(dt)``, for all vehicles at once, with the same numbers.

highway-env decides and moves each vehicle in a Python loop: IDM car following, MOBIL lane changes, the
lateral controller and the bicycle kinematics, with ~1,400 lane projections per frame on a busy motorway. Here
the per-vehicle arithmetic runs as NumPy expressions over every vehicle, in highway-env's own operation order
(a lane projection is ``dx * ux + dy * uy``, which is what ``np.dot`` of two 2-vectors computes; NumPy's
transcendental functions give the same bits for an array as for a scalar), so a tick gives the numbers of the
per-vehicle loop bit for bit (tests/test_stepping.py: every vehicle's position, heading and speed over the whole
highway benchmark, a curved road and highway-env's merge-v0, against highway-env's own ``Road``).

What stays per vehicle, by highway-env's own methods and in the vehicles' order (they read each other's lane
targets): ``follow_road`` for a vehicle near its lane's end, ``change_lane_policy`` (MOBIL) for a vehicle whose
decision timer fired or that is changing lanes, every vehicle whose ``act`` or ``step`` is not the IDM /
kinematic one (a scripted ``ControlledVehicle``, a ``GapFollower``, a user's class), and the projections on a
lane that is not straight (arcs, sine lanes), and the collisions with road objects. A road with fewer than
``BATCH_MIN_VEHICLES`` vehicles, recorded histories or connected-lane neighbour search is stepped by highway-env
itself.
"""
from __future__ import annotations

from operator import attrgetter

import numpy as np
from highway_env.road.lane import StraightLane
from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import Landmark

EPS = 1e-2  # highway_env.utils.not_zero's eps [m or m/s]
BATCH_MIN_VEHICLES = 8  # below this, highway-env's per-vehicle loop is quicker (same numbers either way)
DECIDE_MARGIN = 1e-6  # a vehicle this close to a decision threshold is handed to highway-env's own method


class BumperGapIDM(IDMVehicle):
    """IDM vehicle whose jam distance ``DISTANCE_WANTED`` is bumper to bumper [m]: highway-env measures IDM gaps
    centre to centre with a 10 m jam distance for 5 m cars, which would let a car run into an 18 m truck."""

    DISTANCE_WANTED = 5.0  # [m] bumper to bumper

    def desired_gap(self, ego_vehicle, front_vehicle=None, projected: bool = True) -> float:
        """IDM desired centre-to-centre distance: jam gap + half lengths + v T + v dv / (2 sqrt(a b)) [m]."""
        gap = super().desired_gap(ego_vehicle, front_vehicle, projected)
        return gap + 0.5 * (ego_vehicle.LENGTH + front_vehicle.LENGTH)


class BatchRoad(Road):
    """highway-env ``Road`` whose tick (``act``, ``step``) runs for all vehicles at once: the same numbers."""

    def act(self) -> None:
        batch_act(self)

    def step(self, dt: float) -> None:
        batch_step(self, dt)


GAP_FORMS = {IDMVehicle.desired_gap: 0.0, BumperGapIDM.desired_gap: 0.5}  # desired_gap -> weight of half lengths


class LaneTable:
    """The lanes of a road network as arrays, rows in the network's graph order (that of
    ``RoadNetwork.get_closest_lane_index``): start, direction, lateral direction (L, 2), length, heading, width,
    speed limit (L,; nan for none), whether straight (L,) bool; ``row[lane_index]``; ``lanes`` the objects."""

    def __init__(self, network) -> None:
        self.index = [(f, t, i) for f, tos in network.graph.items() for t, ls in tos.items() for i in range(len(ls))]
        self.lanes = [network.graph[f][t][i] for f, t, i in self.index]
        self.row = {key: k for k, key in enumerate(self.index)}
        self.straight = np.array([type(ln) is StraightLane for ln in self.lanes], dtype=bool)
        zero2 = np.zeros(2)
        self.start, self.dir, self.lat = (np.array([getattr(ln, a, zero2) if s else zero2 for ln, s in
                                                     zip(self.lanes, self.straight)], dtype=np.float64).reshape(-1, 2)
                                           for a in ("start", "direction", "direction_lateral"))
        self.length = np.array([ln.length for ln in self.lanes], dtype=np.float64)
        self.heading = np.array([ln.heading if s else np.nan for ln, s in zip(self.lanes, self.straight)])
        self.width = np.array([ln.width if s else np.nan for ln, s in zip(self.lanes, self.straight)])
        self.limit = np.array([np.nan if ln.speed_limit is None else ln.speed_limit for ln in self.lanes])
        self.vehicle_length = np.array([ln.VEHICLE_LENGTH for ln in self.lanes], dtype=np.float64)
        self.size = sum(len(ls) for tos in network.graph.values() for ls in tos.values())

    @classmethod
    def of(cls, network) -> "LaneTable":
        """The table of ``network``, cached on it until lanes are added."""
        table = getattr(network, "_batch_lane_table", None)
        size = sum(len(ls) for tos in network.graph.values() for ls in tos.values())
        if table is None or table.size != size:
            table = cls(network)
            network._batch_lane_table = table
        return table

    def coords(self, P: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``lane.local_coordinates`` of points P (n, 2) [m] on lanes ``rows`` (n,): (longitudinal, lateral) [m]."""
        d0, d1 = P[:, 0] - self.start[rows, 0], P[:, 1] - self.start[rows, 1]
        s = d0 * self.dir[rows, 0] + d1 * self.dir[rows, 1]  # np.dot(delta, direction) of StraightLane
        r = d0 * self.lat[rows, 0] + d1 * self.lat[rows, 1]
        for k in np.flatnonzero(~self.straight[rows]):
            s[k], r[k] = self.lanes[rows[k]].local_coordinates(P[k])
        return s, r


def not_zero(x: np.ndarray) -> np.ndarray:
    """highway_env.utils.not_zero elementwise: x where |x| > eps, else +-eps by sign (0 -> +eps)."""
    return np.where(np.abs(x) > EPS, x, np.where(x >= 0, EPS, -EPS))


def wrap_to_pi(x: np.ndarray) -> np.ndarray:
    """highway_env.utils.wrap_to_pi elementwise [rad]."""
    return ((x + np.pi) % (2 * np.pi)) - np.pi


def batchable(road) -> bool:
    """Whether ``road`` is stepped here (else highway-env steps it): at least BATCH_MIN_VEHICLES vehicles (fewer
    are quicker one by one), no recorded histories, no connected-lane neighbour search."""
    return len(road.vehicles) >= BATCH_MIN_VEHICLES and not road.record_history and not getattr(road, "neighbour_vehicles_connected_lanes",
                                                                           False)


def decides_like_idm(v) -> bool:
    """Whether ``v.act()`` is highway-env's IDM/MOBIL act with a desired gap known here."""
    t = type(v)
    known = _DECIDES.get(t)
    if known is None:
        known = _DECIDES[t] = _idm_type(t)
    return known


def moves_like_kinematics(v) -> bool:
    """Whether ``v.step(dt)`` is highway-env's bicycle kinematics (plus IDM's decision timer)."""
    t = type(v)
    known = _MOVES.get(t)
    if known is None:
        known = _MOVES[t] = (t.step in (IDMVehicle.step, Vehicle.step) and t.clip_actions is Vehicle.clip_actions
                             and t.on_state_update is Vehicle.on_state_update)
    return known


_DECIDES: dict[type, bool] = {}
_MOVES: dict[type, bool] = {}
IDM_NAMES = ("speed", "heading", "LENGTH", "KP_LATERAL", "KP_HEADING", "MAX_STEERING_ANGLE", "ACC_MAX",
             "COMFORT_ACC_MAX", "COMFORT_ACC_MIN", "DELTA", "DISTANCE_WANTED", "TIME_WANTED", "target_speed")
IDM_STATE = attrgetter(*IDM_NAMES)  # the columns of an IDM vehicle's state row
MOTION = attrgetter("speed", "heading", "LENGTH")
KIN_STATE = attrgetter("speed", "heading", "LENGTH", "MAX_SPEED", "MIN_SPEED")


def _idm_type(t: type) -> bool:
    return (t.act is IDMVehicle.act and t.acceleration is IDMVehicle.acceleration and t.desired_gap in GAP_FORMS
            and t.steering_control is ControlledVehicle.steering_control and t.follow_road is ControlledVehicle.follow_road
            and t.change_lane_policy is IDMVehicle.change_lane_policy)


def batch_act(road) -> None:
    """``Road.act()``: every vehicle's action (steering, acceleration) for this tick, as highway-env decides it."""
    vs = road.vehicles
    if not batchable(road):
        return Road.act(road)
    table = LaneTable.of(road.network)
    idm = np.array([decides_like_idm(v) and not v.crashed for v in vs], dtype=bool)
    _decide_in_order(vs, idm, table)
    A = np.flatnonzero(idm)
    if len(A) == 0:
        return None
    seen = vs + [o for o in road.objects if not isinstance(o, Landmark)]  # what neighbour_vehicles looks at
    P = np.array([v.position for v in seen], dtype=np.float64).reshape(-1, 2)
    every = np.array([MOTION(v) for v in seen], dtype=np.float64).reshape(-1, 3)  # speed, heading, LENGTH
    X = np.array([IDM_STATE(vs[i]) for i in A], dtype=np.float64).reshape(-1, len(IDM_NAMES))
    own = np.array([table.row[vs[i].lane_index] for i in A], dtype=np.int64)
    target = np.array([table.row[vs[i].target_lane_index] for i in A], dtype=np.int64)
    steer = np.clip(_steering(vs, A, P, X, target, table), -X[:, 5], X[:, 5])
    acc = np.clip(_idm_acceleration(vs, A, P, X, every, own, target, table), -X[:, 6], X[:, 6])
    for k, i in enumerate(A):
        vs[i].action = {"steering": steer[k], "acceleration": acc[k]}  # Vehicle.act(action)
    return None


def _decide_in_order(vs: list, idm: np.ndarray, table: LaneTable) -> None:
    """The per-vehicle part of ``act``, in the vehicles' order: other vehicles' own ``act``; for the IDM ones
    ``follow_road`` near a lane end and MOBIL's ``change_lane_policy`` when due (highway-env's methods)."""
    A = np.flatnonzero(idm)
    P = np.array([vs[i].position for i in A], dtype=np.float64).reshape(-1, 2)
    target = np.array([table.row[vs[i].target_lane_index] for i in A], dtype=np.int64)
    s, _ = table.coords(P, target)
    near_end = np.zeros(len(vs), dtype=bool)
    near_end[A] = ~table.straight[target] | (s > table.length[target] - table.vehicle_length[target] / 2
                                             - DECIDE_MARGIN)
    due = np.zeros(len(vs), dtype=bool)
    due[A] = np.array([vs[i].timer - vs[i].LANE_CHANGE_DELAY for i in A]) > -DECIDE_MARGIN
    for i, v in enumerate(vs):
        if not idm[i]:
            v.act()  # its own decision (a crashed IDM vehicle's returns at once)
            continue
        if near_end[i]:
            v.follow_road()
        if v.enable_lane_change and (v.lane_index != v.target_lane_index or due[i]):
            v.change_lane_policy()


def _steering(vs: list, A: np.ndarray, P: np.ndarray, X: np.ndarray, rows: np.ndarray, table: LaneTable) -> np.ndarray:
    """``ControlledVehicle.steering_control(target_lane_index)`` of vehicles A (n,) [rad]; X (n, 13) their
    IDM_NAMES state rows, rows (n,) their target lanes."""
    speed, heading, length, kp_lat, kp_head, max_steer = X[:, 0], X[:, 1], X[:, 2], X[:, 3], X[:, 4], X[:, 5]
    _, r = table.coords(P[A], rows)
    lateral_speed_command = -kp_lat * r  # controller.py steering_control, line by line
    heading_command = np.arcsin(np.clip(lateral_speed_command / not_zero(speed), -1, 1))
    heading_ref = table.heading[rows] + np.clip(heading_command, -np.pi / 4, np.pi / 4)
    heading_rate_command = kp_head * wrap_to_pi(heading_ref - heading)
    slip_angle = np.arcsin(np.clip(length / 2 / not_zero(speed) * heading_rate_command, -1, 1))
    steering = np.clip(np.arctan(2 * np.tan(slip_angle)), -max_steer, max_steer)
    for k in np.flatnonzero(~table.straight[rows]):  # the lane's heading ahead of the vehicle: its own method
        steering[k] = vs[A[k]].steering_control(vs[A[k]].target_lane_index)
    return steering


def lane_coordinates(P: np.ndarray, table: LaneTable, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every point P (N, 2) [m] on every lane of ``table``: longitudinal and lateral coordinates (N, L) [m] and
    whether it is on the lane within 1 m (``AbstractLane.on_lane(margin=1)``) (N, L) bool; of the lanes that are
    not straight only the ``rows`` (by the lane's own methods; the others' columns are nan and False)."""
    d0 = P[:, None, 0] - table.start[None, :, 0]
    d1 = P[:, None, 1] - table.start[None, :, 1]
    s = d0 * table.dir[None, :, 0] + d1 * table.dir[None, :, 1]  # np.dot(delta, direction) of StraightLane
    r = d0 * table.lat[None, :, 0] + d1 * table.lat[None, :, 1]
    width = np.broadcast_to(table.width, s.shape).copy()
    for k in np.flatnonzero(~table.straight):
        if k not in rows:
            s[:, k] = r[:, k] = np.nan
            continue
        lane = table.lanes[k]
        for i in range(len(P)):
            s[i, k], r[i, k] = lane.local_coordinates(P[i])
            width[i, k] = lane.width_at(s[i, k])
    on = (np.abs(r) <= width / 2 + 1) & (-table.vehicle_length <= s) & (s < table.length + table.vehicle_length)
    return s, r, on


def front_vehicles(queries: np.ndarray, rows: np.ndarray, s: np.ndarray, on: np.ndarray) -> np.ndarray:
    """``Road.neighbour_vehicles(vs[q], lane)[0]`` for vehicles ``queries`` (n,) on lanes ``rows`` (n,), given
    every vehicle's lane coordinates s (N, L) and on-lane flags on (N, L) (:func:`lane_coordinates`): the index
    of the vehicle ahead on that lane, -1 for none; of equal distances the last, as highway-env's loop."""
    n = s.shape[0]
    s_q = s[queries, rows]
    cand = s[:, rows].T  # (n, N): every vehicle on each query's lane
    ahead = on[:, rows].T & (cand >= s_q[:, None])
    ahead[np.arange(len(queries)), queries] = False
    value = np.where(ahead, cand, np.inf)[:, ::-1]
    j = n - 1 - np.argmin(value, axis=1)  # the last of equal minima
    return np.where(np.isfinite(value.min(axis=1)), j, -1)


def _idm_acceleration(vs: list, A: np.ndarray, P: np.ndarray, X: np.ndarray, every: np.ndarray, own: np.ndarray,
                      target: np.ndarray, table: LaneTable) -> np.ndarray:
    """IDMVehicle.act's longitudinal command of vehicles A (n,) [m/s^2], before the ACC_MAX clip: IDM behind
    the vehicle ahead on its lane ``own`` (n,) and, while changing lanes, the smaller of that and IDM on the
    ``target`` lane (n,). X (n, 13): their IDM_NAMES rows; every (N, 3): speed, heading, LENGTH of all."""
    s, _, on = lane_coordinates(P, table, np.union1d(own, target))
    acc = _idm(vs, A, X, every, front_vehicles(A, own, s, on), own, s, table.limit[own])
    changing = np.flatnonzero(own != target)
    if len(changing):
        other = _idm(vs, A[changing], X[changing], every, front_vehicles(A[changing], target[changing], s, on),
                     own[changing], s, table.limit[own[changing]])
        acc[changing] = np.where(other < acc[changing], other, acc[changing])  # min(acc, other)
    return acc


def _idm(vs: list, A: np.ndarray, X: np.ndarray, every: np.ndarray, front: np.ndarray, own: np.ndarray,
         s_all: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """``IDMVehicle.acceleration(ego_vehicle=v, front_vehicle=front)`` of vehicles A (n,) whose current lanes are
    ``own`` (n,) (the lane of ``lane_distance_to``), front (n,) indices or -1; s_all (N, L) every vehicle's
    longitudinal lane coordinates, limit (n,) the speed limits of their lanes (nan: none) [m/s^2] (behavior.py)."""
    speed, heading, length = X[:, 0], X[:, 1], X[:, 2]
    a_max, a_min, delta, d0, tau, target = X[:, 7], X[:, 8], X[:, 9], X[:, 10], X[:, 11], X[:, 12]
    target = np.where(np.isnan(limit), target, np.clip(target, 0, np.where(np.isnan(limit), np.inf, limit)))
    acc = a_max * (1 - np.power(np.maximum(speed, 0) / np.abs(not_zero(target)), delta))
    has = np.flatnonzero(front >= 0)
    if len(has) == 0:
        return acc
    f = front[has]
    d = s_all[f, own[has]] - s_all[A[has], own[has]]  # lane_distance_to on the ego's own lane
    sp, c, s = speed[has], np.cos(heading[has]), np.sin(heading[has])
    v_f, h_f = every[f, 0], every[f, 1]
    dv = (sp * c - v_f * np.cos(h_f)) * c + (sp * s - v_f * np.sin(h_f)) * s  # np.dot(v_ego - v_front, direction)
    ab = -a_max[has] * a_min[has]
    gap = d0[has] + sp * tau[has] + sp * dv / (2 * np.sqrt(ab))  # desired_gap
    half = np.array([GAP_FORMS[type(vs[i]).desired_gap] for i in A[has]])
    gap = np.where(half > 0, gap + half * (length[has] + every[f, 2]), gap)
    acc[has] = acc[has] - a_max[has] * np.power(gap / not_zero(d), 2)
    return acc


def batch_step(road, dt: float) -> None:
    """``Road.step(dt)``: every vehicle moved by ``dt`` [s], then the collisions of the pairs that may touch."""
    vs = road.vehicles
    if not batchable(road):
        return Road.step(road, dt)
    kin = np.array([moves_like_kinematics(v) for v in vs], dtype=bool)
    for i in np.flatnonzero(~kin):
        vs[i].step(dt)
    K = np.flatnonzero(kin)
    if len(K):
        _kinematics(road, [vs[i] for i in K], dt)
    pairs = touching_pairs(vs, dt)
    if not road.objects:
        for i, j in pairs:
            vs[i].handle_collisions(vs[j], dt)
        return None
    by_first: dict[int, list[int]] = {}
    for i, j in pairs:
        by_first.setdefault(i, []).append(j)
    for i, v in enumerate(vs):  # Road.step's order: the vehicles after v, then the road objects
        for j in by_first.get(i, ()):
            v.handle_collisions(vs[j], dt)
        for other in road.objects:
            v.handle_collisions(other, dt)
    return None


def _kinematics(road, vs: list, dt: float) -> None:
    """``IDMVehicle.step`` / ``Vehicle.step`` of vehicles vs: decision timer, clip_actions, the bicycle model,
    impacts and the new lane (kinematics.py, line by line)."""
    speed, heading, length, v_max, v_min = np.array([KIN_STATE(v) for v in vs], dtype=np.float64).reshape(-1, 5).T
    crashed = np.array([v.crashed for v in vs], dtype=bool)
    steer = np.where(crashed, 0.0, np.array([float(v.action["steering"]) for v in vs], dtype=np.float64))
    acc = np.where(crashed, -1.0 * speed, np.array([float(v.action["acceleration"]) for v in vs], dtype=np.float64))
    up, down = 1.0 * (v_max - speed), 1.0 * (v_min - speed)
    acc = np.where(speed > v_max, np.where(up < acc, up, acc), np.where((speed < v_min) & (down > acc), down, acc))
    beta = np.arctan(1 / 2 * np.tan(steer))
    move_x, move_y = speed * np.cos(heading + beta) * dt, speed * np.sin(heading + beta) * dt
    new_heading = heading + speed * np.sin(beta) / (length / 2) * dt
    new_speed = speed + acc * dt
    for k, v in enumerate(vs):
        if type(v).step is IDMVehicle.step:
            v.timer += dt
        v.action["steering"], v.action["acceleration"] = float(steer[k]), float(acc[k])
        v.position += np.array([move_x[k], move_y[k]])
        if v.impact is not None:
            v.position += v.impact
            v.crashed = True
            v.impact = None
        v.heading, v.speed = new_heading[k], float(new_speed[k])
    _new_lanes(road, vs)


def _new_lanes(road, vs: list) -> None:
    """``Vehicle.on_state_update``: each vehicle's closest lane by ``RoadNetwork.get_closest_lane_index``
    (position and heading; the first minimum), all at once when every lane is straight."""
    net = road.network
    table = LaneTable.of(net)
    if not table.straight.all() or not vs:
        for v in vs:
            v.on_state_update()
        return
    P = np.array([v.position for v in vs], dtype=np.float64).reshape(-1, 2)
    heading = np.array([v.heading for v in vs], dtype=np.float64)
    d0 = P[:, None, 0] - table.start[None, :, 0]
    d1 = P[:, None, 1] - table.start[None, :, 1]
    s = d0 * table.dir[None, :, 0] + d1 * table.dir[None, :, 1]
    r = d0 * table.lat[None, :, 0] + d1 * table.lat[None, :, 1]
    angle = np.abs(wrap_to_pi(heading[:, None] - table.heading[None, :]))
    dist = (np.abs(r) + np.maximum(s - table.length[None, :], 0) + np.maximum(0 - s, 0)) + 1.0 * angle  # lane.py
    best = np.argmin(dist, axis=1)
    for v, k in zip(vs, best):
        v.lane_index = table.index[k]
        v.lane = table.lanes[k]


def touching_pairs(vs: list, dt: float) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, in ``Road.step``'s order, whose boxes may overlap now or after moving ``dt`` [s].

    Left out only where ``RoadObject._is_colliding`` is sure to find nothing: centres farther apart than its
    own spherical pre-check, or a gap along either vehicle's lateral axis (a separating axis of the
    polygon test) wider than the relative lateral motion in ``dt``; 1 mm margin for rounding.
    """
    if len(vs) < 2:
        return []
    pos = np.array([v.position for v in vs], dtype=np.float64).reshape(-1, 2)
    length, width, diag, speed, heading = (np.array([getattr(v, k) for v in vs], dtype=np.float64)
                                           for k in ("LENGTH", "WIDTH", "diagonal", "speed", "heading"))
    vel = speed[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
    d = pos[None, :, :] - pos[:, None, :]  # (N, N, 2) from i to j
    far = np.hypot(d[..., 0], d[..., 1]) > 0.5 * (diag[:, None] + diag[None, :]) + np.abs(speed)[:, None] * dt
    normal = np.column_stack([-np.sin(heading), np.cos(heading)])  # (N, 2) lateral axis of i
    rel = heading[None, :] - heading[:, None]
    half_j = 0.5 * (length[None, :] * np.abs(np.sin(rel)) + width[None, :] * np.abs(np.cos(rel)))
    lat_gap = (np.abs(np.einsum("ijk,ik->ij", d, normal)) - 0.5 * width[:, None] - half_j
               - np.abs(np.einsum("ijk,ik->ij", vel[None, :, :] - vel[:, None, :], normal)) * dt)
    apart = (lat_gap > 1e-3) | (lat_gap.T > 1e-3)
    ii, jj = np.nonzero(np.triu(~(far | apart), k=1))
    return list(zip(ii.tolist(), jj.tolist()))
