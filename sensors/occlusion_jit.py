"""Compiled (numba) loops of sensors/occlusion.py's `visibility`: each target's sampled azimuth columns, the
footprint's slab test per column, the beams that can reach a target and their bounds, and the ray-by-ray test per
(target, column, beam).

Each kernel computes what the numpy code of `visibility` computed, bit for bit: the same float64 divisions, products
and sums in the same order, `np.maximum` / `np.minimum` as numpy defines them (NaN propagates, the first argument
wins a tie), comparisons with NaN false, `np.rint` for numpy's round; trigonometry stays in numpy (the caller passes
the arctan2, cos, sin and tan arrays: numpy's transcendental functions round differently from the C library's in the
last bit). About 80 numpy calls on small (K, C) and (K, C, b) arrays per call of `visibility` become five calls
(tests/test_occlusion_jit.py compares each kernel with the numpy code it replaced, and `visibility` with the numpy
path, on random boxes and on a real scan). The numpy counting code stays for a sensor with an attitude tolerance
(`_attitude_tolerant`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def _np_max(a, b):
    """np.maximum(a, b) of two floats: NaN if either is NaN, else the larger (a on a tie)."""
    return a if (a >= b or a != a) else b


@njit(cache=True)
def _np_min(a, b):
    """np.minimum(a, b) of two floats: NaN if either is NaN, else the smaller (a on a tie)."""
    return a if (a <= b or a != a) else b


@njit(cache=True)
def _slab(o, u, half):
    """occlusion._slab of one ray o + t u against |x| <= half: (t_in, t_out), empty if t_in > t_out."""
    if u == 0.0:
        if abs(o) <= half:
            return -math.inf, math.inf
        return math.inf, -math.inf
    ta = (-half - o) / u
    tb = (half - o) / u
    return _np_min(ta, tb), _np_max(ta, tb)


@njit(cache=True)
def beam_window(tan_e, h, half, t_in, t_out, crosses, tan_tol):
    """The beams that can hit a target: tan_e (B,) the beams' elevation tangents, h the sensor's height [m], half
    (1 or K,) half the targets' heights [m] (one for all, or per target), t_in, t_out, crosses (K, C) the columns'
    footprint crossings (footprint_slabs), tan_tol the tangent of the attitude tolerance. Returns tz_in, tz_out
    (1 or K, B) the horizontal distances [m] between which each beam is within [0, height] of the box, and the
    contiguous beams b0 .. b1 - 1 that can reach some target within the tolerance's band (b1 = 0: none)."""
    rows, B = half.shape[0], tan_e.shape[0]
    t_reach, t_near = -np.inf, np.inf
    for k in range(t_in.shape[0]):
        for c in range(t_in.shape[1]):
            if crosses[k, c]:
                t_reach = _np_max(t_reach, t_out[k, c])
                t_near = _np_min(t_near, t_in[k, c])
    slack = t_reach * tan_tol if math.isfinite(t_reach) else 0.0
    tz_in = np.empty((rows, B))
    tz_out = np.empty((rows, B))
    b0, b1 = 0, 0
    for j in range(B):
        useful = False
        for r in range(rows):
            base = h - half[r]  # the box's mid-height below the sensor
            tz_in[r, j], tz_out[r, j] = _slab(base, tan_e[j], half[r])
            band_in, band_out = _slab(base, tan_e[j], half[r] + slack)  # where a tilted beam may hit the box
            useful = useful or (band_in <= band_out and band_in <= t_reach and band_out >= t_near)
        if useful:
            if b1 == 0:
                b0 = j
            b1 = j + 1
    return tz_in, tz_out, b0, b1


@njit(cache=True)
def beam_bounds(tan_b, cos_e, tz_out, b0, h, min_hit, min_range, max_range):
    """Bounds on the horizontal distance t_hit [m] where each ray of the beams b0 .. b0 + b - 1 (elevation tangents
    tan_b and cosines cos_e (b,)) may enter a box: lo_t (b,) above min_hit [m] over the road and beyond min_range
    (slant), hi_t (1 or K, b) below the box top (tz_out (1 or K, B), beam_window), above min_hit and within
    max_range (slant); the sensor at height h [m]."""
    b = tan_b.shape[0]
    level = np.inf if h >= min_hit else -np.inf  # a level beam is always or never high enough
    lo_t = np.empty(b)
    hi_t = np.empty((tz_out.shape[0], b))
    for j in range(b):
        if tan_b[j] > 0:  # the ray is at least min_hit above the road for horizontal distances [tl_in, tl_out]
            tl_in, tl_out = (min_hit - h) / tan_b[j], np.inf
        elif tan_b[j] < 0:
            tl_in, tl_out = -np.inf, (min_hit - h) / tan_b[j]
        else:
            tl_in, tl_out = -level, level
        lo_t[j] = _np_max(tl_in, min_range * cos_e[j])
        for r in range(tz_out.shape[0]):
            hi_t[r, j] = _np_min(_np_min(tz_out[r, b0 + j], tl_out), max_range * cos_e[j])
    return lo_t, hi_t


