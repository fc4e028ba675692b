"""Occlusion-aware detection probability and occluder shadows, on real open3d scans.

Truth for "detectable" is the scan's own labels: a vehicle is detectable when at least 5 scan points
(ClusterConfig.min_points) come from it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from roadtrack.sensors import GROUND, LidarConfig, Scan
from roadtrack.sensors.lidar import scan
from roadtrack.sensors.occlusion import OcclusionConfig, detection_probability, shadows, visibility

LIDAR = LidarConfig()  # HDL-32E with range noise and dropout
OCC = OcclusionConfig.from_lidar(LIDAR)
CAR = (4.6, 1.8, 1.5)
TRUCK = [15.0, 0.0, 15.0, 2.5, 3.8, 0.0, 0.0]  # 15 x 2.5 x 3.8 m, centre 15 m ahead in the sensor's lane
MIN_POINTS = 5


def box(x, y, size=CAR, yaw=0.0):
    return [x, y, size[0], size[1], size[2], yaw, 0.0]


def cast(boxes, ids, pose=(0.0, 0.0, 0.0), seed=0) -> Scan:
    return scan(LIDAR, np.array(pose, float), np.array(boxes, float).reshape(-1, 7), np.array(ids, np.int64),
                np.random.default_rng(seed))


def n_points(s: Scan, vehicle_id: int) -> int:
    return int(np.sum(s.source == vehicle_id))


# --- hidden and visible -------------------------------------------------------------------------------

def test_car_behind_a_truck_is_hidden_and_visible_once_the_truck_is_gone():
    car = box(35.0, 0.0)
    hidden = cast([TRUCK, car], [0, 1])
    assert n_points(hidden, 1) == 0  # the scene really hides it
    assert detection_probability(hidden, [car[:2]], OCC)[0] < 0.05

    free = cast([car], [1])
    assert n_points(free, 1) >= MIN_POINTS
    vis = visibility(free, [car[:2]], OCC)
    assert vis.clear_rays[0] == vis.rays[0] >= 20 and vis.clear_columns[0] == vis.columns[0] >= 10
    assert n_points(free, 1) == pytest.approx(vis.rays[0], rel=0.15)  # dropout and the 0.3 m floor aside
    assert detection_probability(free, [car[:2]], OCC)[0] == pytest.approx(OCC.pd_nominal, abs=1e-12)


def test_cars_outside_the_trucks_shadow_are_unaffected():
    cars = [box(35.0, 7.0), box(-35.0, 0.0), box(20.0, -7.0)]  # two lanes over, behind the sensor, beside
    s = cast([TRUCK] + cars, [0, 1, 2, 3])
    assert all(n_points(s, k) >= MIN_POINTS for k in (1, 2, 3))
    pd = detection_probability(s, np.array(cars)[:, :2], OCC)
    assert pd == pytest.approx(np.full(3, OCC.pd_nominal), abs=1e-12)


def test_side_on_car_with_its_middle_hidden_needs_its_heading():
    """A crossing car (yaw 90 deg) behind a 0.5 m post: the post hides its middle 1.5 m, its ends show.
    Assumed end-on, the window is the hidden middle; with its heading, the whole side counts."""
    car = box(30.0, 0.0, yaw=np.pi / 2)
    s = cast([box(10.0, 0.0, (0.5, 0.5, 2.0)), car], [-1, 1])
    assert n_points(s, 1) >= 50
    end_on = detection_probability(s, [car[:2]], OCC)[0]
    side_on = detection_probability(s, [car[:2]], OCC, heading=np.array([np.pi / 2]))[0]
    assert side_on == pytest.approx(OCC.pd_nominal, abs=1e-12)
    assert end_on < 0.5


def test_a_car_seen_over_a_nearer_roof_counts_by_its_width():
    """VLS-128: a 1.6 m high car 15 m ahead hides all of a 1.5 m car at 30 m but a line over its roof. Few
    of the expected rays are clear, yet they span its width (it clusters): P_D by width is nominal."""
    lidar = LidarConfig(preset="vls128")
    occ = OcclusionConfig.from_lidar(lidar)
    boxes = np.array([box(15.0, 0.0, (4.6, 1.8, 1.6)), box(30.0, 0.0)])
    s = scan(lidar, np.zeros(3), boxes, np.array([0, 1]), np.random.default_rng(0))
    assert n_points(s, 1) >= MIN_POINTS
    vis = visibility(s, [[30.0, 0.0]], occ)
    assert vis.clear_rays[0] / vis.rays[0] < 0.2 and vis.clear_rays[0] >= occ.min_points
    assert vis.visible_fraction[0] > 0.8
    assert detection_probability(s, [[30.0, 0.0]], occ)[0] == pytest.approx(occ.pd_nominal, abs=1e-12)


# --- range and beam geometry ------------------------------------------------------------------------------

def test_open_view_at_65_m_is_reached_by_one_beam_and_detectable():
    """Near face of a car centred at 65 m: 62.7 m. The -1.33 deg beam (1.9 m mount) is 0.44 m above the road
    there, between min_hit_height_m and the car's 1.5 m top; the next beams are at -1.0 m and 1.9 m."""
    near = 65.0 - CAR[0] / 2
    heights = LIDAR.mount_height_m + near * np.tan(np.deg2rad(LIDAR.elevations_deg))
    on_car = (heights >= OCC.min_hit_height_m) & (heights <= CAR[2])
    assert on_car.sum() == 1 and heights[on_car][0] == pytest.approx(0.442, abs=1e-3)

    for y in (0.0, 3.5, -3.5):
        s = cast([box(65.0, y)], [1])
        assert n_points(s, 1) >= MIN_POINTS
        assert detection_probability(s, [[65.0, y]], OCC)[0] > 0.5


