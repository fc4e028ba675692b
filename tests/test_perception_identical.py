"""The compiled per-object steps of sensors/perception.py give the bits of their pure-numpy references
(sensors/perception_reference.py), on ray-cast highway scans and on hand-made edge cases: objects of 1-3
points, collinear and repeated points, a single object, distances and rectangle sides exactly at their bounds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import roadtrack.sensors.perception as perception
from roadtrack.sensors import PerceptionConfig, cluster, perception_jit, perception_reference, segment_ground

CFG = PerceptionConfig()
WIDE = dataclasses.replace(CFG, max_length_m=12.0, max_width_m=5.0)  # more unions pass: both branches run


@pytest.fixture(scope="module")
def shipped():
    """(scene name, scan, perception config, road) of every other frame of the first second of every shipped
    scenario."""
    from roadtrack.testbed.scenario.spec import list_scenarios, load_scenario
    from roadtrack.testbed.sensing.frames import rng_streams, scan_frame, sensing_setup

    out = []
    for name in list_scenarios():
        scn = load_scenario(name, {"duration_s": 1.0})
        rngs = rng_streams(scn.seed)
        sim, static, road = sensing_setup(scn, rngs)
        for i, truth in enumerate(sim.frames()):
            s = scan_frame(truth, static, scn.sensor.lidar, rngs["lidar"])
            if i % 2 == 0:
                out.append((name, s, scn.sensor.perception, road))
    return out


def kernel_calls(monkeypatch, frames, name: str) -> list[tuple]:
    """The arguments of every call perceive makes to perception_jit.<name> on `frames` ((name, scan, cfg, road))."""
    calls, kernel = [], getattr(perception_jit, name)
    monkeypatch.setattr(perception_jit, name, lambda *a: calls.append(a) or kernel(*a))
    for _, scan, cfg, road in frames:
        perception.perceive(scan, cfg, road)
    monkeypatch.undo()
    return calls


@pytest.fixture(scope="module")
def highway():
    """(points (N, 3), objects, _stats, road) of the first 1.5 s of highway_benchmark, every frame: the clusters
    before split and merge, as perceive sees them."""
    from roadtrack.testbed.scenario.spec import load_scenario
    from roadtrack.testbed.sensing.frames import rng_streams, scan_frame, sensing_setup

    scn = load_scenario("highway_benchmark", {"duration_s": 1.5})
    rngs = rng_streams(scn.seed)
    sim, static, road = sensing_setup(scn, rngs)
    cfg = scn.sensor.perception
    out = []
    for truth in sim.frames():
        s = scan_frame(truth, static, scn.sensor.lidar, rngs["lidar"])
        pts = s.points
        is_ground = segment_ground(pts, cfg.ground, s.origin)
        cand = np.flatnonzero(~is_ground & (pts[:, 2] - cfg.ground.ground_z_m <= cfg.max_height_m))
        objects = perception._raw_objects(pts, cand, cluster(pts[cand], cfg.cluster))
        out.append((pts, objects, perception._stats(pts, objects, cfg.ground.ground_z_m, s.origin[:2], road), road))
    return out


def same_arrays(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return len(a) == len(b) and all(x.dtype == y.dtype and np.array_equal(x, y) for x, y in zip(a, b))


def synthetic(objects_xyz: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray], object]:
    """Points (N, 3), objects (canonical order) and their _stats (no road) of hand-made objects."""
    pts = np.concatenate(objects_xyz)
    ends = np.cumsum([len(o) for o in objects_xyz])
    objects = [perception._canonical(pts, np.arange(e - len(o), e)) for o, e in zip(objects_xyz, ends)]
    return pts, objects, perception._stats(pts, objects, 0.0, np.zeros(2), None)


def line(x0, x1, y, n, z=1.0):
    return np.column_stack([np.linspace(x0, x1, n), np.full(n, y), np.full(n, z)])


def box(x0, x1, y0, y1, n, z=1.0, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(x0, x1, n), rng.uniform(y0, y1, n), np.full(n, z)])


EDGE_OBJECTS = [
    np.array([[3.0, 1.0, 1.0]]),  # one point
    np.array([[3.0, 1.0, 1.0], [3.2, 1.1, 1.5]]),  # two
    np.array([[3.0, 1.0, 1.0], [3.2, 1.1, 1.5], [3.1, 1.4, 0.5]]),  # three
    line(0.0, 12.0, 2.0, 40),  # collinear, long
    np.repeat([[5.0, 5.0, 1.2]], 12, axis=0),  # one point repeated
    np.vstack([line(0.0, 4.0, 0.0, 30), line(5.3, 9.5, 0.0, 30)]),  # collinear with a 1.3 m gap
    np.vstack([box(0.0, 4.5, 0.0, 1.8, 200), box(4.8, 9.3, 0.0, 1.8, 200, seed=1)]),  # two cars nose to tail
    np.vstack([box(0.0, 4.5, 0.0, 1.8, 200), box(0.0, 4.5, 2.1, 3.9, 200, seed=1)]),  # side by side
    np.vstack([line(0.0, 3.0, 0.0, 20), line(4.2, 7.2, 0.0, 20)]),  # gap of exactly split_gap_m
]


# --- split ----------------------------------------------------------------------------------------------

def test_split_object_equals_the_reference_on_highway_scans(highway):
    n_split = 0
    for pts, objects, st, _ in highway:
        for k, obj in enumerate(objects):
            ref = perception_reference.split_reference(pts, obj, st.axis[k], CFG)
            assert same_arrays(perception.split_object(obj, pts[obj, :2], pts[obj, 2], st.axis[k], CFG), ref)
            n_split += len(ref) > 1
    assert n_split >= 10  # the scans do hold objects that are cut


def test_widest_gaps_equal_the_reference(highway, monkeypatch):
    frames = [st for _, _, st, _ in highway] + [synthetic(EDGE_OBJECTS)[2]]
    for st in frames:
        gaps, clear = perception_jit.widest_gaps(st.u, st.starts, st.n, float(st.u.min()), float(np.ptp(st.u) + 1.0),
                                                 np.arange(len(st.n)))
        assert clear
        ref = perception_reference.widest_gaps_reference(st.u, st.starts, st.n)
        assert np.array_equal(gaps.view(np.int64), ref.view(np.int64))
        assert np.array_equal(perception._widest_gaps(st).view(np.int64), ref.view(np.int64))
    assert sum(int(np.sum(perception_reference.widest_gaps_reference(st.u, st.starts, st.n) > 0.3)) for st in frames) > 10
    # distinct u that one key cannot tell apart (an object far along the key): the reference decides
    u = np.array([0.0, 1e6, 5.0, 5.0 + 1e-11, 7.0])
    starts, n = np.array([0, 1]), np.array([1, 4])
    assert not perception_jit.widest_gaps(u, starts, n, 0.0, float(np.ptp(u) + 1.0), np.arange(2))[1]
    st = type(frames[0])(**{**frames[0].__dict__, "u": u, "starts": starts, "n": n})
    assert np.array_equal(perception._widest_gaps(st), perception_reference.widest_gaps_reference(u, starts, n))


def test_split_object_equals_the_reference_on_edge_cases():
    pts, objects, _ = synthetic(EDGE_OBJECTS)
    cut = 0
    for axis in np.array([0.0, 0.3, np.pi / 2, -2.0]):
        for cfg in (CFG, dataclasses.replace(CFG, cluster=dataclasses.replace(CFG.cluster, min_points=1),
                                             min_extent_m=0.0, max_splits=8)):
            for obj in objects:
                ref = perception_reference.split_reference(pts, obj, axis, cfg)
                assert same_arrays(perception.split_object(obj, pts[obj, :2], pts[obj, 2], axis, cfg), ref)
                cut += len(ref) > 1
    assert cut >= 8


# --- stage timer -------------------------------------------------------------------------------------------

def test_the_timer_sees_the_stages_in_order_and_changes_nothing(shipped):
    full = 0
    for _, scan, cfg, road in shipped[::3]:
        stages = []
        timed = perception.perceive(scan, cfg, road, timer=stages.append)
        plain = perception.perceive(scan, cfg, road)
        assert stages == [s for s in perception.PERCEIVE_STAGES if s in stages]  # in order, each once
        assert stages[:2] == ["ground", "clustering"]
        full += stages == list(perception.PERCEIVE_STAGES)
        for a, b in ((timed.detections, plain.detections), (timed.rejected, plain.rejected)):
            for f in dataclasses.fields(a):
                assert np.array_equal(getattr(a, f.name), getattr(b, f.name)), f.name
        assert np.array_equal(timed.labels, plain.labels)
    assert full >= 3


def results_equal(a, b) -> bool:
    """Whether two PerceptionResults hold the same bits."""
    pairs = [(getattr(x, f.name), getattr(y, f.name)) for x, y in ((a.detections, b.detections), (a.rejected, b.rejected))
             for f in dataclasses.fields(x)]
    pairs += [(a.labels, b.labels), (a.is_ground, b.is_ground), (a.cluster_labels, b.cluster_labels)]
    return all(u.dtype == v.dtype and u.shape == v.shape and u.tobytes() == v.tobytes() for u, v in pairs)


@pytest.mark.parametrize("variant", [{}, {"shape_filter": False}, {"vehicle_like": False}, {"max_length_m": 4.0}])
def test_apply_fits_equals_the_former_loop(monkeypatch, shipped, variant):
    from roadtrack.sensors import COMPLETED

    assert COMPLETED == 4  # the reference's literal
    n_fits = 0
    for _, scan, cfg, road in shipped[::2]:
        cfg = dataclasses.replace(cfg, **variant)
        got = perception.perceive(scan, cfg, road)
        calls = []
        monkeypatch.setattr(perception, "_apply_fits",
                            lambda fits, *a: calls.append(len(fits)) or perception_reference.apply_fits_reference(fits, *a))
        ref = perception.perceive(scan, cfg, road)
        monkeypatch.undo()
        assert results_equal(got, ref)
        n_fits += sum(calls)
    assert n_fits > 100


def test_prior_indices_follow_prior():
    from roadtrack.sensors.boxfit import CAR, TRUCK, BoxFitConfig, SizePrior

    van = SizePrior("van", 1.9, 5.5, 2.0, 0.5, 0.2)
    tops = np.r_[np.linspace(-1.0, 5.0, 601), 0.0, -0.0, 1.9, 2.5, np.nextafter(2.5, 0.0), np.inf, -np.inf]
    for priors in ((CAR, TRUCK), (TRUCK, CAR), (CAR, van, TRUCK), (van, TRUCK, CAR), (CAR,), (van,)):
        cfg = BoxFitConfig(priors=priors)
        got = cfg.prior_indices(tops)
        assert got.dtype == np.int64 and [priors[j] for j in got] == [cfg.prior(float(t)) for t in tops]


# --- scan-line links -------------------------------------------------------------------------------------

def test_link_unions_equal_the_reference_on_every_shipped_scenario(monkeypatch, shipped):
    calls = kernel_calls(monkeypatch, shipped, "link_unions")
    joined = 0
    for args in calls:
        got = perception_jit.link_unions(*args)
        ref = perception_reference.link_unions_reference(*args)
        assert got.dtype == ref.dtype and np.array_equal(got, ref)
        joined += int(np.sum(ref != np.arange(len(ref))))
    assert len(calls) >= 20 and joined >= 100  # links did join noise to clusters


# --- ground ------------------------------------------------------------------------------------------------

def bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a).view(np.int64)


def test_ground_columns_and_band_equal_numpy_on_every_shipped_scenario(monkeypatch, shipped):
    columns = kernel_calls(monkeypatch, shipped, "relative_columns")
    bands = kernel_calls(monkeypatch, shipped, "near_plane")
    assert len(columns) == len(shipped) and len(bands) == 4 * len(shipped)  # 3 coarse rounds on the cells, 1 fine
    for pts, cx, cy, cz in columns:
        x, y, z, bounds = perception_jit.relative_columns(pts, cx, cy, cz)
        for got, ref in ((x, pts[:, 0] - cx), (y, pts[:, 1] - cy), (z, pts[:, 2] - cz),
                         (bounds, np.array([pts[:, 0].min(), pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max()]))):
            assert np.array_equal(bits(got), bits(ref))
    kept = 0
    for x, y, z, a, b, c, band in bands:
        near = np.abs(z - a * x - b * y - c) <= band
        got = perception_jit.near_plane(x, y, z, a, b, c, band)
        for g, ref in zip(got, (x[near], y[near], z[near])):
            assert np.array_equal(bits(g), bits(ref))
        kept += int(near.sum())
        # at a band between two points' residuals the kernel decides as numpy does
        res = np.sort(np.abs(z - a * x - b * y - c))[len(z) // 2 : len(z) // 2 + 2]
        for edge in (res[0], np.nextafter(res[0], -np.inf), res.mean()):
            assert len(perception_jit.near_plane(x, y, z, a, b, c, edge)[0]) == int(
                np.sum(np.abs(z - a * x - b * y - c) <= edge))
    assert kept > 10000


def test_cell_lowest_equals_numpy_on_every_shipped_scenario(monkeypatch, shipped):
    calls = kernel_calls(monkeypatch, shipped, "cell_lowest")
    assert len(calls) == len(shipped)
    rng = np.random.default_rng(4)
    pts = rng.uniform(-3, 3, (500, 3))
    pts[::7, :2] = np.floor(pts[::7, :2])  # points on cell edges
    cases = calls + [(pts, pts[:, 2] - 0.5, 2.0, -6.0, -6.0, 13, 13 * 13, 0.5, 0.25, -0.5)]
    for pts, z, inv, fx0, fy0, ny, size, cell, ox, oy in cases:
        lowest = np.full(size, np.inf)  # the former numpy code of ground._coarse_plane
        ix = np.floor(pts[:, 0] * inv).astype(np.int64) - int(fx0)
        np.minimum.at(lowest, ix * ny + np.floor(pts[:, 1] * inv).astype(np.int64) - int(fy0), z)
        occupied = np.flatnonzero(np.isfinite(lowest))
        ref = ((np.float64(fx0) + 0.5 + occupied // ny) * cell - np.float64(ox),
               (np.float64(fy0) + 0.5 + occupied % ny) * cell - np.float64(oy), lowest[occupied])
        got = perception_jit.cell_lowest(pts, z, inv, fx0, fy0, ny, size, cell, ox, oy)
        for g, r in zip(got, ref):
            assert np.array_equal(bits(g), bits(r))
        assert 0 < len(occupied) < size


def test_the_conditioning_shortcut_decides_as_numpys_cond(monkeypatch, shipped):
    import roadtrack.sensors.ground as ground

    normals, conds = [], []
    ill = ground._ill_conditioned
    monkeypatch.setattr(ground, "_ill_conditioned", lambda m: normals.append(m.copy()) or ill(m))
    for _, scan, cfg, _ in shipped:
        ground.segment_ground(scan.points, cfg.ground, scan.origin)
    monkeypatch.undo()
    rng = np.random.default_rng(5)

    def normal_of(x, y):
        return np.array([[np.dot(x, x), np.dot(x, y), x.sum()], [np.dot(x, y), np.dot(y, y), y.sum()],
                         [x.sum(), y.sum(), len(x)]])

    x = rng.uniform(-70, 70, 500)
    for scale in (1.0, 1e-3, 1e-5, 1e-6, 1e-7, 1e-9, 0.0):  # from a plane to a line: cond crosses 1e12
        normals.append(normal_of(x, 0.5 * x + 3.0 + scale * rng.normal(size=500)))
    normals += [normal_of(np.full(10, 3.0), np.full(10, -2.0)), np.zeros((3, 3)), -np.eye(3),
                np.diag([1e13, 1.0, 1.0]), np.diag([1e10, 1.0, 1.0]), np.diag([1e12 * 0.999, 1.0, 1.0])]
    shortcut = 0
    for m in normals:
        assert ground._ill_conditioned(m) == bool(np.linalg.cond(m) > 1e12)
        conds.append(np.linalg.cond(m))
        (a, b, c), (_, d, e), (_, _, f) = m.tolist()
        det = a * (d * f - e * e) - b * (b * f - c * e) + c * (b * e - c * d)
        shortcut += det > 0 and (a + d + f) ** 3 / (4 * det) < 1e10
    assert len(normals) > 4 * len(shipped) and shortcut >= 4 * len(shipped)  # the scans' fits take the shortcut
    assert min(conds) < 1e12 < max(conds)  # both answers are checked


def road_band_reference(x, y, z, a, b, c, with_range, road_tol, range_term, tan_angle, height_tol, foot_cell,
                        foot_lo, foot_hi, foot_keep):
    """sensors/ground._road_plane's former numpy labels (before perception_jit.road_band): the band tol, then
    the foot test by a sort of the above points' cells and a binary search."""
    res = z - a * x - b * y - c
    if with_range:
        r = np.sqrt(x * x + y * y + z * z)
        tol = road_tol + range_term / np.maximum(r, 1e-9)
        if tan_angle > 0.0:
            tol += r * tan_angle
        tol = np.minimum(tol, height_tol)
    else:
        tol = height_tol
    is_ground = res <= tol
    if foot_cell > 0.0:
        test = np.flatnonzero(is_ground & (res > foot_keep * tol))
        above = np.flatnonzero((res > tol + foot_lo) & (res <= tol + foot_hi))
        if len(test) and len(above):
            inv = 1.0 / foot_cell
            ax, ay = np.floor(x[above] * inv).astype(np.int64), np.floor(y[above] * inv).astype(np.int64)
            tx, ty = np.floor(x[test] * inv).astype(np.int64), np.floor(y[test] * inv).astype(np.int64)
            x0, y0 = min(ax.min(), tx.min()), min(ay.min(), ty.min())
            width = max(ay.max(), ty.max()) - y0 + 1
            keys = np.sort((ax - x0) * width + (ay - y0))
            query = (tx - x0) * width + (ty - y0)
            is_ground[test[keys[np.minimum(np.searchsorted(keys, query), len(keys) - 1)] == query]] = False
    return is_ground


