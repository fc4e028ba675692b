"""Ground segmentation, clustering, detections and Poisson clutter, on real open3d scans."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from sensors.boxfit import lshape_rectangle, min_area_rectangle
from sensors import (
    CLUSTER_METHODS,
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
    return Scan(points=s.points[perm], source=s.source[perm], origin=s.origin), perm


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
    with pytest.raises(ValueError, match="bbox_center, centroid, lshape_center"):
        PerceptionConfig(representative="median")


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


# --- perception -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", sorted(CLUSTER_METHODS))
def test_two_separated_boxes_give_two_detections_whatever_the_point_order(method):
    boxes = np.array([car(10.0, 4.0, 0.1), car(12.0, -4.5, -0.1)])
    s = scan(LidarConfig(), np.zeros(3), boxes, np.array([3, 8]), np.random.default_rng(2))
    cfg = PerceptionConfig(cluster=ClusterConfig(method=method), representative="lshape_center")
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
    cfg = PerceptionConfig(representative=representative)
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
    det = perceive(s, PerceptionConfig(representative="lshape_center")).detections
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
    res = perceive(traffic, PerceptionConfig(representative="centroid", complete_one_face=False))
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
    det = perceive(s, PerceptionConfig()).detections
    assert det.provenance.tolist() == [5]  # the car stays, the tree is rejected by its median height
    # a far tree whose crown top is missed by the rings looks no taller than a truck: then only the
    # median height tells it from a vehicle
    det_loose = perceive(s, PerceptionConfig(max_median_height_m=10.0, max_object_height_m=10.0)).detections
    assert (det_loose.provenance == -1).sum() == 1


@pytest.mark.parametrize("x", [25.0, 30.0, -25.0])  # nearer, one ring also lands on the roof: a split
def test_one_face_completion_moves_a_rear_view_to_the_car_centre(x):
    # a car straight ahead (or behind) in the sensor's lane shows only its rear (front) face
    boxes = np.array([car(x, 0.0)])
    s = scan(EXACT, np.zeros(3), boxes, np.array([7]), np.random.default_rng(0))
    raw = perceive(s, PerceptionConfig(complete_one_face=False)).detections
    done = perceive(s, PerceptionConfig()).detections
    assert len(raw) == len(done) == 1
    assert abs(abs(raw.z[0, 0]) - (abs(x) - 2.25)) < 0.1  # the visible face, half a car short
    assert abs(done.z[0, 0] - x) < 0.2  # completed with the 4.6 m prior: within 0.2 m of the 4.5 m car's centre
    assert abs(done.z[0, 1]) < 0.1