@njit(cache=True)
def footprint_columns(rel, los, yaw, az0, step, max_columns):
    """The azimuth columns of each target's angular window: rel (K, 4) the bearings of its footprint's corners
    relative to its line of sight los (K,) [rad]; yaw the sensor's [rad]; az0, step the first column's azimuth
    and the spacing [rad]. At most max_columns are sampled per target, evenly. Returns col (K, C) unwrapped
    column indices, weight (K,) columns each sample stands for and valid (K, C) bool the sampled ones."""
    K = rel.shape[0]
    first = np.empty(K)
    n_window = np.empty(K, dtype=np.int64)
    for k in range(K):
        lo = _np_max(min(rel[k, 0], rel[k, 1], rel[k, 2], rel[k, 3]), -np.pi / 2)
        hi = _np_min(max(rel[k, 0], rel[k, 1], rel[k, 2], rel[k, 3]), np.pi / 2)
        centre = (los[k] - yaw - az0) / step
        f = np.ceil(centre + lo / step)
        last = np.floor(centre + hi / step)
        if last < f:  # window narrower than one column: take the nearest column
            f = last = np.rint(centre)
        first[k] = f
        n_window[k] = int(last - f + 1)
    C = min(n_window.max(), max_columns)
    col = np.empty((K, C), dtype=np.int64)
    weight = np.empty(K)
    valid = np.empty((K, C), dtype=np.bool_)
    for k in range(K):
        m = min(n_window[k], C)
        share = n_window[k] / m
        weight[k] = share
        for j in range(C):
            valid[k, j] = j < m
            col[k, j] = int(first[k]) + (int(np.floor((j + 0.5) * share)) if j < m else 0)
    return col, weight, valid


@njit(cache=True)
def footprint_slabs(ox, oy, cb, sb, ux, uy, hl, hw, valid):
    """The 2-D slab test of each column's ray against each target's footprint (box frame, centre at the origin):
    ox, oy, cb, sb (K,) the sensor's position in the box frame and the cos and sin of the box axis relative to the
    line of sight; ux, uy (K, C) each column's ray direction relative to the line of sight; hl, hw (K,) half length
    and width [m]; valid (K, C) bool the sampled columns. Returns t_in, t_out (K, C) [m] entry and exit distances,
    crosses (K, C) (a valid column whose ray crosses the footprint in front of the sensor) and end (K, C) (it
    enters through a front or rear face)."""
    K, C = ux.shape
    t_in = np.empty((K, C))
    t_out = np.empty((K, C))
    crosses = np.empty((K, C), dtype=np.bool_)
    end = np.empty((K, C), dtype=np.bool_)
    for k in range(K):
        for c in range(C):
            rx = cb[k] * ux[k, c] + sb[k] * uy[k, c]  # ray direction in the box frame
            ry = -sb[k] * ux[k, c] + cb[k] * uy[k, c]
            x_in, x_out = _slab(ox[k], rx, hl[k])
            y_in, y_out = _slab(oy[k], ry, hw[k])
            end[k, c] = x_in >= y_in  # the x slab (along the box's axis) is entered last
            a, b = _np_max(x_in, y_in), _np_min(x_out, y_out)
            t_in[k, c], t_out[k, c] = a, b
            crosses[k, c] = valid[k, c] and b >= a and a > 0.0
    return t_in, t_out, crosses, end


@njit(cache=True)
def ray_counts(col, t_in, t_out, crosses, end, tz_in, hi_t, lo_t, cos_e, tan_e, ranges, beam0, margin, h):
    """Ray by ray over each target's sampled columns col (K, C) (unwrapped azimuth indices) and the beams beam0 ..
    beam0 + b - 1: t_hit = max(t_in, tz_in) where the ray would enter the box [m], expected when t_hit <= min(t_out,
    hi_t), t_hit >= lo_t and the column crosses the footprint, clear when the range image's return r (ranges (A, B)
    [m], slant) lies no nearer horizontally than t_hit - margin. tz_in (1 or K, b) and hi_t (1 or K, b): per beam,
    for every target or per target; lo_t, cos_e, tan_e (b,). Returns the counts (K,) int64 of expected rays, clear
    rays, columns with an expected ray, columns with a clear one, such columns entered through an end face, and
    seen_top (K,) the highest entry height h + t_hit tan_e of a clear ray [m] (0 without one)."""
    K, C = col.shape
    b = lo_t.shape[0]
    n_az = ranges.shape[0]
    rays = np.zeros(K, dtype=np.int64)
    clear_rays = np.zeros(K, dtype=np.int64)
    columns = np.zeros(K, dtype=np.int64)
    clear_columns = np.zeros(K, dtype=np.int64)
    clear_end = np.zeros(K, dtype=np.int64)
    seen_top = np.zeros(K)
    for k in range(K):
        row = k if tz_in.shape[0] > 1 else 0
        top = 0.0
        for c in range(C):
            if not crosses[k, c]:
                continue
            a = col[k, c] % n_az
            any_expected = False
            any_clear = False
            for j in range(b):
                t_hit = _np_max(t_in[k, c], tz_in[row, j])
                if not (t_hit <= _np_min(t_out[k, c], hi_t[row, j]) and t_hit >= lo_t[j]):
                    continue
                any_expected = True
                rays[k] += 1
                if ranges[a, beam0 + j] * cos_e[j] + margin >= t_hit:
                    any_clear = True
                    clear_rays[k] += 1
                    z = h + t_hit * tan_e[j]
                    top = _np_max(top, z)
            if any_expected:
                columns[k] += 1
            if any_clear:
                clear_columns[k] += 1
                if end[k, c]:
                    clear_end[k] += 1
        seen_top[k] = top
    return rays, clear_rays, columns, clear_columns, clear_end, seen_top


@njit(cache=True)
def quantised_ranges(ranges, ray, drop, step):
    """occlusion.quantised_ranges' image: np.rint(ranges / step) * step (A, B) [m] of a C-contiguous range image
    ranges (A, B) [m], with inf at the rays ray[i] >= 0 of the points i with drop[i] (N,). One pass each; the same
    float64 division, rounding (half to even, as numpy's rint) and product as numpy's (inf stays inf)."""
    out = ranges.copy()
    flat = out.reshape(-1)
    for i in range(len(ray)):
        if drop[i] and ray[i] >= 0:
            flat[ray[i]] = np.inf
    for j in range(flat.size):
        flat[j] = np.rint(flat[j] / step) * step
    return out
