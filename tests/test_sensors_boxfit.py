"""Vehicle box fit (sensors/boxfit.py) on real open3d scans: centres, shapes, occlusion, covariance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadtrack.sensors.boxfit import (
    BoxFit,
    BoxFitConfig,
    SizePrior,
    fit_vehicle_box,
    open_ends_from_ranges,
    shape_class,
)
from roadtrack.sensors.lidar import LidarConfig, Scan, scan

LIDAR = LidarConfig()  # HDL-32E with range noise and dropout
GROUND_CUT_M = 0.25  # points below this height are the ground's (what ground removal takes)


def box(x, y, yaw=0.0, length=4.6, width=1.8, height=1.5, lift=0.0):
    return [x, y, length, width, height, yaw, lift]


def cast(boxes, ids, sensor=(0.0, 0.0, 0.0), seed=0) -> Scan:
    return scan(LIDAR, np.asarray(sensor, float), np.array(boxes, float), np.array(ids), np.random.default_rng(seed))


def cluster(s: Scan, ident: int) -> np.ndarray:
    """(n, 3) points of the box `ident`, without the ground-level ones (as after ground removal)."""
    mask = (s.source == ident) & (s.points[:, 2] > GROUND_CUT_M)
    return s.points[mask]


def fit(pts: np.ndarray, s: Scan, hint=0.0, **kw) -> BoxFit:
    return fit_vehicle_box(pts[:, :2], s.origin[:2], top_m=float(pts[:, 2].max()), heading_hint=hint, **kw)


def range_image(s: Scan) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) ranges and (N,) ray index per point: the Scan's, or rebuilt from the points (sensor yaw 0)."""
    if getattr(s, "ranges", np.zeros((0, 0))).size:
        return s.ranges, s.ray
    d = s.points - s.origin
    a = np.round(np.mod(np.degrees(np.arctan2(d[:, 1], d[:, 0])), 360.0) / LIDAR.azimuth_step_deg).astype(int)
    a %= len(LIDAR.azimuths_deg)
    step = (LIDAR.elevation_max_deg - LIDAR.elevation_min_deg) / (LIDAR.n_beams - 1)
    el = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])))
    b = np.round((el - LIDAR.elevation_min_deg) / step).astype(int)
    ranges = np.full((len(LIDAR.azimuths_deg), LIDAR.n_beams), np.inf)
    ranges[a, b] = np.linalg.norm(d, axis=1)
    return ranges, a * LIDAR.n_beams + b


def nearest_distance(b) -> float:
    """Distance from the sensor at the origin to the footprint of box b [m]."""
    c, s = math.cos(b[5]), math.sin(b[5])
    u, v = abs(-b[0] * c - b[1] * s), abs(b[0] * s - b[1] * c)
    return math.hypot(max(u - b[2] / 2, 0.0), max(v - b[3] / 2, 0.0))


# --- centres against the centroid -----------------------------------------------------------------------

@pytest.mark.parametrize("view", ["behind", "angled"])
def test_box_centre_bias_is_smaller_than_the_centroid_at_30_m(view):
    """A 4.5 m car at 30 m, seen from behind (one face) or at an angle (an L), 8 noisy scans."""
    target = np.array([30.0, 0.0]) if view == "behind" else np.array([26.0, 15.0])
    errors, centroid_errors = [], []
    for seed in range(8):
        s = cast([box(*target, length=4.5)], [1], seed=seed)
        pts = cluster(s, 1)
        errors.append(fit(pts, s).centre - target)
        centroid_errors.append(pts[:, :2].mean(axis=0) - target)
    bias, centroid_bias = np.linalg.norm(np.mean(errors, axis=0)), np.linalg.norm(np.mean(centroid_errors, axis=0))
    spread = np.linalg.norm(np.std(errors, axis=0))
    assert bias < 0.15 and spread < 0.1  # the 4.6 m prior on a 4.5 m car: 0.05 m expected end-on
    assert centroid_bias > 0.7  # the centroid sits on the seen faces: 1.2-2.2 m short
    assert bias < centroid_bias / 5