def test_road_band_equals_the_former_numpy_labels(monkeypatch, shipped):
    calls = kernel_calls(monkeypatch, shipped, "road_band")
    assert len(calls) == len(shipped)
    rng = np.random.default_rng(11)
    feet = 0
    for args in calls:
        ref = road_band_reference(*args)
        assert np.array_equal(perception_jit.road_band(*args), ref)
        feet += int(np.sum(ref != road_band_reference(*args[:11], 0.0, *args[12:])))
    assert feet > 1000  # the foot test removed points
    # hand-made: a car-like block on a noisy road around the sensor, every option of the band, cells at +-0
    for n, cell in ((1, 0.04), (7, 0.04), (3000, 0.04), (3000, 0.5), (20000, 0.01), (3000, 0.0)):
        x, y = rng.uniform(-30, 30, n), rng.uniform(-30, 30, n)
        x[::9], y[::11] = 0.0, -0.0
        z = rng.normal(-1.8, 0.02, n) + np.where(np.abs(x - 5) < 2, rng.uniform(0, 1.5, n), 0.0)
        for with_range, tan_angle in ((True, 0.0), (True, 1e-3), (False, 0.0)):
            args = (x, y, z, 1e-3, -2e-3, -1.8, with_range, 0.005, 0.144, tan_angle, 0.2, cell, 0.05, 0.5, 0.25)
            assert np.array_equal(perception_jit.road_band(*args), road_band_reference(*args))