def test_beyond_the_beams_reach_and_out_of_range_give_zero():
    # centre 72 m: near face 69.7 m, where the lowest useful beam is 0.28 m high (< min_hit_height_m)
    s = cast([box(72.0, 0.0)], [1])
    near = 72.0 - CAR[0] / 2
    heights = LIDAR.mount_height_m + near * np.tan(np.deg2rad(LIDAR.elevations_deg))
    assert not np.any((heights >= OCC.min_hit_height_m) & (heights <= CAR[2]))
    far = np.array([[72.0, 0.0], [80.0, 3.5], [-150.0, 0.0], [0.0, 300.0]])
    assert detection_probability(s, far, OCC) == pytest.approx(np.zeros(4), abs=0)
    # a position on top of the sensor (inside min range, the sensor inside the footprint)
    assert detection_probability(s, [[0.3, 0.0]], OCC)[0] == 0.0


def test_a_tall_target_is_reached_further_than_a_car():
    """A 10 x 2.5 x 3.8 m truck centred at 74 m: near face at 69 m, where the 0 and +1.33 deg beams (1.90 and
    3.51 m high) hit it and no beam is between min_hit_height_m and a 1.5 m car's top (-1.33 deg: 0.30 m)."""
    truck = (10.0, 2.5, 3.8)
    heights = LIDAR.mount_height_m + 69.0 * np.tan(np.deg2rad(LIDAR.elevations_deg))
    on_truck = (heights >= OCC.min_hit_height_m) & (heights <= truck[2])
    assert heights[on_truck] == pytest.approx([1.902, 3.508], abs=1e-3)
    assert not np.any((heights >= OCC.min_hit_height_m) & (heights <= CAR[2]))
    s = cast([box(74.0, 3.5, truck)], [1])
    assert n_points(s, 1) >= MIN_POINTS
    assert detection_probability(s, [[74.0, 3.5]], OCC, size_m=truck)[0] > 0.5
    assert detection_probability(s, [[74.0, 3.5]], OCC, size_m=CAR)[0] == 0.0


def test_no_return_at_all_is_free_space():
    """A range image without any return (every ray clear): nominal P_D within the beams' reach, 0 beyond."""
    s = cast([], [])
    blank = replace(s, ranges=np.full(s.ranges.shape, np.inf))
    pd = detection_probability(blank, [[20.0, 0.0], [-40.0, 3.5], [65.0, 0.0], [75.0, 0.0]], OCC)
    assert pd == pytest.approx([OCC.pd_nominal] * 3 + [0.0], abs=1e-12)


# --- invariance and batching ------------------------------------------------------------------------------

