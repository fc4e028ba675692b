"""Road map region of interest: RoadMap queries, and perception's ROI and lane-heading prior on real scans."""

from __future__ import annotations

import numpy as np
import pytest

import roadtrack.sensors.perception as perception
from roadtrack.sensors import OFF_ROAD, LidarConfig, PerceptionConfig, RoadMap, perceive, scan

LANES = [-5.25, -1.75, 1.75, 5.25]  # a 4-lane road, 3.5 m lanes, edges at +-7 m
EGO = np.array([0.0, -1.75, 0.0])


def straight_road(x0: float = -100.0, x1: float = 100.0) -> RoadMap:
    xs = np.arange(x0, x1 + 1e-9, 1.0)
    centre = np.array([[x, y] for y in LANES for x in xs])
    return RoadMap(centre, np.zeros(len(centre)), np.full(len(centre), 1.75))


def car(x, y, yaw=0.0, length=4.5, width=1.8, height=1.5):
    return [x, y, length, width, height, yaw, 0.0]


# --- RoadMap --------------------------------------------------------------------------------------------

def test_on_road_is_within_the_half_width_plus_margin():
    road = straight_road()
    y = np.array([-1.75, 0.0, 6.9, 7.4, 7.9, 8.1, -8.6, 12.0])  # lateral positions (road: |y| <= 7 m)
    xy = np.column_stack([np.full(len(y), 10.0), y])  # abreast of a sample: distance = |y - lane centre|
    assert road.on_road(xy, 0.0).tolist() == [True, True, True, False, False, False, False, False]
    assert road.on_road(xy, 1.0).tolist() == [True, True, True, True, True, False, False, False]
    assert road.on_road(xy, 1.5).tolist() == [True, True, True, True, True, True, False, False]
    # between two samples the distance to the nearest one is at most sqrt(d^2 + 0.5^2): the edge moves
    # in by at most 0.07 m for a 1.75 m half width
    assert road.on_road(np.array([[10.5, 6.92], [10.5, 6.93]]), 0.0).tolist() == [True, False]  # edge 6.927
    assert road.on_road(np.zeros((0, 2)), 1.0).shape == (0,)


def test_heading_at_follows_a_curve():
    r, t = 200.0, np.arange(0.0, 0.5, 1.0 / 200.0)  # arc of radius 200 m sampled every 1 m
    centre = np.column_stack([r * np.sin(t), r * (1.0 - np.cos(t))])
    road = RoadMap(centre, t.copy(), np.full(len(t), 1.75))
    q = np.array([[r * np.sin(0.2), r * (1.0 - np.cos(0.2)) + 1.0], [r * np.sin(0.41), r * (1.0 - np.cos(0.41))]])
    # nearest sample within 0.5 m along the arc: heading within 0.5 / 200 rad
    assert road.heading_at(q) == pytest.approx([0.2, 0.41], abs=0.5 / r + 1e-9)
    assert road.heading_at(np.zeros((0, 2))).shape == (0,)


@pytest.mark.parametrize(
    "centre, heading, half_width, match",
    [
        (np.zeros((3, 3)), np.zeros(3), np.ones(3), "RoadMap.centre"),
        (np.zeros((0, 2)), np.zeros(0), np.ones(0), "RoadMap.centre"),
        (np.zeros((3, 2)), np.zeros(2), np.ones(3), "RoadMap.heading"),
        (np.zeros((3, 2)), np.zeros(3), np.array([1.0, 0.0, 1.0]), "RoadMap.half_width"),
        (np.array([[0.0, np.nan], [1.0, 0.0]]), np.zeros(2), np.ones(2), "RoadMap.centre"),
        (np.zeros((2, 2)), np.array([0.0, np.inf]), np.ones(2), "RoadMap.heading"),
    ],
)
def test_road_map_rejects_bad_arrays(centre, heading, half_width, match):
    with pytest.raises(ValueError, match=match):
        RoadMap(centre, heading, half_width)