def test_foot_cells_is_a_set():
    rng = np.random.default_rng(3)
    for n in (0, 1, 5, 100, 5000):
        keys = rng.integers(-2**62, 2**62, n)
        keys[: n // 2] = rng.integers(-40, 40, n // 2)  # repeated keys, neighbours, negative ones
        if n:
            keys[0] = -2**63
        cells = perception_jit._foot_cells(n)
        for k in keys:
            perception_jit._foot_cells_add(cells, k)
        assert int(cells[1].sum()) == len(set(keys.tolist())) and len(cells[0]) >= 2 * n
        queries = np.concatenate([keys, rng.integers(-60, 60, 200), keys + 1])
        assert [perception_jit._foot_cells_has(cells, q) for q in queries] == [q in set(keys.tolist())
                                                                             for q in queries.tolist()]


# --- clustering --------------------------------------------------------------------------------------------

def tie_grid(rng, n: int) -> np.ndarray:
    """(n, 3) points on a coarse grid: many equal x, equal (x, y) and equal points; -0.0 beside 0.0."""
    grid = np.column_stack([rng.integers(0, 3, (n, 2)).astype(float), rng.integers(0, 2, n) * 0.5])
    grid[::7, 0] = -0.0  # -0.0 and 0.0 are equal x
    grid[::5, 1] = -0.0
    return grid


def label_cases(shipped):
    """(points (N, 3), labels (N,) with -1 noise) of every shipped frame's clustering (links included) and of
    hand-made ties."""
    from roadtrack.sensors.clustering import ORDER_FREE

    rng = np.random.default_rng(4)
    cases = []
    for _, scan, cfg, _ in shipped:
        pts = scan.points
        cand = pts[~segment_ground(pts, cfg.ground, scan.origin)]
        cases.append((cand, ORDER_FREE["grid"](cand, cfg.cluster)))
        cases.append((cand, rng.integers(-1, 60, len(cand))))
    for n in (1, 2, 7, 300):
        grid = tie_grid(rng, n)
        cases += [(grid, rng.integers(-1, 4, n)), (grid, np.zeros(n, np.int64)), (grid, np.full(n, -1))]
    return cases


def test_grid_components_are_ndimage_labels_partition(shipped):
    from roadtrack.sensors.clustering import ORDER_FREE, numbered

    rng = np.random.default_rng(5)
    cases = [(scan.points[~segment_ground(scan.points, cfg.ground, scan.origin)], cfg.cluster.cell_m)
             for _, scan, cfg, _ in shipped]
    ring = np.array([[np.cos(a) * 5.0, np.sin(a) * 5.0, 0.0] for a in np.linspace(0.0, 2 * np.pi, 200)])
    diagonal = np.array([[0.25 + k, 0.25 + k, 0.0] for k in range(5)] + [[0.25 + k, 4.25 - k, 1.0] for k in range(5)])
    cases += [(ring, 0.5), (diagonal, 1.0), (rng.uniform(0.0, 20.0, (3000, 3)), 0.5), (ring[:1], 0.5)]
    n_clusters = 0
    for pts, cell in cases:
        cfg = dataclasses.replace(CFG.cluster, cell_m=cell)
        got, ref = ORDER_FREE["grid"](pts, cfg), perception_reference.grid_labels_reference(pts, cell)
        pairs = np.unique(np.column_stack([got, ref]), axis=0)  # the same partition: a bijection of the labels
        assert got.dtype == np.int64 and len(pairs) == len(np.unique(got)) == len(np.unique(ref))
        assert np.array_equal(numbered(pts, got, 3), numbered(pts, ref, 3))
        n_clusters += len(pairs)
    assert n_clusters > 1000


def test_numbered_equals_the_reference(shipped):
    from roadtrack.sensors.clustering import numbered

    n_big = 0
    for pts, raw in label_cases(shipped):
        for min_points in (0, 1, 3, 5):
            got, ref = numbered(pts, raw, min_points), perception_reference.numbered_reference(pts, raw, min_points)
            assert got.dtype == ref.dtype and np.array_equal(got, ref)
        n_big += int(raw.max()) > 50
    assert n_big > 10


def test_scan_line_links_equal_the_reference_on_every_shipped_scenario(shipped):
    from roadtrack.sensors.clustering import scan_line_links

    n_links = 0
    for _, s, cfg, _ in shipped:
        is_ground = segment_ground(s.points, cfg.ground, s.origin)
        cand = np.flatnonzero(~is_ground & (s.points[:, 2] - cfg.ground.ground_z_m <= cfg.max_height_m))
        sub = cluster(s.points[cand], cfg.cluster)
        ray = s.ray[cand].copy()
        ray[::50] = -1  # some points of unknown ray
        args = (s.points[cand], ray, s.ranges.shape, s.origin, np.isfinite(s.ranges), cfg.cluster)
        for labels in (sub, None):
            got = scan_line_links(*args, labels=labels)
            ref = perception_reference.scan_line_links_reference(*args, labels=labels)
            assert got.dtype == ref.dtype and got.shape == ref.shape and np.array_equal(got, ref)
            n_links += len(ref)
    # the azimuth wraps round; a ray without a return is looked across; too few points give no link
    pts = np.array([[10.0, 0.0, 1.0], [10.0, 0.05, 1.0], [10.0, 0.1, 1.0], [10.0, 0.2, 1.0]])
    returned = np.ones((4, 1), bool)
    returned[2] = False
    for ray in (np.array([3, 0, 1, 3]), np.array([0, 1, 3, -1]), np.array([-1, -1, -1, 2])):
        for origin in (np.zeros(3), np.array([10.0, 0.0, 1.0])):  # a point at the origin itself
            got = scan_line_links(pts, ray, (4, 1), origin, returned, CFG.cluster)
            ref = perception_reference.scan_line_links_reference(pts, ray, (4, 1), origin, returned, CFG.cluster)
            assert np.array_equal(got, ref) and got.shape == ref.shape
    assert n_links > 1000


# --- canonical order -------------------------------------------------------------------------------------

def test_canonical_order_equals_the_reference(highway):
    rng = np.random.default_rng(2)
    cases = []
    for pts, objects, _, _ in highway[::3]:
        cases += [(pts, np.concatenate(objects[i:i + 3])) for i in range(0, len(objects), 3)]  # joined groups
        cases.append((pts, rng.permutation(np.concatenate(objects))))
    grid = np.column_stack([rng.integers(0, 3, (300, 2)).astype(float), rng.integers(0, 2, 300) * 0.5])
    grid[::7, 0] = -0.0  # -0.0 and 0.0 are equal x
    cases += [(grid, rng.permutation(300)), (grid, np.arange(300)[::-1]), (grid[:1], np.array([0])),
              (grid, np.zeros(0, np.int64))]
    for pts, idx in cases:
        got, ref = perception._canonical(pts, idx), perception_reference.canonical_reference(pts, idx)
        assert got.dtype == ref.dtype and np.array_equal(got, ref)
    assert len(cases) > 50


# --- merge ----------------------------------------------------------------------------------------------

def test_merge_equals_the_reference_on_highway_scans(highway):
    n_joined = 0
    for pts, objects, st, _ in highway:
        flags = list(range(len(objects)))  # distinct flags: their union is checked too
        got = perception._merge(pts, objects, flags, CFG, st)
        ref = perception_reference.merge_reference(pts, objects, flags, CFG, st, perception.MERGED)
        assert same_arrays(got[0], ref[0]) and got[1:] == ref[1:]
        n_joined += len(objects) - len(ref[0])
    assert n_joined >= 3


def test_pair_gaps_equal_the_kdtree_distances(highway):
    frames = [(pts, objects, st) for pts, objects, st, _ in highway[::3]]
    pts, objects, st = synthetic(EDGE_OBJECTS + [np.array([[20.0, 0.0, 1.0]]), np.array([[21.0, 0.0, 1.0]]),
                                                 np.array([[20.6, 10.8, 1.0]]), np.array([[21.2, 10.0, 1.0]])])
    shuffled = [o[::-1] for o in objects]  # not x-sorted: all pairs are measured
    frames += [(pts, objects, st), (pts, shuffled, perception._stats(pts, shuffled, 0.0, np.zeros(2), None))]
    found = 0
    for pts, objects, st in frames:
        pa, pb = np.triu_indices(len(objects), 1)
        for gap in (1.0, 3.0):
            got = perception_jit.pair_gaps(st.xy, st.starts, st.n, pa, pb, gap)
            ref = np.array([perception_reference.point_gap_reference(pts, objects[a], objects[b], gap)
                            for a, b in zip(pa, pb)])
            assert np.array_equal(got.view(np.int64), ref.view(np.int64))
            found += int(np.isfinite(got).sum())
    assert found > 100
    # points exactly 1 m apart are not within distance_upper_bound = 1 m (the k-d tree's strict bound)
    assert perception_reference.point_gap_reference(pts, objects[-4], objects[-3], 1.0) == np.inf


def _pairs_by_gap(st, k_all: int, gap: float) -> tuple[np.ndarray, np.ndarray]:
    pa, pb = np.triu_indices(k_all, 1)
    d = perception_jit.pair_gaps(st.xy, st.starts, st.n, pa, pb, gap)
    near = np.isfinite(d)
    order = np.lexsort((pb[near], pa[near], d[near]))
    return pa[near][order], pb[near][order]


def assert_unions_equal(pts, objects, st, pa, pb, cfg) -> int:
    roots, groups = perception.unite_fitting(pts, objects, st, pa, pb, cfg)
    ref_roots, ref_groups = perception_reference.unite_reference(pts, objects, list(zip(pa.tolist(), pb.tolist())),
                                                                 cfg)
    assert np.array_equal(roots, ref_roots)
    joined = {int(r) for r in np.unique(ref_roots) if np.sum(ref_roots == r) > 1}
    assert set(groups) == joined
    assert all(np.array_equal(groups[r], ref_groups[r]) for r in joined)
    return int(np.sum(roots != np.arange(len(objects))))  # objects joined to another


def test_unite_fitting_equals_the_reference_on_highway_scans(highway):
    n_joined = 0
    for pts, objects, st, _ in highway:
        pa, pb = _pairs_by_gap(st, len(objects), 3.0)
        for cfg in (CFG, WIDE):
            n_joined += assert_unions_equal(pts, objects, st, pa, pb, cfg)
    assert n_joined >= 20


def test_unite_fitting_runs_the_reference_test_at_a_bound(monkeypatch):
    calls = []
    reference = perception.union_fits_reference
    monkeypatch.setattr(perception, "union_fits_reference", lambda *a: calls.append(1) or reference(*a))
    # unions exactly 8 m long (max_length_m) and exactly 3.5 m wide (max_width_m), a right triangle (the rectangle
    # along its hypotenuse has the same area as the one along its legs), collinear fragments (flat)
    at_bound = [np.vstack([line(0.0, 3.0, 0.0, 10), line(0.0, 3.0, 1.0, 10)]),
                np.vstack([line(4.0, 8.0, 0.0, 10), line(4.0, 8.0, 1.0, 10)]),
                line(20.0, 25.0, 0.0, 5), line(20.0, 25.0, 3.5, 5)]
    triangle = [np.array([[40.0, 0.0, 1], [41.0, 0.0, 1], [42.0, 0.0, 1]]),
                np.array([[40.0, 1.0, 1], [40.0, 2.0, 1], [40.0, 3.0, 1]])]
    flat = [line(60.0, 62.0, 0.0, 8), line(62.5, 64.0, 0.0, 8)]
    pts, objects, st = synthetic(at_bound + triangle + flat + EDGE_OBJECTS[:3])
    k = len(objects)
    pa, pb = np.array([0, 2, 4, 6, 0, 8, 9]), np.array([1, 3, 5, 7, 8, 9, 10])
    assert assert_unions_equal(pts, objects, st, pa, pb, CFG) >= 4
    assert len(calls) >= 4  # both bounds, the triangle and the flat pair went to the reference
    pa, pb = np.triu_indices(k, 1)
    assert_unions_equal(pts, objects, st, pa, pb, CFG)
    assert_unions_equal(pts, objects, st, pa, pb, WIDE)


def test_box_gap_bound_is_a_lower_bound_of_the_points_distance():
    rng = np.random.default_rng(3)
    n_pairs, pruned = 2000, 0
    c = rng.uniform(-20, 20, (n_pairs, 2))
    heading = rng.uniform(-np.pi, np.pi, n_pairs)
    half = rng.uniform(0.2, 4.0, (n_pairs, 2))
    pts = [rng.uniform(-1.5, 1.5, (int(rng.integers(1, 30)), 2)) * rng.uniform(0.1, 3.0, 2) + rng.uniform(-25, 25, 2)
           for _ in range(n_pairs)]
    pts[:50] = [np.repeat(p[:1], 3, axis=0) for p in pts[:50]]  # a point box (lo = hi)
    lo, hi = np.array([p.min(axis=0) for p in pts]), np.array([p.max(axis=0) for p in pts])
    bound = perception._box_gap_bound(c, heading, half, lo, hi)
    for k, p in enumerate(pts):
        xy = p - c[k]
        ca, sa = np.cos(heading[k]), np.sin(heading[k])
        du = np.maximum(np.abs(xy @ np.array([ca, sa])) - half[k, 0], 0.0)
        dv = np.maximum(np.abs(xy @ np.array([-sa, ca])) - half[k, 1], 0.0)
        d = float(np.min(np.hypot(du, dv)))  # _merge_boxes' distance
        assert bound[k] <= d + 1e-9
        pruned += bound[k] > 1.0 + perception._BOUND_MARGIN_M
    assert 100 < pruned < n_pairs  # the bound removes pairs, not all


# --- selection and fit ----------------------------------------------------------------------------------

def test_batched_box_fits_equal_one_by_one_fits(highway):
    from roadtrack.sensors.boxfit import fit_vehicle_box_unchecked, fit_vehicle_boxes_unchecked

    n_fits = 0
    for pts, objects, st, _ in highway[::2]:
        keys = np.arange(len(objects))
        rng = np.random.default_rng(len(objects))
        ends = rng.random((len(keys), 2)) < 0.3  # some occluded ends
        z = st.z - CFG.ground.ground_z_m
        for hints in (st.axis, None):
            batch = fit_vehicle_boxes_unchecked(st.xy, z, st.starts, st.n, np.array([1.0, -2.0]), st.top, hints, ends,
                                                CFG.boxfit)
            for k, f in zip(keys, batch):
                one = fit_vehicle_box_unchecked(pts[objects[k], :2], np.array([1.0, -2.0]), top_m=float(st.top[k]),
                                                heading_hint=None if hints is None else float(hints[k]),
                                                open_ends=tuple(ends[k]), cfg=CFG.boxfit,
                                                z=pts[objects[k], 2] - CFG.ground.ground_z_m)
                for field in dataclasses.fields(one):
                    a, b = getattr(f, field.name), getattr(one, field.name)
                    assert type(a) is type(b) and np.array_equal(a, b), field.name
                n_fits += 1
    assert n_fits > 100


def test_open_ends_equal_the_reference(shipped):
    from roadtrack.testbed.scenario.spec import load_scenario
    from roadtrack.testbed.sensing.frames import rng_streams, scan_frame, sensing_setup

    scn = load_scenario("highway_benchmark", {"duration_s": 0.5})
    rngs = rng_streams(scn.seed)
    sim, static, road = sensing_setup(scn, rngs)
    frames = [(scan_frame(truth, static, scn.sensor.lidar, rngs["lidar"]), road) for truth in sim.frames()]
    frames += [(s, road) for _, s, _, road in shipped]  # and every shipped scenario
    n_open = 0
    for s, road in frames:
        is_ground = segment_ground(s.points, CFG.ground, s.origin)
        cand = np.flatnonzero(~is_ground & (s.points[:, 2] <= CFG.max_height_m))
        if len(cand) == 0:
            continue
        objects = perception._raw_objects(s.points, cand, cluster(s.points[cand], CFG.cluster))
        st = perception._stats(s.points, objects, 0.0, s.origin[:2], road)
        for keys in (np.arange(len(objects)), np.arange(len(objects))[::-3]):
            got = perception._open_ends(s, st, keys)
            assert got == perception_reference.open_ends_reference(s, st, keys)
            n_open += sum(map(sum, got))
    assert n_open > 10


def test_min_area_rectangle_with_the_compiled_hull_equals_qhull(highway):
    from roadtrack.sensors.boxfit import min_area_rectangle

    sets = [pts[o, :2] for pts, objects, _, _ in highway[::3] for o in objects]
    rng = np.random.default_rng(1)
    sets += [o[:, :2] for o in EDGE_OBJECTS[2:]] + [
        rng.normal(size=(50, 2)) * [3.0, 1.0] + [1e4, -3e3],  # far from the origin
        np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.5]]),  # a square, one point inside
        np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 1e-13], [1.0, 1.0]]),  # an almost collinear vertex
        np.repeat([[1.0, 2.0], [3.0, 2.5], [2.0, 4.0]], 3, axis=0),  # a triangle, each vertex thrice
    ]
    for xy in sets:
        got, ref = min_area_rectangle(xy), min_area_rectangle(xy, compiled_hull=False)
        assert np.array_equal(got[0], ref[0]) and got[1:] == ref[1:]