def test_batch_equals_one_at_a_time():
    rng = np.random.default_rng(3)
    boxes = [box(x, 3.5 * lane) for x, lane in [(12, 0), (-9, 1), (30, -1), (45, 0), (-25, 0), (8, -1)]]
    s = cast(boxes, np.arange(6))
    xy = np.concatenate([np.array(boxes)[:, :2], rng.uniform(-70, 70, (40, 2))])
    batch = detection_probability(s, xy, OCC)
    single = np.array([detection_probability(s, p[None], OCC)[0] for p in xy])
    # bit for bit: the testbed asks for the car box and the truck box on subsets of a scan's tracks
    assert np.array_equal(batch, single)
    heading = rng.uniform(-np.pi, np.pi, len(xy))
    rows = rng.random(len(xy)) < 0.3
    truck = (15.4, 2.5, 3.5)
    for size in (CAR, truck):
        whole = detection_probability(s, xy, OCC, size_m=size, heading=heading)
        assert np.array_equal(whole[rows], detection_probability(s, xy[rows], OCC, size_m=size, heading=heading[rows]))
    # one size per position: the same as asking each size for its own positions
    mixed = detection_probability(s, xy, OCC, size_m=np.where(rows[:, None], truck, CAR), heading=heading)
    assert np.array_equal(mixed[rows], detection_probability(s, xy[rows], OCC, size_m=truck, heading=heading[rows]))
    assert np.array_equal(mixed[~rows], detection_probability(s, xy[~rows], OCC, size_m=CAR, heading=heading[~rows]))
    assert np.all((batch >= 0) & (batch <= OCC.pd_nominal))
    assert detection_probability(s, np.zeros((0, 2)), OCC).shape == (0,)


def test_moving_the_whole_scene_with_the_sensor_changes_nothing_but_sampling():
    boxes = np.array([TRUCK, box(35.0, 0.0), box(35.0, 7.0), box(-20.0, 3.5), box(25.0, 3.5)])
    ids = np.arange(5)
    xy = boxes[:, :2]
    pd0 = detection_probability(cast(boxes, ids), xy, OCC)
    x0, y0, yaw = 1234.5, -87.0, 2.1
    c, s_ = np.cos(yaw), np.sin(yaw)
    moved = boxes.copy()
    moved[:, 0], moved[:, 1] = x0 + c * xy[:, 0] - s_ * xy[:, 1], y0 + s_ * xy[:, 0] + c * xy[:, 1]
    moved[:, 5] += yaw
    pd1 = detection_probability(cast(moved, ids, pose=(x0, y0, yaw)), moved[:, :2], OCC)
    assert pd1 == pytest.approx(pd0, abs=0.1)  # azimuth columns fall differently on the boxes
    assert np.array_equal(pd0 > 0.5, pd1 > 0.5)


# --- agreement with truth on a realistic scene ------------------------------------------------------------

def three_lane_scene(seed: int, lidar: LidarConfig = LIDAR) -> tuple[np.ndarray, Scan]:
    """10 cars of varied size in 3 lanes (y = -3.5, 0, 3.5, +-0.3 m), -70..75 m, sensor at the origin in
    the middle lane; same-lane cars at least 7 m apart, none within 6 m of the sensor in its lane."""
    rng = np.random.default_rng(seed)
    placed: list[tuple[float, int]] = []
    while len(placed) < 10:
        x, lane = rng.uniform(-70.0, 75.0), int(rng.integers(3))
        if all(abs(x - x2) > 7.0 or l2 != lane for x2, l2 in placed) and not (lane == 1 and abs(x) < 6.0):
            placed.append((x, lane))
    boxes = np.array([[x, 3.5 * (lane - 1) + rng.normal(0, 0.3), rng.uniform(4.2, 5.0), rng.uniform(1.7, 2.0),
                       rng.uniform(1.4, 1.7), rng.normal(0, 0.03), 0.0] for x, lane in placed])
    return boxes, scan(lidar, np.zeros(3), boxes, np.arange(10), rng)


def agreement(seeds, cfg=OCC, position_std_m=0.0, with_heading=False, lidar=LIDAR) -> np.ndarray:
    """Confusion (2, 2): rows truth detectable (>= 5 points) no / yes, columns P_D > 0.5 no / yes."""
    confusion = np.zeros((2, 2), np.int64)
    rng = np.random.default_rng(99)
    for seed in seeds:
        boxes, s = three_lane_scene(seed, lidar)
        detectable = np.bincount(s.source[s.source >= 0], minlength=10) >= MIN_POINTS
        xy = boxes[:, :2] + rng.normal(0.0, position_std_m, (10, 2))
        pd = detection_probability(s, xy, cfg, heading=boxes[:, 5] if with_heading else None)
        np.add.at(confusion, (detectable.astype(int), (pd > 0.5).astype(int)), 1)
    return confusion


def test_agrees_with_truth_visibility_on_three_lane_traffic():
    confusion = agreement(range(20))
    assert confusion.sum() == 200
    assert confusion[0].sum() >= 20  # enough hidden cars for the test to mean something
    assert np.trace(confusion) / confusion.sum() >= 0.95, confusion
    assert confusion[0, 1] <= 2  # hidden cars given a high P_D