def test_end_on_truck_is_completed_to_the_truck_prior():
    """A 15 x 2.5 x 3.8 m truck seen from behind at 20 m (its rear only): completed along its axis."""
    target = np.array([20.0 + 7.5, 0.0])  # rear face at 20 m
    s = cast([box(*target, length=15.0, width=2.5, height=3.8)], [4], seed=3)
    pts = cluster(s, 4)
    f = fit(pts, s)
    centroid_error = np.linalg.norm(pts[:, :2].mean(axis=0) - target)
    assert f.size_class == "truck" and f.faces == 1 and f.completed
    assert abs(math.remainder(f.heading, math.pi)) < math.radians(1.0)  # the 2.5 m rear is an end, not a side
    assert np.linalg.norm(f.centre - target) < 1.0 < 7.0 < centroid_error  # prior 15.4 m: 0.2 m expected
    assert f.length == pytest.approx(15.4) and f.width == pytest.approx(2.5, abs=0.1)
    # the hidden length is uncertain: the along-axis std is the prior's half spread, ~1 m
    assert 0.8 < math.sqrt(f.R[0, 0]) < 1.2 and math.sqrt(f.R[1, 1]) < 0.2


@pytest.mark.parametrize("bearing_deg", [3.0, 6.0, 10.0])
def test_rear_seen_at_a_slight_angle_is_still_completed(bearing_deg):
    """Issue 8: a car end-on at a slight angle gave a fitted width of 0.9-1.2 m and no completion."""
    target = 25.0 * np.array([math.cos(math.radians(bearing_deg)), math.sin(math.radians(bearing_deg))])
    s = cast([box(*target, length=4.5)], [2], seed=1)
    pts = cluster(s, 2)
    for hint in (0.0, None):
        f = fit(pts, s, hint=hint)
        assert f.completed and np.linalg.norm(f.centre - target) < 0.25


def test_far_car_with_few_points_gets_a_sane_fit():
    for k, target in enumerate([np.array([65.0, 0.0]), np.array([60.0, 20.0]), np.array([-62.0, -12.0])]):
        s = cast([box(*target, yaw=0.05)], [1], seed=k)
        pts = cluster(s, 1)
        assert 3 <= len(pts) <= 60
        f = fit(pts, s)
        assert np.linalg.norm(f.centre - target) < 0.6
        assert f.length == pytest.approx(4.6, abs=0.3) and f.width == pytest.approx(1.8, abs=0.2)


@pytest.mark.parametrize("radius", [12.0, 40.0])
def test_centre_is_continuous_as_the_view_turns_around_the_car(radius):
    """Sensor around a 4.5 m car every 3 deg (end-on, angled, side, ...): error <= 0.5 m, small jumps."""
    target = np.array([100.0, 50.0])
    centres = []
    for k, phi in enumerate(np.radians(np.arange(0.0, 360.0, 3.0))):
        sensor = (target[0] + radius * math.cos(phi), target[1] + radius * math.sin(phi), 0.0)
        s = cast([box(*target, yaw=0.2, length=4.5)], [1], sensor=sensor, seed=k)
        centres.append(fit(cluster(s, 1), s, hint=0.2).centre)
    centres = np.array(centres)
    errors = np.linalg.norm(centres - target, axis=1)
    jumps = np.linalg.norm(np.diff(np.vstack([centres, centres[:1]]), axis=0), axis=1)
    assert errors.max() < 0.5  # measured 0.08 (12 m) and 0.14 (40 m)
    assert jumps.max() < 0.3


# --- occlusion ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("target", [(30.0, 0.0), (30.0, 3.5), (20.0, -3.5)])
def test_partly_hidden_car_does_not_jump_while_an_occluder_passes(target):
    """A 3 m high van crosses the line of sight 10-12 m ahead; the open ends come from the range image."""
    target = np.array(target)
    occluder_x = 12.0 if target[0] > 25 else 10.0
    centres, errors, free_errors = [], [], []
    for k, y in enumerate(np.arange(-2.0, 6.01, 0.1)):
        s = cast([box(*target, length=4.5), box(occluder_x, y, height=3.0, length=4.5)], [1, 2], seed=k)
        mask = (s.source == 1) & (s.points[:, 2] > GROUND_CUT_M)
        if mask.sum() < 5:
            continue  # hidden
        ranges, ray = range_image(s)
        ends = open_ends_from_ranges(ranges, ray[mask])
        f = fit(s.points[mask], s, open_ends=ends)
        centres.append(f.centre)
        errors.append(np.linalg.norm(f.centre - target))
        free_errors.append(np.linalg.norm(fit(s.points[mask], s).centre - target))
    jumps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    assert len(centres) >= 50
    assert max(errors) < 1.0 and jumps.max() < 1.5  # measured 0.52 / 0.64 at worst
    assert max(free_errors) > 2.0  # without the open ends the hidden half is taken as missing


