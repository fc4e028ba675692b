"""The compiled loops of the occlusion-aware P_D (sensors/occlusion_jit.py) give what the numpy code they replaced
gave, bit for bit: the footprint's slab test and the ray-by-ray counts, on random boxes (parallel rays, a sensor
inside the footprint, per-target sizes) and, end to end, `visibility` against the numpy path on real scans."""
from __future__ import annotations

import numpy as np
import pytest

from roadtrack.sensors import GROUND, LidarConfig, OcclusionConfig, Scan, occlusion, occlusion_jit, scan


def _slabs_numpy(ox, oy, cb, sb, ux, uy, hl, hw, valid):
    """The numpy code footprint_slabs replaced (occlusion._footprint_columns before issue 33)."""
    rx = cb[:, None] * ux + sb[:, None] * uy
    ry = -sb[:, None] * ux + cb[:, None] * uy
    with np.errstate(divide="ignore", invalid="ignore"):
        t_in, t_out = occlusion._slab(ox[:, None], rx, hl[:, None])
        ty_in, ty_out = occlusion._slab(oy[:, None], ry, hw[:, None])
    end = t_in >= ty_in
    t_in, t_out = np.maximum(t_in, ty_in), np.minimum(t_out, ty_out)
    return t_in, t_out, valid & (t_out >= t_in) & (t_in > 0.0), end


def _counts_numpy(col, t_in, t_out, crosses, end, tz_b, hi_t, lo_t, cos_e, tan_e, ranges, beams, margin, h):
    """The numpy code ray_counts replaced (occlusion.visibility before issue 33); tz_b, hi_t (1 or K, b)."""
    tz_b, hi_t = tz_b[:, None, :], hi_t[:, None, :]
    t_hit = np.maximum(t_in[..., None], tz_b)
    expected = t_hit <= np.minimum(t_out[..., None], hi_t)
    expected &= t_hit >= lo_t
    expected &= crosses[..., None]
    r = ranges[:, beams][np.mod(col, ranges.shape[0])]
    clear = r * cos_e + margin >= t_hit
    clear &= expected
    clear_col = clear.any(axis=2)
    z_hit = h + t_hit * tan_e
    return (expected.sum(axis=(1, 2)), clear.sum(axis=(1, 2)), expected.any(axis=2).sum(axis=1),
            clear_col.sum(axis=1), (clear_col & end).sum(axis=1),
            np.where(clear, z_hit, 0.0).max(axis=(1, 2), initial=0.0))


def _columns_numpy(rel, los, yaw, az0, step, max_columns):
    """The numpy code footprint_columns replaced (occlusion._footprint_columns before issue 33)."""
    lo, hi = np.maximum(rel.min(axis=1), -np.pi / 2), np.minimum(rel.max(axis=1), np.pi / 2)
    centre_col = (los - yaw - az0) / step
    first = np.ceil(centre_col + lo / step)
    last = np.floor(centre_col + hi / step)
    narrow = last < first
    first[narrow] = last[narrow] = np.round(centre_col[narrow])
    n_window = (last - first + 1).astype(np.int64)
    n_cols = min(int(n_window.max()), max_columns)
    m = np.minimum(n_window, n_cols)
    j = np.arange(n_cols)
    valid_col = j[None, :] < m[:, None]
    offset = np.floor((j[None, :] + 0.5) * (n_window / m)[:, None]).astype(np.int64)
    return first.astype(np.int64)[:, None] + np.where(valid_col, offset, 0), n_window / m, valid_col


@pytest.mark.parametrize("seed", range(5))
def test_footprint_columns_match_the_numpy_windows(seed):
    rng = np.random.default_rng(seed)
    K = 11
    step = 2 * np.pi / 2250
    centre = rng.uniform(-np.pi, np.pi, K)
    half = rng.uniform(0.0, 0.3, K)
    half[:3] = rng.uniform(0.0, 0.5 * step, 3)  # narrower than a column
    rel = np.stack([-half, half, -0.5 * half, 0.7 * half], axis=1) + rng.normal(0.0, 1e-3, (K, 4))
    rel[3] = [-2.0, 2.0, 0.1, -0.1]  # the sensor inside the box: clipped to +-pi/2
    centre[4] = 0.5 * step  # the window's centre half-way between two columns
    for max_columns in (1, 8, 32, 1000):
        got = occlusion_jit.footprint_columns(rel, centre, 0.3, -np.pi, step, max_columns)
        want = _columns_numpy(rel, centre, 0.3, -np.pi, step, max_columns)
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)
            assert g.dtype == w.dtype