def test_attitude_tolerance_follows_truth_under_ego_pitch_and_roll():
    """Uncorrected pitch and roll (0.3 deg sigma) tilt the true rays off the nominal ones the range image is
    indexed by: far cars are hit by beams the level model says pass over, and the beam it expects meets the
    road first. With the tolerance from_lidar sets (3 sigma) the agreement with truth is restored."""
    lidar = LidarConfig(pitch_std_deg=0.3, roll_std_deg=0.3)
    tolerant = OcclusionConfig.from_lidar(lidar)
    assert tolerant.attitude_tol_deg == pytest.approx(0.9, abs=1e-12)
    level = replace(tolerant, attitude_tol_deg=0.0)
    with_tol = agreement(range(20), tolerant, lidar=lidar)
    without = agreement(range(20), level, lidar=lidar)
    assert np.trace(with_tol) / 200 >= 0.97, with_tol
    assert np.trace(without) / 200 <= np.trace(with_tol) / 200 - 0.02, without
    assert with_tol[0, 1] <= 2, with_tol


# --- shadows ----------------------------------------------------------------------------------------------

def inside(polygon: np.ndarray, p) -> bool:
    """Even-odd rule point-in-polygon."""
    x, y = polygon[:, 0], polygon[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    crosses = (y > p[1]) != (yn > p[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = x + (p[1] - y) * (xn - x) / (yn - y)
    return bool(np.sum(crosses & (p[0] < x_at)) % 2)


def test_the_trucks_shadow_covers_the_hidden_car_and_not_the_visible_one():
    pose = np.array([100.0, 50.0, 0.8])
    c, s_ = np.cos(pose[2]), np.sin(pose[2])

    def world(u, v):  # sensor frame -> world
        return pose[0] + c * u - s_ * v, pose[1] + s_ * u + c * v

    truck = [*world(15.0, 0.0), *TRUCK[2:5], pose[2], 0.0]
    s = cast([truck, [*world(35.0, 0.0), *CAR, pose[2], 0.0]], [0, 1], pose=pose)
    polys = shadows(s, OCC)
    assert len(polys) == 1  # the truck; the hidden car casts none of its own
    poly = polys[0]
    assert poly.ndim == 2 and poly.shape[1] == 2 and poly.dtype == np.float64
    assert len(poly) <= 2 * OCC.shadow_max_vertices
    assert inside(poly, world(35.0, 0.0)) and inside(poly, world(65.0, 2.0))
    assert not any(inside(poly, world(u, v)) for u, v in [(35.0, 7.0), (-15.0, 0.0), (5.0, 0.0)])
    r = np.hypot(poly[:, 0] - pose[0], poly[:, 1] - pose[1])
    assert r.min() == pytest.approx(7.5, abs=0.3)  # the truck's rear face
    assert r.max() == pytest.approx(OCC.max_range_m, abs=1e-9)
    # the ground labels give the same shadow on a flat road
    labelled = shadows(s, OCC, is_ground=s.source == GROUND)
    assert len(labelled) == 1 and labelled[0] == pytest.approx(poly, abs=1e-9)


def test_empty_road_casts_no_shadow_even_when_tilted():
    assert shadows(cast([], []), OCC) == []
    lidar = LidarConfig(pitch_std_deg=0.3, roll_std_deg=0.3)
    tilted = scan(lidar, np.zeros(3), np.zeros((0, 7)), np.zeros(0, np.int64), np.random.default_rng(3))
    tolerant = OcclusionConfig.from_lidar(lidar)
    assert shadows(tilted, tolerant) == []  # seed 3: pitch 0.61, roll -0.77 deg
    assert len(shadows(tilted, replace(tolerant, attitude_tol_deg=0.0))) > 5  # the tilted road, taken as objects


# --- bad input --------------------------------------------------------------------------------------------

def test_bad_input_is_one_line_value_error():
    s = cast([box(20.0, 0.0)], [1])
    with pytest.raises(ValueError, match=r"^xy: contains NaN"):
        detection_probability(s, [[np.nan, 0.0]], OCC)
    with pytest.raises(ValueError, match=r"^xy: expected shape"):
        detection_probability(s, [1.0, 2.0], OCC)
    with pytest.raises(ValueError, match=r"^size_m:"):
        detection_probability(s, [[20.0, 0.0]], OCC, size_m=(4.6, 0.0, 1.5))
    with pytest.raises(ValueError, match=r"^size_m:"):  # one size per position: as many rows as positions
        detection_probability(s, [[20.0, 0.0]], OCC, size_m=np.ones((2, 3)))
    with pytest.raises(ValueError, match=r"^size_m:"):
        detection_probability(s, [[20.0, 0.0]], OCC, size_m=[[4.6, 1.8, np.nan]])
    with pytest.raises(ValueError, match=r"^heading: expected shape"):
        detection_probability(s, [[20.0, 0.0]], OCC, heading=np.zeros(2))
    old_style = Scan(points=s.points, source=s.source, origin=s.origin)  # no range image
    with pytest.raises(ValueError, match=r"^scan.ranges: expected a non-empty \(A, B\) range image"):
        detection_probability(old_style, [[20.0, 0.0]], OCC)
    with pytest.raises(ValueError, match=r"^scan.ranges:"):
        shadows(old_style, OCC)
    with pytest.raises(ValueError, match=r"^is_ground:"):
        shadows(s, OCC, is_ground=np.zeros(3, bool))
    with pytest.raises(TypeError, match=r"^scan:"):
        detection_probability(s.points, [[20.0, 0.0]], OCC)
    for bad in (dict(pd_nominal=1.5), dict(visible_lo=0.5, visible_hi=0.4), dict(min_range_m=80.0),
                dict(max_columns=0), dict(margin_m=-1.0)):
        with pytest.raises(ValueError, match=r"^OcclusionConfig\.\w+:"):
            OcclusionConfig(**bad)
    with pytest.raises(TypeError, match=r"^lidar:"):
        OcclusionConfig.from_lidar(OCC)
    assert OcclusionConfig.from_lidar(replace(LIDAR, max_range_m=120.0)).max_range_m == 120.0


def test_few_rays_give_a_partial_pd_with_full_points():
    """full_points (11 fits perception's measured P_D, sensor.occlusion_pd_full_points): below it P_D rises linearly from min_points - 1 clear rays
    (a car with min_points rays gets 1 / (full_points - min_points + 1) of the step's P_D); at or above it the
    step's P_D; 0 keeps the step at min_points."""
    s = cast([box(65.0, 0.0), box(20.0, 3.5)], [1, 2])
    far, near = visibility(s, [[65.0, 0.0], [20.0, 3.5]], OCC).clear_rays
    assert MIN_POINTS <= far <= 11 <= near
    full = int(far) + 3  # the far car below it
    step = detection_probability(s, [[65.0, 0.0], [20.0, 3.5]], OCC)
    ramp = detection_probability(s, [[65.0, 0.0], [20.0, 3.5]], replace(OCC, full_points=full))
    assert step[0] > 0 and ramp[1] == pytest.approx(step[1])
    assert ramp[0] == pytest.approx(step[0] * (far - MIN_POINTS + 1) / (full - MIN_POINTS + 1))
    with pytest.raises(ValueError, match="full_points"):
        replace(OCC, full_points=-1)


def test_a_far_car_showing_only_its_side_gets_no_pd_with_the_edge_on_term():
    """A car 52 m ahead, 16 m to the side (seen low: only the beam at -1.33 deg reaches it), its rear face hidden
    by a post 20 m ahead: the rays see its side only, along the line of sight, and perception drops it as
    edge-on (sensors/perception.py). edge_on_top_m (perception's min_height_m) makes its P_D 0; with the post
    gone the rear face is seen and both the P_D and perception keep it."""
    from roadtrack.sensors import PerceptionConfig, perceive

    car, post = box(52.0, 16.0), box(20.0, 6.53, size=(1.0, 1.02, 3.0))
    edge = replace(OCC, edge_on_top_m=PerceptionConfig().min_height_m)
    hidden, free = cast([post, car], [-1, 1]), cast([car], [1])
    assert n_points(hidden, 1) >= MIN_POINTS  # the side really is hit
    vis = visibility(hidden, [car[:2]], edge, heading=[0.0])
    assert vis.clear_end_columns[0] <= 1 < vis.clear_columns[0] - 3 and vis.seen_top[0] < 0.8  # a corner at most
    assert detection_probability(hidden, [car[:2]], OCC, heading=[0.0])[0] > 0.4  # without the term: half seen
    assert detection_probability(hidden, [car[:2]], edge, heading=[0.0])[0] == 0.0
    rejected = perceive(hidden, PerceptionConfig()).rejected
    assert "edge_on" in rejected.reason[rejected.provenance == 1]

    assert detection_probability(free, [car[:2]], edge, heading=[0.0])[0] == pytest.approx(OCC.pd_nominal)
    assert 1 in perceive(free, PerceptionConfig()).detections.provenance
    with pytest.raises(ValueError, match="edge_on_lo_m"):
        replace(OCC, edge_on_lo_m=1.2)