@pytest.mark.parametrize("kind", ["straight", "ring", "sparse", "one sample"])
def test_the_grid_look_up_is_the_kd_trees_bit_for_bit(kind):
    """RoadMap's compiled grid (roi_jit.grid_nearest) gives scipy cKDTree's nearest samples and distances, bit for bit,
    for points on and far off the road, on cell edges and outside the map's box."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(11)
    if kind == "straight":
        road = straight_road()
    elif kind == "ring":
        a = np.arange(0.0, 2 * np.pi, 1.0 / 40.0)
        road = RoadMap(np.column_stack([40.0 * np.cos(a), 40.0 * np.sin(a)]), a + np.pi / 2, np.full(len(a), 1.75))
    elif kind == "sparse":  # 2 km x 2 km, few samples: cells larger than GRID_CELL_M
        c = rng.uniform(-1000.0, 1000.0, (300, 2))
        road = RoadMap(c, np.zeros(300), np.full(300, 1.75))
    else:
        road = RoadMap(np.array([[3.0, -2.0]]), np.zeros(1), np.ones(1))
    lo, hi = road.centre.min(axis=0) - 60.0, road.centre.max(axis=0) + 60.0
    h = road._grid[2]
    q = np.concatenate([rng.uniform(lo, hi, (4000, 2)), road.centre[::7] + 0.25,
                        road._grid[0] + h * rng.integers(-3, 40, (200, 2)),  # exactly on cell edges
                        np.array([[1e5, -3e4], [-2e6, 0.0]])])
    d_tree, k_tree = cKDTree(road.centre).query(q)
    d, k = road.nearest(q)
    np.testing.assert_array_equal(k, k_tree)
    np.testing.assert_array_equal(d, d_tree)
    np.testing.assert_array_equal(road.nearest_index(q), k)
    np.testing.assert_array_equal(road.heading_at(q[:50]), road.heading[k[:50]])
    assert road.nearest_index(np.zeros((0, 2))).shape == (0,)
    if kind == "sparse":
        assert h > 4.0


def test_equal_distances_are_the_kd_trees_to_decide():
    """A point exactly as far from two samples (here: a lane's end and the next lane's start at one position, as on
    u_turn's road) gets the sample scipy's cKDTree gives, as before the grid; the tree is made only then."""
    from scipy.spatial import cKDTree

    xs = np.arange(0.0, 30.0)
    centre = np.concatenate([np.array([[29.0, 0.0], [29.0, 4.0]]),  # repeated by samples 31 and 32
                             np.column_stack([xs, np.zeros(30)]), np.column_stack([xs[::-1], np.full(30, 4.0)])])
    road = RoadMap(centre, np.zeros(len(centre)), np.ones(len(centre)))
    road.nearest(np.array([[10.3, 0.2], [5.0, 3.9]]))
    assert road._tree == []  # no tie: the grid alone
    q = np.array([[29.4, -0.3], [28.8, 4.6], [29.0, 2.0], [10.3, 0.2]])
    d_tree, k_tree = cKDTree(centre).query(q)
    d, k = road.nearest(q)
    np.testing.assert_array_equal(k, k_tree)  # [31, 32, 31, 12] with scipy 1.x: not the lowest index, 0 or 1
    np.testing.assert_array_equal(d, d_tree)
    assert len(road._tree) == 1


def test_road_map_queries_reject_bad_arguments():
    road = straight_road()
    with pytest.raises(ValueError, match="margin_m"):
        road.on_road(np.zeros((1, 2)), -1.0)
    with pytest.raises(ValueError, match="xy"):
        road.on_road(np.zeros((2, 3)), 1.0)
    with pytest.raises(ValueError, match="xy"):
        road.heading_at(np.array([[np.nan, 0.0]]))
    with pytest.raises(TypeError, match="road"):
        perceive(scan(LidarConfig(), EGO, np.zeros((0, 7)), np.zeros(0, int), np.random.default_rng(0)),
                 PerceptionConfig(), road="map")


# --- ROI in perception ----------------------------------------------------------------------------------

@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_bush_beside_the_road_is_rejected_with_the_map_and_kept_without(seed):
    # a vehicle-sized bush 1 m beyond a 1.5 m shoulder (testbed/world/roadside.py places them so); a car on the
    # road and one straddling the road edge (its centre 0.4 m beyond the outer lane) are kept either way
    rng = np.random.default_rng(seed)
    size = rng.uniform([2.0, 1.6, 1.2], [3.5, 2.5, 2.0])
    bush = [rng.uniform(10.0, 30.0), -(7.0 + 1.5 + 1.0 + size[1] / 2), *size, rng.uniform(-np.pi, np.pi), 0.0]
    boxes = np.array([bush, car(-18.0, 1.75), car(25.0, 7.3)])
    s = scan(LidarConfig(), EGO, boxes, np.array([-1, 4, 5]), rng)
    road = straight_road()
    on = perceive(s, PerceptionConfig(), road)
    off = perceive(s, PerceptionConfig(roi=False), road)
    assert sorted(on.detections.provenance.tolist()) == [4, 5]
    assert sorted(off.detections.provenance.tolist()) == [-1, 4, 5]  # vehicle-like: only the map removes it
    bush_det = off.detections.z[off.detections.provenance == -1][0]
    assert np.linalg.norm(bush_det - bush[:2]) < 2.0
    rej = on.rejected
    k = np.flatnonzero(rej.reason == "off_road")
    assert len(k) == 1 and rej.provenance[k[0]] == -1 and rej.flags[k[0]] & OFF_ROAD
    assert np.linalg.norm(rej.centre[k[0]] - bush_det) < 1e-9  # the same fitted centre
    assert on.rejected.counts()["off_road"] == 1 and off.rejected.counts()["off_road"] == 0
    # without a map there is no ROI, whatever cfg.roi says
    assert sorted(perceive(s, PerceptionConfig()).detections.provenance.tolist()) == [-1, 4, 5]


def test_the_box_fit_gets_the_lane_heading_at_the_centroid(monkeypatch):
    # a diagonal road (heading 0.4 rad): every fit of a kept object gets road.heading_at(centroid) as hint
    theta = 0.4
    s_along = np.arange(-100.0, 100.0, 1.0)
    axis, normal = np.array([np.cos(theta), np.sin(theta)]), np.array([-np.sin(theta), np.cos(theta)])
    centre = np.vstack([s_along[:, None] * axis + off * normal for off in (-1.75, 1.75)])
    road = RoadMap(centre, np.full(len(centre), theta), np.full(len(centre), 1.75))
    cars = [(p * axis + off * normal) for p, off in ((15.0, 1.75), (-25.0, -1.75), (40.0, 1.75))]
    boxes = np.array([car(*c, yaw=theta) for c in cars])
    s = scan(LidarConfig(), np.array([*(-1.75 * normal), theta]), boxes, np.arange(3), np.random.default_rng(3))
    seen = []
    real = perception.fit_vehicle_boxes_unchecked  # perception's entry to boxfit: all fits of a frame in one call

    def spy(xy, z, starts, n, sensor_xy, tops, hints, open_ends, cfg):
        for k in range(len(starts)):
            seen.append((xy[starts[k]:starts[k] + n[k]].mean(axis=0), None if hints is None else hints[k]))
        return real(xy, z, starts, n, sensor_xy, tops, hints, open_ends, cfg)

    monkeypatch.setattr(perception, "fit_vehicle_boxes_unchecked", spy)
    det = perceive(s, PerceptionConfig(), road).detections
    assert sorted(det.provenance.tolist()) == [0, 1, 2] and len(seen) >= 3
    for centroid, hint in seen:
        assert hint == pytest.approx(road.heading_at(centroid[None])[0], abs=1e-12)
    assert np.abs(np.sin(det.heading - theta)).max() < np.sin(np.deg2rad(3.0))  # aligned with the lane
    seen.clear()
    perceive(s, PerceptionConfig())  # no map: no hint
    assert seen and all(hint is None for _, hint in seen)