def test_restats_after_split_and_merge_equal_stats(highway):
    kept_some = 0
    for pts, objects, _, road in highway:
        st = perception._stats(pts, objects, 0.0, np.zeros(2), road)  # the old summaries, as restats is given them
        for step in (perception._split, perception._merge):
            out, _, changed = step(pts, objects, [0] * len(objects), CFG, st)
            if not changed:
                continue
            got = perception._restats(pts, out, objects, st, 0.0, np.zeros(2), road)
            ref = perception._stats(pts, out, 0.0, np.zeros(2), road)
            for f in dataclasses.fields(ref):
                a, b = getattr(got, f.name), getattr(ref, f.name)
                assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.uint8), b.view(np.uint8))
            kept_some += sum(any(o is p for p in objects) for o in out) > 0
    # all objects new, and none new (the same list)
    pts, objects, st = synthetic(EDGE_OBJECTS)
    for out in ([o.copy() for o in objects], list(objects[::-1])):
        got, ref = perception._restats(pts, out, objects, st, 0.0, np.zeros(2), None), perception._stats(
            pts, out, 0.0, np.zeros(2), None)
        assert all(np.array_equal(getattr(got, f.name), getattr(ref, f.name)) for f in dataclasses.fields(ref))
    assert kept_some >= 10


