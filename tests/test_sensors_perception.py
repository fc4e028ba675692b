"""Ground segmentation, clustering, detections and Poisson clutter, on real open3d scans."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

import roadtrack.sensors.perception as perception
from roadtrack.sensors.boxfit import lshape_rectangle, min_area_rectangle, open_ends_from_ranges
from roadtrack.sensors import (
    CLUSTER_METHODS,
    COMPLETED,
    MERGED,
    REJECT_REASONS,
    SPLIT,
    Rejected,
    GROUND,
    GROUND_METHODS,
    REPRESENTATIVES,
    ClusterConfig,
    Detections,
    GroundConfig,
    LidarConfig,
    PerceptionConfig,
    Scan,
    cluster,
    clutter_detections,
    perceive,
    poisson_clutter,
    scan,
    segment_ground,
)

EXACT = LidarConfig(range_noise_std_m=0.0, dropout=0.0)
LANES = [-5.25, -1.75, 1.75, 5.25]


def car(x, y, yaw=0.0, length=4.5, width=1.8, height=1.5):
    return [x, y, length, width, height, yaw, 0.0]


@pytest.fixture(scope="module")
def traffic() -> Scan:
    """Ego in lane 2 of a 4-lane road, 10 cars from -35 m to +55 m (realistic noise and dropout)."""
    xs = [-35, -22, -12, 8, 15, 25, 33, 42, 55, -28]
    boxes = np.array([car(x, LANES[i % 4]) for i, x in enumerate(xs)])
    return scan(LidarConfig(), np.array([0.0, -1.75, 0.0]), boxes, np.arange(10), np.random.default_rng(0))


def permuted(s: Scan, seed: int) -> tuple[Scan, np.ndarray]:
    perm = np.random.default_rng(seed).permutation(len(s.points))
    return dataclasses.replace(s, points=s.points[perm], source=s.source[perm], ray=s.ray[perm]), perm


# --- ground ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", sorted(GROUND_METHODS))
def test_ground_segmentation_agrees_with_truth(traffic, method):
    is_ground = segment_ground(traffic.points, GroundConfig(method=method))
    truth = traffic.source == GROUND
    assert is_ground.shape == truth.shape and is_ground.dtype == bool
    assert np.mean(is_ground == truth) >= 0.98
    assert np.mean(is_ground[truth]) >= 0.999  # the disagreement is the bottom 0.2 m of the cars


def test_ransac_does_not_take_a_wall_for_the_road():
    rng = np.random.default_rng(0)
    wall = np.column_stack([rng.uniform(0, 30, 2000), np.full(2000, 5.0), rng.uniform(0.5, 4.0, 2000)])
    assert segment_ground(wall, GroundConfig(method="ransac")).sum() == 0


def test_grid_ground_absorbs_a_road_height_offset():
    """Road 0.15 m higher than expected: grid follows it, a fixed threshold does not (tolerance 0.1 m)."""
    rng = np.random.default_rng(1)
    road = np.column_stack([rng.uniform(-20, 20, (4000, 2)), np.full(4000, 0.15)])
    body = np.column_stack([rng.uniform(4, 8, 500), rng.uniform(-1, 1, 500), rng.uniform(0.45, 1.6, 500)])
    pts = np.vstack([road, body])
    truth = np.r_[np.ones(4000, bool), np.zeros(500, bool)]
    grid = segment_ground(pts, GroundConfig(method="grid", height_tol_m=0.1))
    height = segment_ground(pts, GroundConfig(method="height", height_tol_m=0.1))
    assert np.mean(grid == truth) == 1.0
    assert np.mean(height[:4000]) == 0.0


def test_unknown_method_lists_the_valid_ones():
    with pytest.raises(ValueError, match="grid, height, ransac"):
        GroundConfig(method="plane")
    with pytest.raises(ValueError, match="dbscan, grid"):
        ClusterConfig(method="kmeans")
    with pytest.raises(ValueError, match="bbox_center, centroid, lshape_center, vehicle_box"):
        PerceptionConfig(fit="median")


def test_segment_ground_rejects_bad_points():
    with pytest.raises(ValueError, match="points"):
        segment_ground(np.zeros((4, 2)), GroundConfig())
    with pytest.raises(ValueError, match="points"):
        segment_ground(np.array([[0.0, 0.0, np.nan]]), GroundConfig())


# --- clustering -----------------------------------------------------------------------------------------

blobs = st.lists(
    st.tuples(st.floats(-30, 30), st.floats(-30, 30), st.integers(1, 40)), min_size=1, max_size=6
)


@pytest.mark.parametrize("method", sorted(CLUSTER_METHODS))
@settings(max_examples=25, deadline=None, database=None)
@given(centres=blobs, seed=st.integers(0, 2**32 - 1))
def test_cluster_labels_do_not_depend_on_point_order(method, centres, seed):
    rng = np.random.default_rng(seed)
    pts = np.vstack([c[:2] + rng.normal(0, 0.6, (n, 2)) for *c, n in centres])
    pts = np.column_stack([pts, rng.uniform(0.3, 1.5, len(pts))])
    cfg = ClusterConfig(method=method)
    labels = cluster(pts, cfg)
    perm = rng.permutation(len(pts))
    assert np.array_equal(cluster(pts[perm], cfg), labels[perm])  # same partition, same numbering
    sizes = np.bincount(labels[labels >= 0])
    assert sizes.size == 0 or sizes.min() >= cfg.min_points
    assert labels.dtype == np.int64 and labels.min() >= -1


@pytest.mark.parametrize("method", sorted(CLUSTER_METHODS))
def test_clusters_smaller_than_min_points_are_noise(method):
    four = np.array([[0, 0, 1], [0.1, 0, 1], [0, 0.1, 1], [0.1, 0.1, 1.0]])
    five = np.vstack([four + [10, 0, 0], [[10.05, 0.05, 1.2]]])
    labels = cluster(np.vstack([four, five]), ClusterConfig(method=method, min_points=5))
    assert labels.tolist() == [-1] * 4 + [0] * 5


def test_grid_labels_equal_the_sort_first_numbering():
    # the grid labels the points unsorted and numbers its clusters by their lexicographically first
    # points; the reference sorts every point first (as DBSCAN still does), with ties in x across clusters
    import roadtrack.sensors.clustering as clustering

    rng = np.random.default_rng(11)
    pts = np.vstack([c + rng.normal(0, 0.5, (n, 3)) for c, n in
                     (([0, 0, 1], 40), ([8, 3, 1], 30), ([8, -6, 1], 25), ([-9, 5, 1], 3), ([20, 0, 1], 60))])
    pts[::7, 0] = np.round(pts[::7, 0])  # many equal x
    # clusters whose first points share x (the order falls to y; within a cluster to z)
    pts = np.vstack([pts, [[-15.0, 10.0, 2.0], [-15.0, 0.0, 1.0], [-15.0, 0.0, 0.5], [-15.0, 20.0, 0.7],
                           [-15.0, 20.0, 0.2], [-14.9, 20.0, 0.3]]])
    for min_points in (1, 5, 31):
        cfg = ClusterConfig(method="grid", min_points=min_points)
        order = np.lexsort((pts[:, 2], pts[:, 1], pts[:, 0]))
        ref = np.empty(len(pts), np.int64)
        ref[order] = clustering._canonical(clustering._grid(pts[order], cfg), min_points)
        assert np.array_equal(cluster(pts, cfg), ref)


def test_shape_prefilter_keeps_every_object_shape_class_may_reject(traffic):
    # _screen classifies only the objects _maybe_not_vehicle passes on; every other one must be a vehicle
    from roadtrack.sensors.boxfit import shape_class

    cfg = PerceptionConfig()
    boxes = np.array([car(12.0, 1.75), [20.0, -8.0, 30.0, 0.3, 0.8, 0.0, 0.0], [9.0, 7.0, 0.3, 0.3, 3.0, 0.0, 0.0],
                      [15.0, 9.0, 3.0, 0.2, 1.0, 0.0, 1.2]])  # a car, a rail, a post, a raised panel
    s = scan(LidarConfig(), np.array([0.0, 0.0, 0.0]), boxes, np.array([0, -1, -1, -1]), np.random.default_rng(2))
    for sc in (s, traffic):
        is_ground = segment_ground(sc.points, cfg.ground, sc.origin)
        cand = np.flatnonzero(~is_ground)
        objects = perception._raw_objects(sc.points, cand, cluster(sc.points[cand], cfg.cluster))
        st = perception._stats(sc.points, objects, 0.0, sc.origin[:2], None)
        maybe = perception._maybe_not_vehicle(st, cfg.boxfit)
        shapes = [shape_class(sc.points[o, :2], sc.points[o, 2], float(st.top[k]), cfg.boxfit)
                  for k, o in enumerate(objects)]
        assert all(sh == "vehicle" for sh, m in zip(shapes, maybe) if not m)
        if sc is s:
            assert {"thin_long", "post", "panel"} <= set(shapes)  # the scene exercises every rule


# --- perception -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", sorted(CLUSTER_METHODS))
def test_two_separated_boxes_give_two_detections_whatever_the_point_order(method):
    boxes = np.array([car(10.0, 4.0, 0.1), car(12.0, -4.5, -0.1)])
    s = scan(LidarConfig(), np.zeros(3), boxes, np.array([3, 8]), np.random.default_rng(2))
    cfg = PerceptionConfig(cluster=ClusterConfig(method=method), fit="lshape_center")
    res = perceive(s, cfg)
    det = res.detections
    assert len(det) == 2
    assert sorted(det.provenance.tolist()) == [3, 8]
    for k, vid in enumerate(det.provenance):
        # L-shaped view of a near car: the L-shape box centre is within 0.25 m of the true centre
        assert np.linalg.norm(det.z[k] - boxes[[3, 8].index(vid), :2]) < 0.25
    for seed in range(3):
        sp, perm = permuted(s, seed)
        rp = perceive(sp, cfg)
        assert np.array_equal(rp.labels, res.labels[perm])
        assert np.array_equal(rp.is_ground, res.is_ground[perm])
        assert np.array_equal(rp.detections.z, det.z) and np.array_equal(rp.detections.extent, det.extent)
        assert np.array_equal(rp.detections.provenance, det.provenance)


@pytest.mark.parametrize("representative", sorted(REPRESENTATIVES))
def test_detections_do_not_depend_on_point_order(traffic, representative):
    cfg = PerceptionConfig(fit=representative)
    res = perceive(traffic, cfg)
    sp, perm = permuted(traffic, 9)
    rp = perceive(sp, cfg)
    assert len(res.detections) >= 7
    for field in ("z", "provenance", "n_points", "extent"):
        assert np.array_equal(getattr(rp.detections, field), getattr(res.detections, field))  # exactly
    assert np.array_equal(rp.labels, res.labels[perm])


@pytest.mark.parametrize("yaw", [0.0, -0.4])
def test_l_shaped_view_recovers_box_size_and_centre(yaw):
    box = car(8.0, 6.0, yaw=yaw)  # two faces visible from the origin
    s = scan(EXACT, np.zeros(3), np.array([box]), np.array([0]), np.random.default_rng(0))
    det = perceive(s, PerceptionConfig(fit="lshape_center")).detections
    assert len(det) == 1
    assert np.linalg.norm(det.z[0] - box[:2]) < 0.1
    assert det.extent[0] == pytest.approx([4.5, 1.8, 1.5], abs=0.1)


def test_box_fits_are_exact_on_a_fully_seen_footprint():
    t = np.linspace(0, 1, 50)[:, None]
    corners = np.array([[-2.25, -0.9], [2.25, -0.9], [2.25, 0.9], [-2.25, 0.9], [-2.25, -0.9]])
    outline = np.vstack([a + t * (b - a) for a, b in zip(corners[:-1], corners[1:])])
    c, s = np.cos(0.7), np.sin(0.7)
    xy = outline @ np.array([[c, s], [-s, c]]) + [1000.0, -250.0]  # rotate by 0.7 rad, far from the origin
    centre, length, width = min_area_rectangle(xy)
    assert np.abs(centre - [1000.0, -250.0]).max() < 1e-9
    assert (length, width) == pytest.approx((4.5, 1.8), abs=1e-9)
    centre, length, width = lshape_rectangle(xy)  # 1 deg heading grid: ~2 cm of size error
    assert np.abs(centre - [1000.0, -250.0]).max() < 1e-6
    assert (length, width) == pytest.approx((4.5, 1.8), abs=0.05)


def test_labels_index_detections_and_provenance_is_the_plurality(traffic):
    res = perceive(traffic, PerceptionConfig())
    det = res.detections
    assert len(det) >= 7  # 9 of 10 cars visible; far ones may split or drop (realistic sparsity)
    assert res.labels.shape == (len(traffic.points),) and res.labels.dtype == np.int64
    assert np.all(res.labels[res.is_ground] == -1)
    for k in range(len(det)):
        members = res.labels == k
        assert det.n_points[k] == members.sum()
        values, counts = np.unique(traffic.source[members], return_counts=True)
        assert det.provenance[k] == values[np.argmax(counts)]
    assert set(det.provenance.tolist()) <= set(range(10))  # no roadside objects in this scene


def test_centroid_representative_is_the_mean_of_the_cluster(traffic):
    res = perceive(traffic, PerceptionConfig(fit="centroid", complete_one_face=False))
    for k in range(len(res.detections)):
        mean = traffic.points[res.labels == k, :2].mean(axis=0)
        assert np.abs(res.detections.z[k] - mean).max() < 1e-9


def test_roadside_objects_make_natural_clutter():
    bush = [6.0, 9.0, 1.5, 1.5, 1.2, 0.3, 0.0]
    barrier = [0.0, -9.0, 40.0, 0.3, 0.8, 0.0, 0.0]  # longer than any vehicle: rejected
    tree = [-6.0, 9.5, 0.8, 0.8, 9.0, 0.0, 0.0]  # cropped at 4 m, still taller than a vehicle: rejected
    boxes = np.array([bush, barrier, tree, car(-15.0, 1.75)])
    s = scan(LidarConfig(), np.zeros(3), boxes, np.array([-1, -1, -1, 5]), np.random.default_rng(4))
    det = perceive(s, PerceptionConfig()).detections
    clutter = det.provenance == -1
    assert clutter.sum() == 1
    assert np.linalg.norm(det.z[clutter][0] - bush[:2]) < 1.0
    assert set(det.provenance[~clutter].tolist()) == {5}  # a car at 15 m may come in two pieces
    everything = perceive(s, PerceptionConfig(vehicle_like=False)).detections
    assert len(everything) >= 4  # without the vehicle-like test, barrier and tree come back


def test_empty_scan_gives_no_detections():
    s = Scan(points=np.zeros((0, 3)), source=np.zeros(0, np.int64), origin=np.zeros(3))
    res = perceive(s, PerceptionConfig())
    assert len(res.detections) == 0 and res.detections.z.shape == (0, 2)
    assert res.is_ground.shape == (0,) and res.labels.shape == (0,)


def test_detections_empty_concat_and_validation():
    e = Detections.empty()
    assert e.z.shape == (0, 2) and e.extent.shape == (0, 3) and e.provenance.dtype == np.int64
    a = Detections(np.ones((2, 2)), np.array([1, -1]), np.array([30, 8]), np.ones((2, 3)))
    b = e.concat(a).concat(a)
    assert len(b) == 4 and b.provenance.tolist() == [1, -1, 1, -1]
    with pytest.raises(ValueError, match="Detections.provenance"):
        Detections(np.ones((2, 2)), np.array([1]), np.array([30, 8]), np.ones((2, 3)))


# --- Poisson clutter ------------------------------------------------------------------------------------

def test_clutter_count_is_poisson_with_mean_density_times_area():
    density, radius, n_frames = 1e-2, 30.0, 400
    lam = density * np.pi * radius**2  # 28.27 per frame
    rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(11).spawn(n_frames)]
    counts = np.array([len(poisson_clutter(r, density, np.array([5.0, -3.0]), radius)) for r in rngs])
    assert abs(counts.mean() - lam) < 4 * np.sqrt(lam / n_frames)  # mean within 4 standard errors
    dispersion = np.sum((counts - lam) ** 2) / lam  # ~ chi2(n_frames) for Poisson counts
    assert stats.chi2.ppf(0.001, n_frames) < dispersion < stats.chi2.ppf(0.999, n_frames)


def test_clutter_is_uniform_in_the_disk():
    centre, radius = np.array([100.0, 50.0]), 20.0
    z = poisson_clutter(np.random.default_rng(0), 0.5, centre, radius)  # ~628 points
    r = np.linalg.norm(z - centre, axis=1)
    assert z.shape[1] == 2 and z.dtype == np.float64 and r.max() <= radius
    assert stats.kstest((r / radius) ** 2, "uniform").pvalue > 1e-3  # uniform area: (r/R)^2 ~ U(0, 1)


def test_clutter_detections_and_degenerate_arguments():
    d = clutter_detections(np.random.default_rng(1), 0.05, np.zeros(2), 10.0)
    assert len(d) > 0 and np.all(d.provenance == -1) and np.all(d.n_points == 0)
    for density in (0.0, -1.0):
        assert poisson_clutter(np.random.default_rng(1), density, np.zeros(2), 10.0).shape == (0, 2)
    assert poisson_clutter(np.random.default_rng(1), 1.0, np.zeros(2), 0.0).shape == (0, 2)


@pytest.mark.parametrize(
    "density, centre, radius, match",
    [(float("nan"), np.zeros(2), 10.0, "density"), (0.1, np.zeros(3), 10.0, "center_xy"),
     (0.1, np.zeros(2), -1.0, "radius_m"), (0.1, np.array([0.0, np.inf]), 10.0, "center_xy")],
)
def test_clutter_bad_arguments_raise(density, centre, radius, match):
    with pytest.raises(ValueError, match=match):
        poisson_clutter(np.random.default_rng(0), density, centre, radius)


def test_tree_crown_over_a_thin_trunk_is_not_a_vehicle():
    # trunk + crown as the testbed builds trees: a 0.4 m trunk up to 2.5 m, a 3 x 3 x 4 m crown above it
    trunk = [20.0, 9.0, 0.4, 0.4, 2.5, 0.0, 0.0]
    crown = [20.0, 9.0, 3.0, 3.0, 4.0, 0.0, 2.5]
    s = scan(LidarConfig(), np.zeros(3), np.array([trunk, crown, car(-15.0, 1.75)]), np.array([-1, -1, 5]),
             np.random.default_rng(5))
    for cfg in (PerceptionConfig(), PerceptionConfig.thesis()):
        det = perceive(s, cfg).detections
        assert det.provenance.tolist() == [5]  # the car stays, the tree is rejected
    # a far tree whose crown top is missed by the rings looks no taller than a truck: in the thesis
    # pipeline only the median height tells it from a vehicle; the full one sees a crown over a trunk
    loose = {"max_median_height_m": 10.0, "max_object_height_m": 10.0}
    det_loose = perceive(s, dataclasses.replace(PerceptionConfig.thesis(), **loose)).detections
    assert (det_loose.provenance == -1).sum() == 1
    res = perceive(s, PerceptionConfig(**loose))
    assert res.detections.provenance.tolist() == [5] and "lifted" in res.rejected.reason.tolist()


@pytest.mark.parametrize("x", [25.0, 30.0, -25.0])  # nearer, one ring also lands on the roof: a split
def test_one_face_completion_moves_a_rear_view_to_the_car_centre(x):
    # a car straight ahead (or behind) in the sensor's lane shows only its rear (front) face
    boxes = np.array([car(x, 0.0)])
    s = scan(EXACT, np.zeros(3), boxes, np.array([7]), np.random.default_rng(0))
    thesis = PerceptionConfig.thesis()
    raw = perceive(s, dataclasses.replace(thesis, complete_one_face=False)).detections
    done = perceive(s, thesis).detections  # the plain representative's one-face completion
    box = perceive(s, PerceptionConfig()).detections  # the vehicle box fit completes by itself
    assert len(raw) == len(done) == len(box) == 1
    assert abs(abs(raw.z[0, 0]) - (abs(x) - 2.25)) < 0.1  # the visible face, half a car short
    for det in (done, box):  # completed with the 4.6 m prior: within 0.2 m of the 4.5 m car's centre
        assert abs(det.z[0, 0] - x) < 0.2
        assert abs(det.z[0, 1]) < 0.1
    assert raw.flags[0] == 0 and done.flags[0] == box.flags[0] == COMPLETED


# --- issue 8: the full pipeline -------------------------------------------------------------------------
# Roadside objects as testbed/world/roadside.py builds them (sizes copied: sensors tests do not import testbed).
ROAD_EDGE = 7.0  # |y| of the road edges of LANES
RAIL = (4.0, 0.3, 0.75)  # guard-rail segments end to end, 1.5 m beyond the road edge
POST = (0.2, 0.2, 1.2)  # 0.5 m behind the rail line
SIGN = (2.0, 0.15, 1.2)  # panel lifted 1 m, 3 m beyond the road edge


def rails_and_posts(post_every: float = 20.0) -> list[list[float]]:
    out = []
    for side in (-1.0, 1.0):
        y_rail, y_post = side * (ROAD_EDGE + 1.5 + RAIL[1] / 2), side * (ROAD_EDGE + 2.0)
        out += [[x + 2.0, y_rail, *RAIL, 0.0, 0.0] for x in np.arange(-80.0, 80.0, 4.0)]
        out += [[x, y_post, *POST, 0.0, 0.0] for x in np.arange(-70.0, 71.0, post_every)]
    return out


def test_detections_default_fields_and_concat():
    d = Detections(np.ones((2, 2)), np.array([1, -1]), np.array([30, 8]), np.ones((2, 3)))
    assert d.R.shape == (2, 2, 2) and np.array_equal(d.R, np.broadcast_to(0.25 * np.eye(2), (2, 2, 2)))
    assert np.array_equal(d.centroid, d.z) and d.heading.tolist() == [0.0, 0.0] and d.flags.tolist() == [0, 0]
    full = Detections(np.zeros((1, 2)), [3], [40], np.ones((1, 3)), R=[[[0.1, 0.02], [0.02, 0.3]]],
                      centroid=[[0.5, 0.0]], heading=[1.2], flags=[MERGED | COMPLETED])
    both = d.concat(full)
    assert len(both) == 3 and both.flags.tolist() == [0, 0, MERGED | COMPLETED]
    assert np.array_equal(both.R[2], [[0.1, 0.02], [0.02, 0.3]]) and both.centroid[2].tolist() == [0.5, 0.0]
    assert Detections.empty().R.shape == (0, 2, 2) and Detections.empty().concat(full).heading.tolist() == [1.2]
    with pytest.raises(ValueError, match="Detections.R"):
        Detections(np.zeros((1, 2)), [3], [40], np.ones((1, 3)), R=[[[0.1, 0.05], [0.0, 0.3]]])
    with pytest.raises(ValueError, match="Detections.flags"):
        Detections(np.zeros((1, 2)), [3], [40], np.ones((1, 3)), flags=[0, 1])


@pytest.mark.parametrize(
    "kwargs, match",
    [({"roi": 1}, "PerceptionConfig.roi"), ({"roi_margin_m": -0.5}, "PerceptionConfig.roi_margin_m"),
     ({"min_height_mode": "ring"}, "PerceptionConfig.min_height_mode"), ({"fit": "box"}, "PerceptionConfig.fit"),
     ({"merge_fragments": "yes"}, "PerceptionConfig.merge_fragments"), ({"merge_gap_m": 0.0}, "merge_gap_m"),
     ({"split_gap_m": 0.2}, "PerceptionConfig.split_gap_m"), ({"max_splits": 0}, "PerceptionConfig.max_splits"),
     ({"ref_height_m": float("nan")}, "PerceptionConfig.ref_height_m"),
     ({"max_truck_length_m": 6.0}, "PerceptionConfig.max_truck_length_m"),
     ({"boxfit": {}}, "PerceptionConfig.boxfit"), ({"edge_on_width_m": -1.0}, "edge_on_width_m")],
)
def test_perception_config_rejects_bad_new_fields(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        PerceptionConfig(**kwargs)


def test_thesis_preset_is_the_plain_pipeline():
    t, full = PerceptionConfig.thesis(), PerceptionConfig()
    assert (t.roi, t.min_height_mode, t.merge_fragments, t.split_vehicles, t.fit, t.complete_one_face) == (
        False, "fixed", False, False, "lshape_center", True)
    assert (full.roi, full.min_height_mode, full.merge_fragments, full.split_vehicles, full.fit) == (
        True, "beams", True, True, "vehicle_box")
    assert (t.min_height_m, t.max_object_height_m, t.max_median_height_m, t.max_length_m) == (0.8, 3.5, 2.0, 8.0)
    assert t.max_length_for(np.array([1.5, 3.9])).tolist() == [8.0, 8.0]  # no truck allowance in the thesis
    assert full.max_length_for(np.array([1.5, 3.9])).tolist() == [8.0, 20.0]


@pytest.mark.parametrize("lane", [-1.75, 1.75, 5.25])
def test_a_car_at_65_m_is_detected_but_not_by_the_thesis_pipeline(lane):
    # sensor at 1.9 m: at 65 m the highest HDL-32E beam under 1.4 m runs at 1.9 - 65 tan(1.33 deg) = 0.39 m
    boxes = np.array([car(65.0, lane)])
    for seed in range(3):
        s = scan(LidarConfig(), np.array([0.0, -1.75, 0.0]), boxes, np.array([2]), np.random.default_rng(seed))
        full = perceive(s, PerceptionConfig()).detections
        assert full.provenance.tolist() == [2]
        assert 0.3 < full.extent[0, 2] < 0.5  # its top: it passed only by the range-aware bound
        assert np.linalg.norm(full.z[0] - [65.0, lane]) < 1.5
        thesis = perceive(s, PerceptionConfig.thesis())
        assert len(thesis.detections) == 0
        assert thesis.rejected.reason[thesis.rejected.provenance == 2].tolist() == ["too_low"]
        # a scan without its beam pattern (the 3-argument Scan) falls back to the fixed bound
        bare = perceive(Scan(points=s.points, source=s.source, origin=s.origin), PerceptionConfig())
        assert len(bare.detections) == 0 and bare.rejected.reason.tolist() == ["too_low"]


@pytest.mark.parametrize("x", [15.0, 20.0, 30.0, 35.0])
def test_a_post_standing_on_a_guard_rail_does_not_lift_the_rail(x):
    # one rail segment with a post 0.2 m behind it: the post's points make the cluster's top 0.9-1.2 m,
    # above the 0.8 m bound, but most of its footprint stays at the rail's 0.75 m
    boxes = np.array([[x, -(ROAD_EDGE + 1.65), *RAIL, 0.0, 0.0], [x + 1.0, -(ROAD_EDGE + 2.0), *POST, 0.0, 0.0]])
    for seed in range(3):
        s = scan(LidarConfig(), np.array([0.0, -1.75, 0.0]), boxes, np.array([-1, -1]), np.random.default_rng(seed))
        res = perceive(s, PerceptionConfig(roi=False))
        assert len(res.detections) == 0 and res.rejected.reason.tolist() == ["too_low"]
        assert len(perceive(s, PerceptionConfig(roi=False, robust_height=False)).detections) == 1  # top only


@pytest.mark.parametrize("seed", range(4))
def test_guard_rails_and_posts_are_never_detections_even_without_the_map(seed):
    # rails on both edges with posts, cars in all lanes occluding parts of them, the ego in any lane
    rng = np.random.default_rng(seed)
    static = rails_and_posts()
    xs = rng.permutation(np.arange(-60.0, 61.0, 12.0))[:8] + rng.uniform(-2.0, 2.0, 8)
    cars = [car(x, LANES[i % 4], height=rng.uniform(1.4, 1.7)) for i, x in enumerate(xs)]
    ego_y = LANES[seed % 4]
    cars = [c for c in cars if not (abs(c[0]) < 6.0 and c[1] == ego_y)]
    boxes = np.array(static + cars)
    ids = np.r_[np.full(len(static), -1), np.arange(len(cars))]
    s = scan(LidarConfig(), np.array([0.0, ego_y, 0.0]), boxes, ids, rng)
    res = perceive(s, PerceptionConfig(roi=False))
    det = res.detections
    assert np.all(det.provenance >= 0)
    assert len(set(det.provenance.tolist())) == len(det)  # one detection per car
    visible = [v for v in range(len(cars)) if (s.source == v).sum() >= 60]
    assert set(visible) <= set(det.provenance.tolist())  # the cars are still there
    rej = res.rejected
    static = rej.provenance == -1
    # rail runs go by their size; beyond 47 m the range-aware bound lets a 0.75 m rail piece pass, and only
    # its shape (edge-on, too small) rejects it: no static object out there is rejected by height
    assert np.any(static & np.isin(rej.reason, ["too_long", "thin_long"]))
    far = static & (np.hypot(rej.centre[:, 0], rej.centre[:, 1] - ego_y) > 47.0)
    assert not np.any(rej.reason[far] == "too_low")


def test_a_sign_panel_is_rejected_by_shape_and_not_moved():
    for x, yaw in ((-20.0, 0.3), (8.0, 0.0), (15.0, -0.3), (30.0, 1.2)):
        sign = [x, ROAD_EDGE + 3.0, *SIGN, yaw, 1.0]
        s = scan(LidarConfig(), np.array([0.0, -1.75, 0.0]), np.array([sign]), np.array([-1]),
                 np.random.default_rng(1))
        res = perceive(s, PerceptionConfig(roi=False))
        assert len(res.detections) == 0 and res.rejected.reason.tolist() == ["panel"]
        assert np.linalg.norm(res.rejected.centre[0] - sign[:2]) < 0.2
        kept = perceive(s, PerceptionConfig(roi=False, vehicle_like=False)).detections  # no selection at all
        assert len(kept) == 1 and np.linalg.norm(kept.z[0] - sign[:2]) < 0.2  # the fit does not complete it
        old = perceive(s, PerceptionConfig.thesis()).detections  # the thesis pushes it a car deeper
        assert len(old) == 1 and np.linalg.norm(old.z[0] - sign[:2]) > 1.5


@pytest.mark.parametrize("seed", range(3))
def test_a_car_split_into_rear_face_and_roof_ring_is_merged(seed):
    # straight ahead at 15 m: the rear face and, 4.4 m further, a ring grazing the roof's far edge
    s = scan(LidarConfig(), np.zeros(3), np.array([car(15.0, 0.0)]), np.array([6]), np.random.default_rng(seed))
    raw = np.unique(perceive(s, PerceptionConfig()).cluster_labels[s.source == 6])
    assert len(raw[raw >= 0]) == 2  # two raw clusters
    assert perceive(s, PerceptionConfig.thesis()).detections.provenance.tolist() == [6, 6]
    det = perceive(s, PerceptionConfig()).detections
    assert det.provenance.tolist() == [6] and det.flags[0] & MERGED
    assert np.linalg.norm(det.z[0] - [15.0, 0.0]) < 0.2


@pytest.mark.parametrize("seed", range(3))
def test_a_car_cut_in_two_by_a_pole_in_front_is_merged(seed):
    # a 0.2 m pole 6 m ahead hides the middle of the side of a car in the next lane, 18 m ahead
    target = car(18.0, 1.75)
    pole = [6.0, -1.75 + 6.0 / 18.0 * (1.75 - 0.9 + 1.75), 0.2, 0.2, 3.0, 0.0, 0.0]
    s = scan(LidarConfig(), np.array([0.0, -1.75, 0.0]), np.array([target, pole]), np.array([4, -1]),
             np.random.default_rng(seed))
    res = perceive(s, PerceptionConfig())
    raw = np.unique(res.cluster_labels[s.source == 4])
    assert len(raw[raw >= 0]) == 2
    assert perceive(s, PerceptionConfig.thesis()).detections.provenance.tolist() == [4, 4]
    det = res.detections
    assert det.provenance.tolist() == [4] and det.flags[0] & MERGED
    assert np.linalg.norm(det.z[0] - target[:2]) < 0.25


@pytest.mark.parametrize("gap", [0.5, 1.0, 5.0])
def test_close_cars_in_one_lane_are_separated_where_the_points_allow(gap):
    # two cars bumper to bumper in one lane, seen from the next lane on the left, the rear one 15 m ahead:
    # from there the gap is in view (the side's points are ~0.3 m apart), so even at 1 m the cars are two
    # detections; at 0.5 m the grid joins them into one 9.5 m cluster, which the split cuts at the gap and
    # the thesis pipeline rejects as too long (both cars lost)
    rear, front = car(15.0, 0.0), car(15.0 + 4.5 + gap, 0.0)
    for seed in range(3):
        s = scan(LidarConfig(), np.array([0.0, 3.5, 0.0]), np.array([rear, front]), np.array([0, 1]),
                 np.random.default_rng(seed))
        res = perceive(s, PerceptionConfig())
        det = res.detections
        assert sorted(det.provenance.tolist()) == [0, 1]
        for k, truth in ((0, rear), (1, front)):
            members = res.labels == int(np.flatnonzero(det.provenance == k)[0])
            assert np.all(s.source[members] == k)  # no detection holds points of both
            assert np.linalg.norm(det.z[det.provenance == k][0] - truth[:2]) < 0.5
        raw = np.unique(res.cluster_labels[s.source >= 0])
        joined = len(raw[raw >= 0]) == 1
        assert joined == (gap == 0.5) and bool(np.all(det.flags & SPLIT)) == joined
        thesis = perceive(s, PerceptionConfig.thesis()).detections  # (it may split a car into face and roof)
        assert set(thesis.provenance.tolist()) == (set() if gap == 0.5 else {0, 1})


def test_rejected_record_and_raw_cluster_labels():
    boxes = np.array(rails_and_posts() + [[12.0, 12.0, 2.0, 2.0, 1.5, 0.3, 0.0], car(20.0, 1.75), car(-30.0, -5.25)])
    ids = np.r_[np.full(len(boxes) - 2, -1), [0, 1]]
    s = scan(LidarConfig(), np.array([0.0, -1.75, 0.0]), boxes, ids, np.random.default_rng(8))
    cfg = PerceptionConfig(cluster=ClusterConfig(scan_line_links=False))  # the links attach noise points too
    res = perceive(s, cfg)
    rej = res.rejected
    counts = rej.counts()
    assert list(counts) == list(REJECT_REASONS) and sum(counts.values()) == len(rej) > 0
    assert rej.centre.shape == (len(rej), 2) and set(rej.reason.tolist()) <= set(REJECT_REASONS)
    assert counts["too_low"] > 0 and counts["too_long"] + counts["thin_long"] > 0  # near rails, long rail runs
    # raw labels: the clusterer's own partition of the non-ground points below max_height_m
    keep = ~res.is_ground & (s.points[:, 2] <= cfg.max_height_m)
    assert np.array_equal(res.cluster_labels[keep], cluster(s.points[keep], cfg.cluster))
    assert np.all(res.cluster_labels[~keep] == -1)
    # every kept point belongs to a raw cluster; every rejected object's points have label -1
    assert np.all(res.cluster_labels[res.labels >= 0] >= 0)
    assert np.sum(res.labels >= 0) == res.detections.n_points.sum()
    assert np.sum((res.labels < 0) & (res.cluster_labels >= 0)) == rej.n_points.sum()
    with pytest.raises(ValueError, match="Rejected.reason"):
        Rejected(np.zeros((1, 2)), ["windy"], [1], [5], [0])


@pytest.mark.parametrize("x, length", [(20.0, 15.0), (45.0, 12.0), (-25.0, 18.0)])
def test_a_truck_is_one_detection_and_not_a_thesis_one(x, length):
    # 2.5 m wide, 3.8 m high trucks in the next lane: longer than max_length_m, and at 45 m the median
    # of their rings (1.0, 1.9, 2.8, 3.7 m) can exceed 2.5 m; the thesis pipeline drops them (too tall)
    boxes = np.array([[x, 1.75, length, 2.5, 3.8, 0.0, 0.0]])
    for seed in range(3):
        s = scan(LidarConfig(), np.array([0.0, -1.75, 0.0]), boxes, np.array([9]), np.random.default_rng(seed))
        det = perceive(s, PerceptionConfig()).detections
        assert det.provenance.tolist() == [9] and det.extent[0, 2] > 2.5
        assert len(perceive(s, PerceptionConfig.thesis()).detections) == 0


def test_batched_open_ends_agree_with_the_box_fit_module(traffic):
    # perception computes every object's occluded azimuth edges at once; boxfit's per-cluster function is
    # the reference
    # poles in front of cars cut them into fragments whose ends at the pole are open
    poles = [[6.0, -1.75 + 6.0 / 18.0 * 2.6, 0.2, 0.2, 3.0, 0.0, 0.0],
             [-5.0, -1.75 + 5.0 / 20.0 * 5.25, 0.3, 0.3, 3.0, 0.0, 0.0]]
    boxes = np.array([car(18.0, 1.75), car(-20.0, 3.5), car(25.0, -1.75), car(8.0, -5.25), *poles])
    scans = [traffic, scan(LidarConfig(), np.array([0.0, -1.75, 0.3]), boxes, np.r_[np.arange(4), -1, -1],
                           np.random.default_rng(6))]
    n_open = 0
    for s in scans:
        cfg = PerceptionConfig()
        is_ground = segment_ground(s.points, cfg.ground)
        cand = np.flatnonzero(~is_ground)
        objects = perception._raw_objects(s.points, cand, cluster(s.points[cand], cfg.cluster))
        st = perception._stats(s.points, objects, 0.0, s.origin[:2], None)
        keys = np.arange(len(objects))
        batch = perception._open_ends(s, st, keys)
        for k, ends in zip(keys, batch):
            assert ends == open_ends_from_ranges(s.ranges, s.ray[objects[k]])
            n_open += sum(ends)
    assert n_open >= 4  # the scenes do have occluded edges
    bare = Scan(points=traffic.points, source=traffic.source, origin=traffic.origin)
    assert perception._open_ends(bare, perception._stats(bare.points, [np.arange(10)], 0.0, np.zeros(2), None),
                                 np.array([0])) == [None]


def test_split_and_merged_detections_do_not_depend_on_point_order():
    boxes = np.array([car(15.0, 0.0), car(20.0, 0.0), car(14.0, 3.5), car(-25.0, 7.0)])  # 0.5 m gap; ahead
    s = scan(LidarConfig(), np.array([0.0, 3.5, 0.0]), boxes, np.arange(4), np.random.default_rng(4))
    res = perceive(s, PerceptionConfig())
    flags = res.detections.flags
    assert np.any(flags & SPLIT) and np.any(flags & MERGED)
    for seed in range(3):
        sp, perm = permuted(s, seed)
        rp = perceive(sp, PerceptionConfig())
        for field in ("z", "R", "extent", "heading", "flags", "provenance"):
            assert np.array_equal(getattr(rp.detections, field), getattr(res.detections, field))
        assert np.array_equal(rp.labels, res.labels[perm])
        assert np.array_equal(rp.rejected.centre, res.rejected.centre)