def _beam_window_numpy(elevations, h, height, cfg, t_in, t_out, crosses):
    """The numpy code beam_window and beam_bounds replaced (occlusion._beam_window before issue 33)."""
    tan_e = np.tan(elevations)
    base = (np.full_like(tan_e, h - height / 2) if np.ndim(height) == 0
            else np.broadcast_to(h - height / 2, (len(height), len(tan_e))))
    with np.errstate(divide="ignore", invalid="ignore"):
        tz_in, tz_out = occlusion._slab(base, tan_e, height / 2)
    t_reach = np.where(crosses, t_out, -np.inf).max(initial=-np.inf)
    t_near = np.where(crosses, t_in, np.inf).min(initial=np.inf)
    slack = t_reach * np.tan(np.deg2rad(cfg.attitude_tol_deg)) if np.isfinite(t_reach) else 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        band_in, band_out = occlusion._slab(base, tan_e, height / 2 + slack)
    useful = (band_in <= band_out) & (band_in <= t_reach) & (band_out >= t_near)
    useful = np.flatnonzero(useful if useful.ndim == 1 else useful.any(axis=0))
    if len(useful) == 0:
        return None
    beams = slice(useful[0], useful[-1] + 1)
    tan_b, cos_e = tan_e[beams], np.cos(elevations[beams])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_lo = (cfg.min_hit_height_m - h) / tan_b
    level = np.inf if h >= cfg.min_hit_height_m else -np.inf
    tl_in = np.where(tan_b > 0, t_lo, np.where(tan_b < 0, -np.inf, -level))
    tl_out = np.where(tan_b < 0, t_lo, np.where(tan_b > 0, np.inf, level))
    lo_t = np.maximum(tl_in, cfg.min_range_m * cos_e)
    hi_t = np.minimum(np.minimum(tz_out[..., beams], tl_out), cfg.max_range_m * cos_e)
    return beams, tz_in, cos_e, lo_t, hi_t


@pytest.mark.parametrize("per_target", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_beam_window_matches_the_numpy_beam_window(seed, per_target):
    rng = np.random.default_rng(seed)
    K, C = 6, 9
    elevations = np.deg2rad(np.linspace(-30.67, 10.67, 32))
    if not per_target:  # a level beam (the numpy code broadcast it wrongly against per-target heights)
        elevations[20] = 0.0
    h = [1.9, 0.2, 1.5, 1.9, 3.0, 1.9][seed]  # 0.2: the sensor below min_hit_height_m
    tol = [0.0, 0.0, 1.5, 0.0, 0.4, 0.0][seed]
    cfg = OcclusionConfig(attitude_tol_deg=tol)
    height = rng.uniform(1.2, 4.0, (K, 1)) if per_target else float(rng.uniform(1.2, 4.0))
    t_in = rng.uniform(1.0, 60.0, (K, C))
    t_out = t_in + rng.uniform(0.0, 5.0, (K, C))
    crosses = rng.random((K, C)) < (0.0 if seed == 5 else 0.7)  # seed 5: no column crosses (no beam)
    got = occlusion._beam_window(elevations, h, height, cfg, t_in, t_out, crosses)
    want = _beam_window_numpy(elevations, h, height, cfg, t_in, t_out, crosses)
    if want is None:
        assert got is None
        return
    assert got[0] == want[0]
    for g, w in zip(got[1:], want[1:]):
        assert g.shape == w.shape
        np.testing.assert_array_equal(g, w)


@pytest.mark.parametrize("seed", range(5))
def test_footprint_slabs_match_the_numpy_slab_test(seed):
    rng = np.random.default_rng(seed)
    K, C = 9, 17
    d = rng.uniform(0.5, 60.0, K)
    beta = rng.uniform(-np.pi, np.pi, K)
    cb, sb = np.cos(beta), np.sin(beta)
    ox, oy = -d * cb, d * sb
    phi = rng.uniform(-0.3, 0.3, (K, C))
    ux, uy = np.cos(phi), np.sin(phi)
    ux[0, :3], uy[1, :3] = 0.0, 0.0  # rays parallel to a slab
    beta[2] = 0.0
    hl, hw = rng.uniform(1.0, 8.0, K), rng.uniform(0.8, 1.3, K)
    ox[3], oy[3] = 0.2, -0.1  # the sensor inside a footprint
    valid = rng.random((K, C)) < 0.8
    got = occlusion_jit.footprint_slabs(ox, oy, cb, sb, ux, uy, hl, hw, valid)
    want = _slabs_numpy(ox, oy, cb, sb, ux, uy, hl, hw, valid)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)
    assert got[2].any() and not got[2].all()