def along_reference(rel, cx, cy, starts, n):
    """u (each member's coordinate along its object's (cx, cy)) and each object's extent along it, in NumPy: the
    same products and sums, member by member, as axis_extents (no fused multiply-add on either side)."""
    u = np.full(len(rel), np.nan)
    out = np.empty(len(starts))
    for k, (s0, m) in enumerate(zip(starts, n)):
        w = rel[s0:s0 + m, 0] * cx[k] + rel[s0:s0 + m, 1] * cy[k]
        u[s0:s0 + m] = w
        out[k] = (w.max() - w.min()) if m else -np.inf
    return u, out


def test_axis_extents_equal_the_separate_extent_kernels(highway):
    rng = np.random.default_rng(6)
    _, _, edge = synthetic(EDGE_OBJECTS)
    for st in [st for _, _, st, _ in highway] + [edge]:
        k = len(st.n)
        cos_p, sin_p, cos_a, sin_a = (np.cos(st.principal), np.sin(st.principal), *np.split(
            rng.normal(size=(2, k)) / np.hypot(*rng.normal(size=(2, k))), 2))
        cos_a, sin_a = cos_a[0], sin_a[0]
        got = perception_jit.axis_extents(st.rel, cos_p, sin_p, cos_a, sin_a, st.starts, st.n)
        u, along = along_reference(st.rel, cos_a, sin_a, st.starts, st.n)
        ref = (perception_jit.extent(st.rel, -sin_p, cos_p, st.starts, st.n),
               perception_jit.extent(st.rel, cos_p, sin_p, st.starts, st.n), u, along,
               perception_jit.extent(st.rel, -sin_a, cos_a, st.starts, st.n))
        for g, r in zip(got, ref):
            assert np.array_equal(g.view(np.int64), r.view(np.int64))