def test_open_ends_from_a_range_image():
    ranges = np.full((12, 3), np.inf)
    ranges[3:6, 1:] = 20.0  # the cluster: azimuth columns 3-5, beams 1-2
    ranges[2, 1] = 8.0  # a nearer object just clockwise of it
    ranges[6, :] = 35.0  # background counter-clockwise of it
    ray = np.array([a * 3 + b for a in range(3, 6) for b in (1, 2)])
    assert open_ends_from_ranges(ranges, ray) == (True, False)
    assert open_ends_from_ranges(ranges, ray, look=1) == (True, False)
    ranges[2, 1] = 19.8  # within the margin: the same surface, not an occluder
    assert open_ends_from_ranges(ranges, ray) == (False, False)
    # a cluster across azimuth 0 (columns 11, 0, 1) with an occluder at column 2
    wrap = np.full((12, 2), np.inf)
    wrap[[11, 0, 1], 0] = 30.0
    wrap[2, 0] = 10.0
    assert open_ends_from_ranges(wrap, np.array([22, 0, 2])) == (False, True)
    with pytest.raises(ValueError, match="ray"):
        open_ends_from_ranges(wrap, np.array([24]))
    with pytest.raises(ValueError, match="ranges"):
        open_ends_from_ranges(np.zeros(5), np.array([0]))


def test_occluded_sliver_of_a_rear_is_completed_from_its_true_edge():
    """Hand-made: a 0.3 m piece of a car's rear (the rest hidden counter-clockwise of it)."""
    v = np.linspace(-0.9, -0.6, 8)
    xy = np.column_stack([np.full(8, 27.75), v])  # the rear face of a car centred at (30, 0)
    f = fit_vehicle_box(xy, np.zeros(2), top_m=1.3, heading_hint=0.0, open_ends=(False, True))
    assert f.shape == "vehicle"  # not a post: its small footprint is the occluder's doing
    assert np.linalg.norm(f.centre - [30.05, 0.0]) < 0.25
    post = fit_vehicle_box(xy, np.zeros(2), top_m=1.3, heading_hint=0.0)
    assert post.shape == "post" and not post.completed


# --- shapes ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("x, y, yaw", [(15.0, 8.0, 0.0), (8.0, 6.0, 0.1), (30.0, 8.0, 0.2), (20.0, 0.0, math.pi / 2),
                                       (25.0, 4.0, 1.2)])
def test_sign_panel_is_not_a_vehicle_and_is_not_moved(x, y, yaw):
    s = cast([box(x, y, yaw=yaw, length=2.0, width=0.15, height=1.2, lift=1.0)], [-1])
    pts = s.points[s.source == -1]
    assert shape_class(pts[:, :2], pts[:, 2], float(pts[:, 2].max())) == "panel"
    f = fit(pts, s, z=pts[:, 2])
    assert f.shape == "panel" and not f.completed
    assert np.linalg.norm(f.centre - [x, y]) < 0.2


def test_guard_rail_run_is_thin_long_and_post_is_post():
    rails = [box(x, -8.0, length=4.0, width=0.3, height=0.75) for x in np.arange(-30.0, 31.0, 4.0)]
    s = cast(rails + [box(10.0, 6.0, length=0.2, width=0.2, height=1.2), box(30.0, -7.0, length=0.2, width=0.2,
                                                                           height=1.2)],
             [-1] * len(rails) + [7, 8])
    rail = s.points[s.source == -1]
    for lo, hi in ((-30.0, 30.0), (10.0, 18.0)):  # the whole run, and 8 m of it
        part = rail[(rail[:, 0] > lo) & (rail[:, 0] < hi)]
        assert shape_class(part[:, :2], part[:, 2], float(part[:, 2].max())) == "thin_long"
    for ident in (7, 8):
        post = s.points[s.source == ident]
        assert shape_class(post[:, :2], post[:, 2], float(post[:, 2].max())) == "post"