@pytest.mark.parametrize("per_target", [False, True])
@pytest.mark.parametrize("seed", range(4))
def test_ray_counts_match_the_numpy_counts(seed, per_target):
    rng = np.random.default_rng(seed)
    K, C, A, B, b, beam0 = 7, 12, 400, 32, 11, 9
    ranges = rng.uniform(2.0, 60.0, (A, B))
    ranges[rng.random((A, B)) < 0.2] = np.inf  # no return
    col = rng.integers(-30, A + 30, (K, C))
    t_in = rng.uniform(0.0, 40.0, (K, C))
    t_out = t_in + rng.uniform(-1.0, 5.0, (K, C))
    crosses = rng.random((K, C)) < 0.85
    end = rng.random((K, C)) < 0.5
    rows = K if per_target else 1
    tz = rng.uniform(0.0, 45.0, (rows, b))
    hi = rng.uniform(5.0, 70.0, (rows, b))
    lo_t = rng.uniform(0.0, 10.0, b)
    cos_e, tan_e = np.cos(np.linspace(-0.5, 0.1, b)), np.tan(np.linspace(-0.5, 0.1, b))
    got = occlusion_jit.ray_counts(col, t_in, t_out, crosses, end, tz, hi, lo_t, cos_e, tan_e, ranges, beam0, 2.0, 1.9)
    want = _counts_numpy(col, t_in, t_out, crosses, end, tz, hi, lo_t, cos_e, tan_e, ranges,
                         slice(beam0, beam0 + b), 2.0, 1.9)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)
    assert got[1].sum() > 0 and (got[1] < got[0]).any()


def test_visibility_is_the_numpy_paths_on_a_real_scan(monkeypatch):
    """visibility with the kernels against the numpy code (the kernels swapped for the reference functions above)."""
    rng = np.random.default_rng(7)
    boxes = np.array([[x, y, 4.5, 1.8, 1.5, yaw, 0.0] for x, y, yaw in
                      [(12.0, 0.0, 0.0), (25.0, 3.5, 0.1), (-18.0, -3.5, 0.0), (40.0, 0.2, 0.05), (8.0, -3.4, 3.1)]])
    sc = scan(LidarConfig(), np.zeros(3), boxes, np.arange(len(boxes)), rng)
    xy = np.concatenate([boxes[:, :2] + rng.normal(0.0, 0.5, (5, 2)), rng.uniform(-60.0, 60.0, (20, 2))])
    heading = rng.uniform(-np.pi, np.pi, len(xy))
    size = np.where((rng.random(len(xy)) < 0.3)[:, None], [12.0, 2.5, 3.5], [4.6, 1.8, 1.5])
    cfg = OcclusionConfig()
    fast = [occlusion.visibility(sc, xy, cfg, heading=heading), occlusion.visibility(sc, xy, cfg, size_m=size)]
    monkeypatch.setattr(occlusion_jit, "footprint_slabs", _slabs_numpy)
    monkeypatch.setattr(occlusion_jit, "footprint_columns", _columns_numpy)
    monkeypatch.setattr(occlusion, "_beam_window", _beam_window_numpy)
    monkeypatch.setattr(occlusion_jit, "ray_counts",
                        lambda col, *a: _counts_numpy(col, *a[:10], slice(a[10], a[10] + len(a[6])), *a[11:]))
    slow = [occlusion.visibility(sc, xy, cfg, heading=heading), occlusion.visibility(sc, xy, cfg, size_m=size)]
    for f, s in zip(fast, slow):
        for g, w in zip(f, s):
            np.testing.assert_array_equal(g, w)
    assert fast[0].clear_rays.sum() > 0


def _quantised_numpy(sc, drop, step):
    """The numpy code quantised_ranges replaced (testbed/sensing/lidar.pd_scan before issue 30)."""
    ranges = sc.ranges / step
    ranges.reshape(-1)[sc.ray[drop & (sc.ray >= 0)]] = np.inf
    np.rint(ranges, out=ranges)
    return ranges * step