def test_plurality_equals_the_reference(shipped):
    rng = np.random.default_rng(7)
    cases = [(s.source[np.flatnonzero(s.source != -2)], None) for _, s, _, _ in shipped[::2]]
    cases += [(np.array([3, 1, 3, 1, -1, -1, 7]), np.array([4, 3])),  # a 2-2 tie: the smaller label, 1
              (np.array([-1, -1, 5]), np.array([3])), (np.array([2]), np.array([1]))]
    n_vehicle = 0
    for source, n in cases:
        if n is None:  # the scan's points cut into objects of 1-40 points
            n = rng.integers(1, 40, len(source))
            n = n[np.cumsum(n) <= len(source)]
            source = source[: n.sum()]
        got = perception._plurality_vehicle(source, n)
        ref = perception_reference.plurality_reference(source, n)
        assert got.dtype == ref.dtype and np.array_equal(got, ref)
        n_vehicle += int(np.sum(ref >= 0))
    assert n_vehicle > 100


def test_nearest_range_of_the_object_sums_is_numpys_smallest_hypot(highway):
    for pts, objects, st, _ in highway[::4]:
        for k, o in enumerate(objects[:40]):
            ref = np.min(np.hypot(pts[o, 0] - 1.5, pts[o, 1] + 0.5))
            got = perception._stats(pts, [o], 0.0, np.array([1.5, -0.5]), None).d_min[0]
            assert got == ref