def test_vehicles_are_vehicles():
    cars = [box(10.0, 3.5), box(30.0, 0.0), box(60.0, 3.5, yaw=0.1), box(-20.0, -3.5), box(-45.0, 3.5)]
    trucks = [box(20.0, -7.0, length=15.0, width=2.5, height=3.8), box(-30.0, -8.0, length=15.0, width=2.5,
                                                                       height=3.8)]
    s = cast(cars + trucks, np.arange(7))
    for ident in range(7):
        pts = cluster(s, ident)
        assert shape_class(pts[:, :2], pts[:, 2], float(pts[:, 2].max())) == "vehicle"


# --- heading --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("yaw_deg", [5.0, 17.0, 45.0, 90.0])
def test_heading_follows_the_hint_and_a_clearly_turned_vehicle(yaw_deg):
    """A lane change (5 deg) stays in the hint's window; a car turned across the road is seen as such."""
    yaw = math.radians(yaw_deg)
    for k, target in enumerate([(20.0, 3.5), (40.0, -3.5), (12.0, 0.0)]):
        s = cast([box(*target, yaw=yaw)], [1], seed=k)
        f = fit(cluster(s, 1), s, hint=0.0)
        assert abs(math.remainder(f.heading - yaw, math.pi)) < math.radians(2.0)
        assert np.linalg.norm(f.centre - target) < 0.2


# --- covariance -----------------------------------------------------------------------------------------

def _random_scene(rng, truck: bool):
    """Four vehicles in four 90 deg sectors, 5-65 m away (their footprints >= 4 m from the sensor), each
    aligned with the road (x) within a 3 deg std; cars half 5.0 x 2.0 (scripted scenario vehicles), half
    the background traffic's 4.2-5.0 x 1.75-2.0; trucks 12-18.75 x 2.45-2.55 x 3.4-4.0."""
    boxes = []
    for sector in range(4):
        if truck:
            size = (rng.uniform(12.0, 18.75), rng.uniform(2.45, 2.55), rng.uniform(3.4, 4.0))
        elif rng.random() < 0.5:
            size = (5.0, 2.0, 1.6)
        else:
            size = (rng.uniform(4.2, 5.0), rng.uniform(1.75, 2.0), rng.uniform(1.4, 1.7))
        while True:
            r, bearing = rng.uniform(5.0, 65.0), math.radians(90.0 * sector + rng.uniform(10.0, 80.0))
            yaw = rng.normal(0.0, math.radians(3.0)) + (math.pi if rng.random() < 0.5 else 0.0)
            b = [r * math.cos(bearing), r * math.sin(bearing), *size, yaw, 0.0]
            if nearest_distance(b) >= 4.0:
                break
        boxes.append(b)
    return np.array(boxes)


@pytest.mark.parametrize("truck", [False, True])
def test_covariance_is_calibrated_on_ray_cast_vehicles(truck):
    """Normalised squared centre errors e' R^-1 e, chi-square(2) if R were exact (mean 2). Measured with a
    hint: cars mean 1.4-1.5, trucks 0.8-1.05 (4 seeds; 1.8-2.1 before issue 17 grew a truck's length from
    its seen side: its along-axis error halved, 0.05 m, under R's 0.05 m floor); mean centre error cars
    0.10 m (centroid 1.2 m), trucks 0.07-0.09 m (centroid 2.7-2.9 m)."""
    rng = np.random.default_rng(17 if truck else 11)
    nees = {True: [], False: []}
    errors, centroid_errors = [], []
    for k in range(25 if truck else 40):
        boxes = _random_scene(rng, truck)
        s = scan(LIDAR, np.zeros(3), boxes, np.arange(4), rng)
        ranges, ray = range_image(s)
        for ident, b in enumerate(boxes):
            mask = (s.source == ident) & (s.points[:, 2] > GROUND_CUT_M)
            pts = s.points[mask]
            if len(pts) < 5:
                continue
            ends = open_ends_from_ranges(ranges, ray[mask])  # a long truck may hide part of another
            for hinted in (True, False):
                hint = rng.normal(0.0, math.radians(1.0)) if hinted else None  # a road map's lane heading
                f = fit(pts, s, hint=hint, open_ends=ends)
                e = f.centre - b[:2]
                nees[hinted].append(float(e @ np.linalg.solve(f.R, e)))
                assert np.allclose(f.R, f.R.T) and np.all(np.linalg.eigvalsh(f.R) > 0)
            errors.append(np.linalg.norm(e))
            centroid_errors.append(np.linalg.norm(pts[:, :2].mean(axis=0) - b[:2]))
    for hinted, values in nees.items():
        values = np.array(values)
        assert len(values) >= 90
        assert 0.7 < np.median(values) < 2.5  # chi-square(2) median 1.39
        assert np.mean(values > 13.8) < 0.03  # chi-square(2) 99.9 % point: no heavy tail
    # with a road hint (the pipeline's default) the mean too; without one, a truck side cut short by an
    # occluder can be taken for its rear (1 in 160 views), which the mean does not forgive
    assert (0.6 if truck else 1.0) < np.mean(nees[True]) < 3.0
    assert np.mean(errors) < np.mean(centroid_errors) / 5


