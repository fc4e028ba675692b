"""Synthetic HDL-32E: beam pattern, geometry of hits, range limits, occlusion, noise and dropout, validation.

Real open3d ray casting throughout. Tolerances: float32 ray casting gives ~1e-5 m at 70 m, so geometric
checks without noise use 1e-3 m.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sensors import GROUND, LidarConfig, Scan, scan

EXACT = LidarConfig(range_noise_std_m=0.0, dropout=0.0)  # noise-free sensor for geometric checks
GEOM_TOL = 1e-3  # [m]
REPO = Path(__file__).resolve().parents[1]


def car(x, y, yaw=0.0, length=4.5, width=1.8, height=1.5, z_bottom=0.0):
    return [x, y, length, width, height, yaw, z_bottom]


def to_box_frame(points, box):
    """Points (N, 3) in the frame of box [cx, cy, L, W, H, yaw, zb]: origin at its bottom centre."""
    c, s = np.cos(box[5]), np.sin(box[5])
    dx, dy = points[:, 0] - box[0], points[:, 1] - box[1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, points[:, 2] - box[6]], -1)


def face_distance(local, box):
    """Distance (N,) from box-frame points to the nearest face plane of the box."""
    half_l, half_w, h = box[2] / 2, box[3] / 2, box[4]
    return np.min(
        np.abs(np.stack([local[:, 0] - half_l, local[:, 0] + half_l, local[:, 1] - half_w,
                         local[:, 1] + half_w, local[:, 2], local[:, 2] - h], -1)),
        axis=1,
    )


def test_ray_pattern_is_hdl32e():
    cfg = LidarConfig()
    assert cfg.n_rays == 32 * 2250 == 72_000
    el = cfg.elevations_deg
    assert el.shape == (32,)
    assert el[0] == pytest.approx(-30.67, abs=1e-12) and el[-1] == pytest.approx(10.67, abs=1e-12)
    assert np.diff(el) == pytest.approx(np.full(31, 41.34 / 31), abs=1e-12)  # 1.333 deg apart
    az = cfg.azimuths_deg
    assert len(az) == 2250 and az[0] == 0.0 and az[-1] == pytest.approx(359.84, abs=1e-9)


def test_empty_road_every_downward_ray_hits_flat_ground():
    s = scan(EXACT, np.array([3.0, -2.0, 0.7]), np.zeros((0, 7)), np.zeros(0, np.int64), np.random.default_rng(0))
    # beams whose ground range 1.9 / tan(-el) is within 70 m: elevations <= -1.555 deg -> 22 of 32 beams
    assert len(s.points) == 22 * 2250
    assert np.all(s.source == GROUND)
    assert np.max(np.abs(s.points[:, 2])) < GEOM_TOL
    assert s.origin == pytest.approx([3.0, -2.0, 1.9], abs=0)
    rng_m = np.linalg.norm(s.points - s.origin, axis=1)
    assert rng_m.min() >= EXACT.min_range_m and rng_m.max() <= EXACT.max_range_m


@pytest.mark.parametrize("yaw", [0.0, 0.4])
def test_hits_on_a_known_box_lie_on_its_faces(yaw):
    box = car(12.0, 4.0, yaw=yaw)
    s = scan(EXACT, np.array([2.0, -1.0, 0.3]), np.array([box]), np.array([7]), np.random.default_rng(0))
    hit = s.source == 7
    assert hit.sum() > 300
    local = to_box_frame(s.points[hit], box)
    assert face_distance(local, box).max() < GEOM_TOL
    inside = (np.abs(local[:, 0]) <= box[2] / 2 + GEOM_TOL) & (np.abs(local[:, 1]) <= box[3] / 2 + GEOM_TOL)
    inside &= (local[:, 2] >= -GEOM_TOL) & (local[:, 2] <= box[4] + GEOM_TOL)
    assert inside.all()
    assert np.max(np.abs(s.points[s.source == GROUND, 2])) < GEOM_TOL


def test_noisy_hits_within_three_sigma_of_faces_and_range_limits_hold():
    cfg = LidarConfig()  # sigma = 2 cm, 2 % dropout
    box = car(9.0, -3.0, yaw=0.2)
    s = scan(cfg, np.array([0.0, 0.0, 0.0]), np.array([box]), np.array([1]), np.random.default_rng(1))
    d = face_distance(to_box_frame(s.points[s.source == 1], box), box)
    # the noise is along the ray, so the distance to the face is at most |noise|: P(> 3 sigma) <= 0.27 %
    assert np.mean(d < 3 * cfg.range_noise_std_m + GEOM_TOL) >= 0.99
    assert d.max() < 5 * cfg.range_noise_std_m + GEOM_TOL
    assert np.max(np.abs(s.points[s.source == GROUND, 2])) < 5 * cfg.range_noise_std_m
    r = np.linalg.norm(s.points - s.origin, axis=1)
    assert r.min() >= cfg.min_range_m and r.max() <= cfg.max_range_m


def test_boxes_beyond_max_range_or_inside_min_range_return_nothing():
    far = car(85.0, 0.0)  # nearest face at 82.75 m > 70 m
    pole = [0.6, 0.0, 0.3, 0.3, 3.0, 0.0, 0.0]  # face 0.45 m from the sensor: every hit is nearer than 1 m
    s = scan(EXACT, np.zeros(3), np.array([far, pole]), np.array([1, -1]), np.random.default_rng(0))
    assert np.count_nonzero(s.source == 1) == 0
    assert np.count_nonzero(s.source == -1) == 0
    # the pole still blocks its sector: fewer ground hits than the empty road's 22 * 2250
    assert len(s.points) < 22 * 2250 - 100


def test_occlusion_box_behind_a_truck_is_hidden():
    rng_seed = 3
    truck = car(10.0, 0.0, length=8.0, width=2.5, height=3.0)  # front face at 6 m, 2.5 m wide, 3 m high
    hidden = car(22.0, 0.0)  # same bearing, further, narrower and lower
    cfg = LidarConfig()
    alone = scan(cfg, np.zeros(3), np.array([hidden]), np.array([2]), np.random.default_rng(rng_seed))
    both = scan(cfg, np.zeros(3), np.array([truck, hidden]), np.array([1, 2]), np.random.default_rng(rng_seed))
    assert np.count_nonzero(alone.source == 2) > 100
    assert np.count_nonzero(both.source == 2) == 0
    # per-ray noise draws: the truck's points are identical whether or not the hidden car exists
    only_truck = scan(cfg, np.zeros(3), np.array([truck]), np.array([1]), np.random.default_rng(rng_seed))
    assert np.array_equal(only_truck.points[only_truck.source == 1], both.points[both.source == 1])


def test_partial_occlusion_reduces_points():
    front = car(10.0, 0.0)
    behind = car(20.0, 1.0)  # same bearing roughly, offset by 1 m: partly visible
    cfg = EXACT
    alone = scan(cfg, np.zeros(3), np.array([behind]), np.array([2]), np.random.default_rng(0))
    both = scan(cfg, np.zeros(3), np.array([front, behind]), np.array([1, 2]), np.random.default_rng(0))
    n_alone, n_both = np.count_nonzero(alone.source == 2), np.count_nonzero(both.source == 2)
    assert n_alone > 100
    assert n_both < 0.5 * n_alone


def test_same_seed_same_scan_and_different_seed_differs():
    boxes = np.array([car(10.0, 3.0, 0.1), car(-15.0, -3.5, 3.0)])
    ids = np.array([4, 9])
    a = scan(LidarConfig(), np.array([1.0, 2.0, 0.5]), boxes, ids, np.random.default_rng(42))
    b = scan(LidarConfig(), np.array([1.0, 2.0, 0.5]), boxes, ids, np.random.default_rng(42))
    c = scan(LidarConfig(), np.array([1.0, 2.0, 0.5]), boxes, ids, np.random.default_rng(43))
    assert np.array_equal(a.points, b.points) and np.array_equal(a.source, b.source)
    assert len(a.points) != len(c.points) or np.abs(a.points - c.points).max() > 1e-3
    assert a.points.dtype == np.float64 and a.source.dtype == np.int64 and a.origin.shape == (3,)


def test_dropout_fraction_is_binomial():
    cfg = replace(EXACT, dropout=0.1)
    n_rays_hitting = 22 * 2250  # ground hits of the empty road without dropout
    s = scan(cfg, np.zeros(3), np.zeros((0, 7)), np.zeros(0, np.int64), np.random.default_rng(5))
    expected, sd = 0.9 * n_rays_hitting, np.sqrt(n_rays_hitting * 0.9 * 0.1)  # 44,550 +- 67
    assert abs(len(s.points) - expected) < 4 * sd


def test_sensor_yaw_only_rotates_the_pattern():
    """Rotating the whole scene about the sensor by k azimuth steps rotates the scan exactly."""
    theta = np.deg2rad(0.16 * 300)  # 48 deg, a whole number of azimuth steps
    sensor = np.array([5.0, -2.0, 0.0])
    boxes = np.array([car(20.0, 3.0, 0.2), car(-8.0, -6.0, 1.0), [9.0, -9.0, 1.5, 1.5, 1.2, 0.0, 0.0]])
    ids = np.array([0, 1, -1])
    a = scan(EXACT, sensor, boxes, ids, np.random.default_rng(0))
    c, s_ = np.cos(theta), np.sin(theta)
    rot = np.array([[c, -s_], [s_, c]])
    moved = boxes.copy()
    moved[:, :2] = (boxes[:, :2] - sensor[:2]) @ rot.T + sensor[:2]
    moved[:, 5] += theta
    b = scan(EXACT, sensor + [0.0, 0.0, theta], moved, ids, np.random.default_rng(0))
    assert np.array_equal(a.source, b.source)
    a_rot = (a.points[:, :2] - sensor[:2]) @ rot.T + sensor[:2]
    assert np.abs(b.points[:, :2] - a_rot).max() < GEOM_TOL
    assert np.abs(b.points[:, 2] - a.points[:, 2]).max() < GEOM_TOL


def test_far_from_world_origin_keeps_millimetre_precision():
    offset = np.array([12_345.0, -6_789.0])
    boxes = np.array([car(10.0, 3.0, 0.3), car(-20.0, -3.0)])
    a = scan(EXACT, np.array([0.0, 0.0, 0.2]), boxes, np.array([0, 1]), np.random.default_rng(0))
    moved = boxes.copy()
    moved[:, :2] += offset
    b = scan(EXACT, np.array([*offset, 0.2]), moved, np.array([0, 1]), np.random.default_rng(0))
    assert np.array_equal(a.source, b.source)
    assert np.abs(b.points[:, :2] - offset - a.points[:, :2]).max() < GEOM_TOL


def test_raised_panel_is_hit_only_where_it_is():
    panel = [15.0, 8.0, 0.1, 3.0, 1.0, 0.0, 2.5]  # sign panel, 2.5-3.5 m above the road
    s = scan(EXACT, np.zeros(3), np.array([panel]), np.array([-1]), np.random.default_rng(0))
    z = s.points[s.source == -1, 2]
    assert len(z) > 10
    assert z.min() >= 2.5 - GEOM_TOL and z.max() <= 3.5 + GEOM_TOL


@pytest.mark.parametrize(
    "pose, boxes, ids, match",
    [
        (np.zeros(3), np.array([car(5, 0)[:6]]), np.array([0]), "boxes"),  # 6 columns
        (np.zeros(3), np.array([[5, 0, 4.5, np.nan, 1.5, 0, 0]]), np.array([0]), "boxes"),
        (np.zeros(3), np.array([[5, 0, 4.5, -1.8, 1.5, 0, 0]]), np.array([0]), "boxes"),
        (np.zeros(3), np.array([car(5, 0)]), np.array([0, 1]), "box_ids"),
        (np.zeros(3), np.array([car(5, 0)]), np.array([-2]), "box_ids"),
        (np.zeros(3), np.array([car(5, 0)]), np.array([0.5]), "box_ids"),
        (np.zeros(2), np.array([car(5, 0)]), np.array([0]), "sensor_xy_yaw"),
        (np.array([0, np.inf, 0]), np.array([car(5, 0)]), np.array([0]), "sensor_xy_yaw"),
    ],
)
def test_bad_inputs_raise_value_error_naming_the_argument(pose, boxes, ids, match):
    with pytest.raises(ValueError, match=match):
        scan(LidarConfig(), pose, boxes, ids, np.random.default_rng(0))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"n_beams": 0}, "n_beams"),
        ({"dropout": 1.0}, "dropout"),
        ({"min_range_m": 80.0}, "min_range_m"),
        ({"range_noise_std_m": -0.1}, "range_noise_std_m"),
        ({"elevation_min_deg": float("nan")}, "elevation_min_deg"),
    ],
)
def test_bad_config_raises_value_error(kwargs, match):
    with pytest.raises(ValueError, match=match):
        LidarConfig(**kwargs)


def test_scan_validates_its_arrays():
    with pytest.raises(ValueError, match="Scan.source"):
        Scan(points=np.zeros((3, 3)), source=np.zeros(2, np.int64), origin=np.zeros(3))


def _run(code: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          cwd=REPO, timeout=60, **kw)


def test_sensors_imports_no_simulator_viewer_or_sibling_package():
    out = _run("""
        import sys, numpy as np, sensors
        sensors.perceive(sensors.scan(sensors.LidarConfig(), np.zeros(3), np.zeros((0, 7)), np.zeros(0, int),
                                      np.random.default_rng(0)), sensors.PerceptionConfig())
        bad = [m for m in ("highway_env", "rerun", "trackers", "testbed") if m in sys.modules]
        print(len(bad), *bad)
    """)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["0"]


def test_open3d_import_failure_is_one_clear_line(tmp_path):
    """A stand-in `open3d` that fails like the GPU wheel without libusb (the only non-real open3d here)."""
    (tmp_path / "open3d").mkdir()
    (tmp_path / "open3d" / "__init__.py").write_text(
        "raise ImportError('libusb-1.0.so.0: cannot open shared object file: No such file or directory')\n"
    )
    out = _run(f"""
        import sys; sys.path.insert(0, {str(tmp_path)!r})
        import numpy as np, sensors
        try:
            sensors.scan(sensors.LidarConfig(), np.zeros(3), np.zeros((0, 7)), np.zeros(0, int),
                         np.random.default_rng(0))
        except RuntimeError as e:
            print(type(e).__name__, "|", str(e).count(chr(10)), "|", e)
    """)
    assert out.returncode == 0, out.stderr
    kind, newlines, message = out.stdout.strip().split(" | ")
    assert kind == "RuntimeError" and newlines == "0"
    assert "libusb-1.0" in message and "open3d-cpu" in message