# --- the P_D's range image (testbed.sensing.pd_scan) -----------------------------------------------------------

def pd_ranges_reference(scan, is_ground: np.ndarray) -> np.ndarray:
    """testbed.sensing.pd_scan's former range image: ground rays inf, the rest rounded to PD_RANGE_STEP_M where
    finite (a mask of the finite entries)."""
    from roadtrack.testbed.sensing import PD_RANGE_STEP_M

    ranges = scan.ranges.copy()
    ranges.reshape(-1)[scan.ray[is_ground & (scan.ray >= 0)]] = np.inf
    finite = np.isfinite(ranges)
    ranges[finite] = np.rint(ranges[finite] / PD_RANGE_STEP_M) * PD_RANGE_STEP_M
    return ranges


def test_pd_scan_ranges_equal_the_reference(shipped):
    from roadtrack.testbed.sensing import pd_scan

    n_inf = 0
    for _, scan, cfg, _ in shipped:
        is_ground = segment_ground(scan.points, cfg.ground, scan.origin)
        got, ref = pd_scan(scan, is_ground).ranges, pd_ranges_reference(scan, is_ground)
        assert got.dtype == ref.dtype and got.shape == ref.shape and bits(got).tobytes() == bits(ref).tobytes()
        n_inf += int(np.isinf(got).sum())
    assert n_inf > 1000