def test_covariance_grows_with_range_and_with_a_hidden_length():
    near = fit_vehicle_box(np.column_stack([np.full(20, 10.0), np.linspace(-0.9, 0.9, 20)]), np.zeros(2),
                           top_m=1.5, heading_hint=0.0)
    assert near.faces == 1 and near.completed
    # one end seen: the hidden length gives the along-axis (x) std of half the prior's: 0.2 m
    assert math.sqrt(near.R[0, 0]) == pytest.approx(math.hypot(0.2, 0.05, 0.02), rel=0.05)
    assert near.R[0, 0] > 2 * near.R[1, 1]
    # a side seen whole from beside it: both ends are seen, the length is the points'
    side = fit_vehicle_box(np.column_stack([np.linspace(-2.3, 2.3, 40), np.full(40, 10.0)]), np.zeros(2),
                           top_m=1.5, heading_hint=0.0)
    assert side.length == pytest.approx(4.6, abs=0.05) and math.sqrt(side.R[0, 0]) < 0.1


# --- interface ------------------------------------------------------------------------------------------

def test_bad_arguments_raise_naming_the_argument():
    xy = np.array([[10.0, 0.0], [10.0, 1.0], [10.0, -1.0]])
    with pytest.raises(ValueError, match="xy"):
        fit_vehicle_box(np.zeros((0, 2)), np.zeros(2), top_m=1.5)
    with pytest.raises(ValueError, match="xy"):
        fit_vehicle_box(np.zeros((3, 3)), np.zeros(2), top_m=1.5)
    with pytest.raises(ValueError, match="sensor_xy"):
        fit_vehicle_box(xy, np.zeros(3), top_m=1.5)
    with pytest.raises(ValueError, match="top_m"):
        fit_vehicle_box(xy, np.zeros(2), top_m=float("nan"))
    with pytest.raises(ValueError, match="heading_hint"):
        fit_vehicle_box(xy, np.zeros(2), top_m=1.5, heading_hint=float("inf"))
    with pytest.raises(ValueError, match="open_ends"):
        fit_vehicle_box(xy, np.zeros(2), top_m=1.5, open_ends=(True,))
    with pytest.raises(ValueError, match="z"):
        fit_vehicle_box(xy, np.zeros(2), top_m=1.5, z=np.zeros(2))
    with pytest.raises(ValueError, match="BoxFitConfig.face_tol_m"):
        BoxFitConfig(face_tol_m=0.0)
    with pytest.raises(ValueError, match="SizePrior.length_m"):
        SizePrior("bus", 3.0, -12.0, 2.5, 1.0, 0.1)


def test_one_and_two_points_give_a_box_along_the_hint_or_the_line_of_sight():
    one = fit_vehicle_box(np.array([[20.0, 0.0]]), np.zeros(2), top_m=0.8, heading_hint=0.0)
    assert one.faces == 0 and one.centre == pytest.approx([22.3, 0.0], abs=1e-9)  # extended away, along the hint
    two = fit_vehicle_box(np.array([[0.0, 20.0], [0.6, 20.0]]), np.zeros(2), top_m=1.2)
    assert abs(math.remainder(two.heading - math.atan2(20.0, 0.3), math.pi)) < 1e-9  # along the line of sight
    assert two.centre[1] > 21.0
    for f in (one, two):
        assert f.length >= f.width and np.all(np.linalg.eigvalsh(f.R) > 0)