@pytest.mark.parametrize("seed", range(3))
def test_quantised_ranges_match_numpy_on_a_real_scan_and_on_ties(seed):
    """The P_D's range image, compiled, is numpy's: on a real scan (ground returns dropped, misses inf) and on an
    image of exact halves (rint rounds half to even) with a hand-made ray index."""
    rng = np.random.default_rng(seed)
    boxes = np.array([[12.0, 0.0, 4.5, 1.8, 1.5, 0.0, 0.0], [25.0, 3.5, 4.5, 1.8, 1.5, 0.1, 0.0]])
    sc = scan(LidarConfig(), np.zeros(3), boxes, np.arange(2), rng)
    drop = sc.source == GROUND if seed == 0 else rng.random(len(sc.points)) < 0.5
    got = occlusion.quantised_ranges(sc, drop, 0.002)
    np.testing.assert_array_equal(got, _quantised_numpy(sc, drop, 0.002))
    assert np.isinf(got).any() and np.isfinite(got).any()
    ties = (np.arange(40, dtype=np.float64).reshape(8, 5) + 0.5) * 0.25  # k + 1/2 steps of 0.25 m exactly
    tied = Scan(points=np.zeros((3, 3)), source=np.zeros(3, np.int64), origin=np.zeros(3), ranges=ties,
                ray=np.array([-1, 7, 39]), azimuths=np.arange(8.0) * 0.1, elevations=np.zeros(5))
    mask = np.array([True, True, False])
    got = occlusion.quantised_ranges(tied, mask, 0.25)
    np.testing.assert_array_equal(got, _quantised_numpy(tied, mask, 0.25))
    assert np.isinf(got.reshape(-1)[7]) and got.reshape(-1)[39] == 10.0 and got[0, 0] == 0.0  # 39.5 -> 40, 0.5 -> 0


def test_quantised_ranges_reject_a_bad_mask_or_step():
    sc = Scan(points=np.zeros((2, 3)), source=np.zeros(2, np.int64), origin=np.zeros(3), ranges=np.ones((2, 2)),
              ray=np.array([0, 3]), azimuths=np.zeros(2), elevations=np.zeros(2))
    with pytest.raises(ValueError, match="drop: expected a \\(2,\\) bool mask"):
        occlusion.quantised_ranges(sc, np.ones(3, bool), 0.002)
    with pytest.raises(ValueError, match="step_m"):
        occlusion.quantised_ranges(sc, np.ones(2, bool), 0.0)
    no_image = Scan(points=np.zeros((2, 3)), source=np.zeros(2, np.int64), origin=np.zeros(3), ray=np.array([0, 5]))
    assert occlusion.quantised_ranges(no_image, np.ones(2, bool), 0.002).shape == (0, 0)  # rays but no image


def test_one_footprint_signature_for_shared_and_per_target_sizes():
    """The footprint kernel gets writable (K,) half sizes whether the size is one float tuple (broadcast; a read-only
    view when K = 1) or per target: one compiled signature, so a run with trucks compiles nothing after the warm-up."""
    rng = np.random.default_rng(2)
    boxes = np.array([[12.0, 0.0, 4.5, 1.8, 1.5, 0.0, 0.0], [30.0, 3.5, 12.0, 2.5, 3.5, 0.0, 0.0]])
    sc = scan(LidarConfig(), np.zeros(3), boxes, np.arange(2), rng)
    seen = []
    real = occlusion_jit.footprint_slabs

    def spy(*args):
        seen.append(tuple((a.dtype, a.ndim, a.flags.c_contiguous, a.flags.writeable) for a in args))
        return real(*args)

    cfg = OcclusionConfig()
    import unittest.mock as mock
    with mock.patch.object(occlusion_jit, "footprint_slabs", spy):
        occlusion.visibility(sc, boxes[:1, :2], cfg)  # K = 1, one shared size
        occlusion.visibility(sc, boxes[:, :2], cfg)  # K = 2, one shared size
        occlusion.visibility(sc, boxes[:, :2], cfg, size_m=np.array([[4.6, 1.8, 1.5], [12.0, 2.5, 3.5]]))
    assert len(seen) == 3 and len(set(seen)) == 1 and all(w for *_, w in seen[0])
