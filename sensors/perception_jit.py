"""Compiled (numba) per-object loops of sensors/perception.py, sensors/ground.py and sensors/clustering.py.

Each kernel computes what the former numpy code computed, bit for bit: sums follow numpy's pairwise
summation (the order `np.add.reduceat` adds in, `_reduceat_add`), products and differences are the same
float64 operations, and trigonometry and matrix products stay in numpy (the callers pass cos/sin arrays and
projections: numpy's transcendental functions and BLAS kernels round differently in the last bit). The merge's
union test (`merge_pairs`) only decides a comparison: it uses its own hull and rectangle, and hands the
decision back to the reference (sensors/perception_reference.py) where rounding could flip it. The former code
of the split, merge and link loops is kept in sensors/perception_reference.py and
tests/test_perception_identical.py checks the kernels against it. Objects are packed: `starts` (K,) and `n`
(K,) index the members' rows of the (sum n, ...) arrays, object by object.

Installed as roadtrack.sensors.perception_jit (issue 31.1). numba's cache pickles that module name and
recognises this file by a hash of its text (numba 0.68): code cached under the former top-level name
`sensors.perception_jit` cannot be loaded ("No module named 'sensors'"), so this paragraph came with the rename:
a new text, compiled afresh.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_PW_BLOCK = 128  # numpy's PW_BLOCKSIZE


@njit(cache=True)
def _pairwise(a, lo, n):
    """numpy's pairwise_sum of a[lo : lo + n] (the same additions in the same order)."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    if n <= _PW_BLOCK:
        r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
        r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
        i = 8
        stop = n - (n % 8)
        while i < stop:
            j = lo + i
            r0 += a[j]
            r1 += a[j + 1]
            r2 += a[j + 2]
            r3 += a[j + 3]
            r4 += a[j + 4]
            r5 += a[j + 5]
            r6 += a[j + 6]
            r7 += a[j + 7]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[lo + i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise(a, lo, n2) + _pairwise(a, lo + n2, n - n2)


@njit(cache=True)
def _reduceat_add(a, starts, n):
    """np.add.reduceat(a, starts) for consecutive segments of lengths n (all >= 1)."""
    out = np.empty(len(starts))
    for k in range(len(starts)):
        out[k] = a[starts[k]] + _pairwise(a, starts[k] + 1, n[k] - 1)
    return out


@njit(cache=True)
def object_sums(pts, members, starts, n, road_z, sx, sy):
    """Per object: top above the road (K,), footprint corners lo, hi (K, 2), centroid (K, 2), the second
    moments sxx, syy, sxy (K,) about it, the nearest horizontal range d_min (K,) from the sensor (sx, sy);
    per member: xy (sum n, 2), z (sum n,) and rel = xy - its object's centroid (sum n, 2). pts (N, 3) [m].

    d_min is the smallest np.hypot, taken only over the points whose dx * dx + dy * dy lies within 1e-12
    (relative) of the smallest: every other point's hypot is larger (both are within a few ulp of the range)."""
    k_all, m = len(starts), len(members)
    xy = np.empty((m, 2))
    x, y, z, d2 = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    top = np.empty(k_all)
    lo, hi = np.empty((k_all, 2)), np.empty((k_all, 2))
    d_min = np.empty(k_all)
    for k in range(k_all):
        s0, s1 = starts[k], starts[k] + n[k]
        t, xl, xh, yl, yh, d2_min = -np.inf, np.inf, -np.inf, np.inf, -np.inf, np.inf
        for i in range(s0, s1):
            p = members[i]
            px, py, pz = pts[p, 0], pts[p, 1], pts[p, 2]
            xy[i, 0], xy[i, 1] = px, py
            x[i], y[i], z[i] = px, py, pz
            t = max(t, pz)
            xl, xh, yl, yh = min(xl, px), max(xh, px), min(yl, py), max(yh, py)
            dx, dy = px - sx, py - sy
            d2[i] = dx * dx + dy * dy
            d2_min = min(d2_min, d2[i])
        near, d = d2_min * (1.0 + 1e-12) + 1e-290, np.inf
        for i in range(s0, s1):
            if d2[i] <= near:
                d = min(d, np.hypot(x[i] - sx, y[i] - sy))
        top[k] = t - road_z
        lo[k, 0], lo[k, 1], hi[k, 0], hi[k, 1] = xl, yl, xh, yh
        d_min[k] = d
    centroid = np.empty((k_all, 2))
    centroid[:, 0] = _reduceat_add(x, starts, n) / n
    centroid[:, 1] = _reduceat_add(y, starts, n) / n
    rel = np.empty((m, 2))
    xx, yy, xy_ = np.empty(m), np.empty(m), np.empty(m)
    for k in range(k_all):
        for i in range(starts[k], starts[k] + n[k]):
            rx, ry = x[i] - centroid[k, 0], y[i] - centroid[k, 1]
            rel[i, 0], rel[i, 1] = rx, ry
            xx[i], yy[i], xy_[i] = rx * rx, ry * ry, rx * ry
    return (top, lo, hi, centroid, _reduceat_add(xx, starts, n), _reduceat_add(yy, starts, n),
            _reduceat_add(xy_, starts, n), d_min, xy, z, rel)


@njit(cache=True)
def extent(rel, cx, cy, starts, n):
    """(K,) extent of each object's points rel (sum n, 2) along (cx, cy) (K,) each."""
    out = np.empty(len(starts))
    for k in range(len(starts)):
        w_lo, w_hi = np.inf, -np.inf
        for i in range(starts[k], starts[k] + n[k]):
            w = rel[i, 0] * cx[k] + rel[i, 1] * cy[k]
            w_lo, w_hi = min(w_lo, w), max(w_hi, w)
        out[k] = w_hi - w_lo
    return out


@njit(cache=True)
def axis_extents(rel, cos_p, sin_p, cos_a, sin_a, starts, n):
    """extent(rel, -sin_p, cos_p), extent(rel, cos_p, sin_p), u (each member along (cos_a, sin_a)) and its extent, and
    extent(rel, -sin_a, cos_a) in one pass over rel (sum n, 2): the same products and sums per point."""
    k_all = len(starts)
    thickness, p_length, along_, across = np.empty(k_all), np.empty(k_all), np.empty(k_all), np.empty(k_all)
    u = np.empty(len(rel))
    for k in range(k_all):
        cp, sp, ca, sa = cos_p[k], sin_p[k], cos_a[k], sin_a[k]
        ncp, nsp, nsa = -sp, cp, -sa  # (cx, cy) of the principal axis's normal; -sin_a of axis's normal
        t_lo = p_lo = u_lo = c_lo = np.inf
        t_hi = p_hi = u_hi = c_hi = -np.inf
        for i in range(starts[k], starts[k] + n[k]):
            x, y = rel[i, 0], rel[i, 1]
            w = x * ncp + y * nsp
            t_lo, t_hi = min(t_lo, w), max(t_hi, w)
            w = x * cp + y * sp
            p_lo, p_hi = min(p_lo, w), max(p_hi, w)
            w = x * ca + y * sa
            u[i] = w
            u_lo, u_hi = min(u_lo, w), max(u_hi, w)
            w = x * nsa + y * ca
            c_lo, c_hi = min(c_lo, w), max(c_hi, w)
        thickness[k], p_length[k], along_[k], across[k] = t_hi - t_lo, p_hi - p_lo, u_hi - u_lo, c_hi - c_lo
    return thickness, p_length, u, along_, across


@njit(cache=True)
def medians(z, starts, n):
    """(K,) median of each object's z (sum n,)."""
    out = np.empty(len(starts))
    for k in range(len(starts)):
        m = n[k]
        s = np.partition(z[starts[k] : starts[k] + m], m // 2)  # s[m // 2] in place, the smaller ones before
        lower = s[m // 2] if m % 2 else s[: m // 2].max()  # the ((m - 1) // 2)-th smallest
        out[k] = 0.5 * (lower + s[m // 2])
    return out


@njit(cache=True)
def lift_spans(z, xy, top, starts, n):
    """Per object: its lowest z (K,), and the larger x/y span of its points at most half-way between its
    lowest z and top (K,) and of those above (K,) (0 when there are none)."""
    k_all = len(starts)
    bottom, low_span, high_span = np.empty(k_all), np.empty(k_all), np.empty(k_all)
    for k in range(k_all):
        s0, s1 = starts[k], starts[k] + n[k]
        b = np.inf
        for i in range(s0, s1):
            b = min(b, z[i])
        mid = 0.5 * (b + top[k])
        lx0, lx1, ly0, ly1 = np.inf, -np.inf, np.inf, -np.inf
        hx0, hx1, hy0, hy1 = np.inf, -np.inf, np.inf, -np.inf
        for i in range(s0, s1):
            px, py = xy[i, 0], xy[i, 1]
            if z[i] <= mid:
                lx0, lx1, ly0, ly1 = min(lx0, px), max(lx1, px), min(ly0, py), max(ly1, py)
            else:
                hx0, hx1, hy0, hy1 = min(hx0, px), max(hx1, px), min(hy0, py), max(hy1, py)
        bottom[k] = b
        low_span[k] = max(lx1 - lx0, ly1 - ly0) if lx1 >= lx0 else 0.0
        high_span[k] = max(hx1 - hx0, hy1 - hy0) if hx1 >= hx0 else 0.0
    return bottom, low_span, high_span


@njit(cache=True)
def body_reaches(z, u, required, bin_m, starts, n):
    """(K,) bool: in at least half of each object's occupied bin_m bins along u (sum n,), the highest z
    (sum n,) reaches required (K,)."""
    out = np.empty(len(starts), np.bool_)
    for k in range(len(starts)):
        s0, s1 = starts[k], starts[k] + n[k]
        u0 = np.inf
        for i in range(s0, s1):
            u0 = min(u0, u[i])
        b = np.empty(s1 - s0, np.int64)
        for i in range(s0, s1):
            b[i - s0] = np.int64((u[i] - u0) / bin_m)
        bin_top = np.full(b.max() + 1, -np.inf)
        for i in range(s0, s1):
            bin_top[b[i - s0]] = max(bin_top[b[i - s0]], z[i])
        used = np.zeros(len(bin_top), np.bool_)
        for i in range(s1 - s0):
            used[b[i]] = True
        bins, reach = 0, 0
        for j in range(len(bin_top)):
            if used[j]:
                bins += 1
                if bin_top[j] >= required[k]:
                    reach += 1
        out[k] = reach >= 0.5 * bins
    return out


@njit(cache=True)
def relative_columns(pts, cx, cy, cz):
    """sensors/ground._road_plane's columns: x, y, z (N,) = pts (N, 3) [m] minus (cx, cy, cz), and (4,) the
    smallest and largest pts x, then y [m] (pts[:, 0].min(), .max(), pts[:, 1].min(), .max()); N >= 1."""
    n = len(pts)
    x, y, z = np.empty(n), np.empty(n), np.empty(n)
    x_lo, x_hi, y_lo, y_hi = pts[0, 0], pts[0, 0], pts[0, 1], pts[0, 1]
    for i in range(n):
        px, py = pts[i, 0], pts[i, 1]
        x[i], y[i], z[i] = px - cx, py - cy, pts[i, 2] - cz
        x_lo, x_hi, y_lo, y_hi = min(x_lo, px), max(x_hi, px), min(y_lo, py), max(y_hi, py)
    return x, y, z, np.array([x_lo, x_hi, y_lo, y_hi])


@njit(cache=True)
def near_plane(x, y, z, a, b, c, band):
    """x, y, z (M,) of the points x, y, z (N,) with np.abs(z - a x - b y - c) <= band (the same operations in
    the same order as numpy's), in their order."""
    n = len(z)
    xs, ys, zs = np.empty(n), np.empty(n), np.empty(n)
    m = 0
    for i in range(n):  # branch-free: every point written at m, kept when m moves on
        xs[m], ys[m], zs[m] = x[i], y[i], z[i]
        m += abs(z[i] - a * x[i] - b * y[i] - c) <= band
    return xs[:m], ys[:m], zs[:m]


@njit(cache=True)
def cell_lowest(pts, z, inv, fx0, fy0, ny, size, cell, ox, oy):
    """The lowest z (N,) in each occupied BEV cell (floor(x inv) - fx0) * ny + floor(y inv) - fy0 of the points
    (N, 3) (sensors/grid.bev_cells numbering; size cells), in cell order, and the cells' centres relative to
    (ox, oy): cx = (fx0 + 0.5 + cell // ny) * cell - ox and cy likewise (numpy's operations): cx, cy, low (M,)."""
    lowest = np.full(size, np.inf)
    for i in range(len(z)):
        c = np.int64(np.floor(pts[i, 0] * inv) - fx0) * ny + np.int64(np.floor(pts[i, 1] * inv) - fy0)
        if z[i] < lowest[c]:
            lowest[c] = z[i]
    m = 0
    for c in range(size):
        m += lowest[c] < np.inf
    cx, cy, low = np.empty(m), np.empty(m), np.empty(m)
    j = 0
    for c in range(size):
        if lowest[c] < np.inf:
            cx[j] = (fx0 + 0.5 + np.float64(c // ny)) * cell - ox
            cy[j] = (fy0 + 0.5 + np.float64(c % ny)) * cell - oy
            low[j] = lowest[c]
            j += 1
    return cx, cy, low


@njit(cache=True)
def road_band(x, y, z, a, b, c, with_range, road_tol, range_term, tan_angle, height_tol, foot_cell, foot_lo,
              foot_hi, foot_keep):
    """sensors/ground._road_plane's labels: (N,) bool, a point at most its band above the plane z = a x + b y + c
    (x, y, z (N,) relative to the sensor), minus the band's upper part at an object foot.

    with_range: band = min(road_tol + range_term / max(r, 1e-9) + r tan_angle, height_tol) at the range r,
    else height_tol. foot_cell > 0: a point with height above the plane in (foot_keep band, band] sharing a
    foot_cell cell with one in (band + foot_lo, band + foot_hi] is not road (the latter's cells in a _foot_cells
    hash set: one probe per point instead of a sort and a binary search)."""
    n = len(z)
    is_ground = np.empty(n, np.bool_)
    # per point 1 when tested, 2 when above; padded to whole uint64 words, so the gathering below skips 8 points
    # with no flag at a time (this loop stays branch-free: compiled to SIMD code)
    flag = np.zeros((n + 7) // 8 * 8, np.uint8)
    n_test = n_above = 0
    for i in range(n):
        res = z[i] - a * x[i] - b * y[i] - c
        if with_range:
            r = np.sqrt(x[i] * x[i] + y[i] * y[i] + z[i] * z[i])
            tol = road_tol + range_term / max(r, 1e-9)
            if tan_angle > 0.0:
                tol += r * tan_angle
            tol = min(tol, height_tol)
        else:
            tol = height_tol
        g = res <= tol
        is_ground[i] = g
        tested = g and res > foot_keep * tol
        above = res > tol + foot_lo and res <= tol + foot_hi
        flag[i] = tested + 2 * above
        n_test += tested
        n_above += above
    if foot_cell <= 0.0 or n_above == 0 or n_test == 0:
        return is_ground
    test, above_at = np.empty(n_test, np.int64), np.empty(n_above, np.int64)  # the flagged points' indices
    n_test = n_above = 0
    words = flag.view(np.uint64)
    for w in range(len(words)):
        if words[w] != 0:
            for i in range(8 * w, 8 * w + 8):
                if flag[i] & 1:
                    test[n_test] = i
                    n_test += 1
                if flag[i] & 2:
                    above_at[n_above] = i
                    n_above += 1
    inv = 1.0 / foot_cell
    cells = _foot_cells(n_above)
    for i in above_at:
        _foot_cells_add(cells, _foot_key(x[i], y[i], inv))
    for i in test:
        if _foot_cells_has(cells, _foot_key(x[i], y[i], inv)):
            is_ground[i] = False
    return is_ground


@njit(cache=True)
def _foot_key(x, y, inv):
    """One int64 per (floor(x inv), floor(y inv)) cell (distinct cells, distinct keys, within +-2^31 cells)."""
    return np.int64(np.floor(x * inv)) * 4294967296 + np.int64(np.floor(y * inv))


_FIB = np.uint64(0x9E3779B97F4A7C15)  # 2^64 / golden ratio: Fibonacci hashing's multiplier


@njit(cache=True)
def _foot_cells(n):
    """An empty hash set for up to n int64 keys: (keys (2^k,) int64, used (2^k,) bool, k), 2^k >= 2 n slots, open
    addressing with linear probing from the key's Fibonacci hash."""
    bits = 4
    while (1 << bits) < 2 * n:
        bits += 1
    return np.empty(1 << bits, np.int64), np.zeros(1 << bits, np.bool_), bits


@njit(cache=True)
def _slot(key, bits):
    return np.int64((np.uint64(key) * _FIB) >> np.uint64(64 - bits))


@njit(cache=True)
def _foot_cells_probe(cells, key):
    """The slot of key in the set `cells` (_foot_cells), or the empty slot where it goes (linear probing)."""
    keys, used, bits = cells
    mask = len(keys) - 1
    s = _slot(key, bits)
    while used[s] and keys[s] != key:
        s = (s + 1) & mask
    return s


@njit(cache=True)
def _foot_cells_add(cells, key):
    """Put key into the set `cells` (_foot_cells)."""
    s = _foot_cells_probe(cells, key)
    cells[0][s], cells[1][s] = key, True


@njit(cache=True)
def _foot_cells_has(cells, key):
    """Whether key is in the set `cells` (_foot_cells)."""
    return cells[1][_foot_cells_probe(cells, key)]


# --- split (sensors/perception_reference.split_reference) ---------------------------------------------------

@njit(cache=True)
def _best_cut(u, v, z, by_u, by_v, road_z, bounds, min_split_gap, split_gap, min_extent, min_points):
    """perception_reference.cut_reference on one part of an object: (dim, j), its first piece being the points
    by_u[: j + 1] (dim 0) or by_v[: j + 1] (dim 1), or (-1, -1) when the part stays whole. u, v (n,) the object's
    points along / across its axis, z (n,) their heights [m]; by_u, by_v (m,) the part's points sorted by u and
    by v (stable: ties in point order, as the reference's argsort of the part); bounds (4,) max_length_m,
    max_width_m, truck_min_top_m, max_truck_length_m."""
    m = len(by_u)
    ext_u, ext_v = u[by_u[m - 1]] - u[by_u[0]], v[by_v[m - 1]] - v[by_v[0]]
    top = -np.inf
    for i in range(m):
        top = max(top, z[by_u[i]])
    top -= road_z
    max_length = bounds[3] if top >= bounds[2] else bounds[0]
    too_big = max(ext_u, ext_v) > max_length or min(ext_u, ext_v) > bounds[1]
    min_gap = min_split_gap if too_big else split_gap
    best_dim, best_j, best_gap = -1, -1, 0.0
    r_hi, r_lo = np.empty(m), np.empty(m)
    for dim in range(2 if too_big else 1):  # a vehicle-sized object is cut only along the axis
        order, t, o = (by_u, u, v) if dim == 0 else (by_v, v, u)
        hi, lo = -np.inf, np.inf
        for i in range(m - 1, -1, -1):  # the other coordinate's range from i on
            hi, lo = max(hi, o[order[i]]), min(lo, o[order[i]])
            r_hi[i], r_lo[i] = hi, lo
        hi, lo = -np.inf, np.inf
        j, j_gap = -1, 0.0
        t0, t1 = t[order[0]], t[order[m - 1]]
        for i in range(m - 1):
            hi, lo = max(hi, o[order[i]]), min(lo, o[order[i]])
            gap = t[order[i + 1]] - t[order[i]]
            left = max(t[order[i]] - t0, hi - lo)
            right = max(t1 - t[order[i + 1]], r_hi[i + 1] - r_lo[i + 1])
            if (gap >= min_gap and i + 1 >= min_points and m - i - 1 >= min_points and left >= min_extent
                    and right >= min_extent and (j < 0 or gap > j_gap)):
                j, j_gap = i, gap  # the first widest gap
        if j >= 0 and (best_j < 0 or j_gap > best_gap):
            best_dim, best_j, best_gap = dim, j, j_gap
    return best_dim, best_j


@njit(cache=True)
def split_pieces(u, v, z, by_u, by_v, road_z, bounds, min_split_gap, split_gap, min_extent, min_points,
                 max_splits):
    """perception_reference.split_reference of one object: piece (n,) int64 the piece of each point, numbered
    in the reference's order of the pieces, and their count. u, v (n,) the points along / across the object's
    axis (numpy's products, as the reference computes them), z (n,) their heights [m], by_u, by_v (n,) their
    stable argsorts; bounds as _best_cut. Each part keeps the object's sorted orders (a stable sort of a part is
    its points in the object's order)."""
    n = len(u)
    piece = np.empty(n, np.int64)
    first = np.zeros(n, np.bool_)
    stack_u, stack_v = [by_u], [by_v]
    depth = [0]
    count = 0
    while len(depth) > 0:
        by_u, by_v, d = stack_u.pop(), stack_v.pop(), depth.pop()
        dim, j = -1, -1
        if d < max_splits:
            dim, j = _best_cut(u, v, z, by_u, by_v, road_z, bounds, min_split_gap, split_gap, min_extent,
                               min_points)
        if dim < 0:
            piece[by_u] = count
            count += 1
            continue
        cut = by_u if dim == 0 else by_v
        first[cut[: j + 1]] = True
        in_u, in_v = first[by_u], first[by_v]
        for part in (True, False):  # the reference queues (first, second) and takes the second first
            stack_u.append(by_u[in_u == part])
            stack_v.append(by_v[in_v == part])
            depth.append(d + 1)
        first[cut[: j + 1]] = False
    return piece, count


# --- merge (sensors/perception_reference.merge_reference, union_fits_reference) ----------------------------

@njit(cache=True)
def _sorted_by_x(xy, s0, m):
    for i in range(s0 + 1, s0 + m):
        if xy[i, 0] < xy[i - 1, 0]:
            return False
    return True


@njit(cache=True)
def _nearest_sq(xy, sa, na, sb, nb, bound):
    """The smallest squared distance dx*dx + dy*dy (cKDTree's arithmetic) below `bound` between the points
    xy[sa : sa + na] and xy[sb : sb + nb] [m], else bound. Each run sorted by x: a sweep in x that skips only
    pairs whose dx*dx alone exceeds the best so far; otherwise (unsorted) all pairs."""
    best = bound
    if not (_sorted_by_x(xy, sa, na) and _sorted_by_x(xy, sb, nb)):
        for j in range(sb, sb + nb):
            for i in range(sa, sa + na):
                dx, dy = xy[i, 0] - xy[j, 0], xy[i, 1] - xy[j, 1]
                best = min(best, dx * dx + dy * dy)
        return best
    x_lo, x_hi = xy[sa, 0], xy[sa + na - 1, 0]  # the box of a's points
    y_lo, y_hi = np.inf, -np.inf
    for i in range(sa, sa + na):
        y_lo, y_hi = min(y_lo, xy[i, 1]), max(y_hi, xy[i, 1])
    lo = sa
    for j in range(sb, sb + nb):
        xb, yb = xy[j, 0], xy[j, 1]
        # a point of b farther from a's box than the best is farther from every point of a: skipped. Exact: each
        # coordinate difference to a point of a rounds to at least that to the box's side (rounding is monotone)
        bx = x_lo - xb if xb < x_lo else (xb - x_hi if xb > x_hi else 0.0)
        by = y_lo - yb if yb < y_lo else (yb - y_hi if yb > y_hi else 0.0)
        if bx * bx + by * by > best:
            continue
        while lo < sa + na and xy[lo, 0] < xb and (xb - xy[lo, 0]) * (xb - xy[lo, 0]) > best:
            lo += 1  # farther left than the best distance, for this point and every later (larger x) one
        for i in range(lo, sa + na):
            dx = xy[i, 0] - xb
            if dx >= 0.0 and dx * dx > best:
                break
            dy = xy[i, 1] - yb
            best = min(best, dx * dx + dy * dy)
    return best


@njit(cache=True)
def pair_gaps(xy, starts, n, pa, pb, gap):
    """(P,) the smallest distance [m] between the points of objects pa (P,) and pb (P,) when it is below gap [m],
    else inf: the cKDTree query of perception_reference.merge_reference (distance_upper_bound=gap reports a
    neighbour when its squared distance is below gap * gap). xy (sum n, 2) the objects' points, packed by starts,
    n (K,), each object's in canonical (x-sorted) order."""
    out = np.empty(len(pa))
    bound = gap * gap
    for p in range(len(pa)):
        a, b = pa[p], pb[p]
        best = _nearest_sq(xy, starts[a], n[a], starts[b], n[b], bound)
        out[p] = np.sqrt(best) if best < bound else np.inf
    return out


@njit(cache=True)
def _turn(x, y, a, b, q):
    """> 0 when the points a, b, q turn counter-clockwise."""
    return (x[b] - x[a]) * (y[q] - y[a]) - (y[b] - y[a]) * (x[q] - x[a])


@njit(cache=True)
def _hull_ccw(x, y):
    """Indices of the convex-hull vertices of the points (x, y) (m,), sorted by x then y, counter-clockwise
    (Andrew's monotone chain; points on an edge left out). Fewer than 3 for collinear points."""
    m = len(x)
    h = np.empty(2 * m + 1, np.int64)
    k = 0
    for q in range(m):  # lower chain, left to right
        while k >= 2 and _turn(x, y, h[k - 2], h[k - 1], q) <= 0.0:
            k -= 1
        h[k] = q
        k += 1
    lower = k + 1
    for q in range(m - 2, -1, -1):  # upper chain, back
        while k >= lower and _turn(x, y, h[k - 2], h[k - 1], q) <= 0.0:
            k -= 1
        h[k] = q
        k += 1
    return h[: max(k - 1, 0)]


@njit(cache=True)
def _sort_xy(x, y):
    """The order sorting the points (x, y) (m,) by x, then y."""
    order = np.argsort(x, kind="mergesort")
    i = 0
    while i < len(order):  # runs of equal x: by y (insertion sort, runs are short)
        j = i + 1
        while j < len(order) and x[order[j]] == x[order[i]]:
            q, r = order[j], j
            while r > i and y[order[r - 1]] > y[q]:
                order[r] = order[r - 1]
                r -= 1
            order[r] = q
            j += 1
        i = j
    return order


@njit(cache=True)
def _object_hull(xy, s0, m, out_x, out_y, k):
    """Append the convex-hull vertices of the points xy[s0 : s0 + m] to out_x, out_y from k on; returns the new k."""
    x, y = xy[s0 : s0 + m, 0].copy(), xy[s0 : s0 + m, 1].copy()
    ordered = True
    for i in range(1, m):
        if x[i] < x[i - 1] or (x[i] == x[i - 1] and y[i] < y[i - 1]):
            ordered = False
            break
    if not ordered:
        order = _sort_xy(x, y)
        x, y = x[order], y[order]
    for q in _hull_ccw(x, y) if m >= 3 else np.arange(m):
        out_x[k], out_y[k] = x[q], y[q]
        k += 1
    return k


@njit(cache=True)
def _group_hull(xy, starts, n, head, nxt, ra, rb):
    """(x, y) the convex-hull vertices (counter-clockwise, relative to the first point) of the points of the
    objects listed from head[ra] and head[rb] along nxt (-1 ends a list)."""
    size = 0
    for r in (ra, rb):
        o = head[r]
        while o >= 0:
            size += n[o]
            o = nxt[o]
    hx, hy = np.empty(size), np.empty(size)
    k = 0
    for r in (ra, rb):
        o = head[r]
        while o >= 0:
            k = _object_hull(xy, starts[o], n[o], hx, hy, k)
            o = nxt[o]
    hx, hy = hx[:k] - hx[0], hy[:k] - hy[0]
    order = _sort_xy(hx, hy)
    hx, hy = hx[order], hy[order]
    keep = _hull_ccw(hx, hy)
    return hx[keep], hy[keep]


@njit(cache=True)
def _min_area_box(x, y, area_tol, side_tol):
    """(length, width, clear): the sides [m] of the minimum-area rectangle around the convex polygon (x, y)
    (h >= 3 vertices, counter-clockwise), one side on an edge (rotating calipers). clear is False when the
    polygon is flat (width <= side_tol) or another edge's rectangle comes within area_tol (relative) of the
    smallest area with sides more than side_tol apart (a reference on its own hull may pick either)."""
    h = len(x)
    area, length, width = np.empty(h), np.empty(h), np.empty(h)
    for e in range(h):
        f = (e + 1) % h
        ex, ey = x[f] - x[e], y[f] - y[e]
        norm = math.hypot(ex, ey)
        c, s = ex / norm, ey / norm
        u_lo, u_hi, v_lo, v_hi = np.inf, -np.inf, np.inf, -np.inf
        for q in range(h):
            u, v = x[q] * c + y[q] * s, y[q] * c - x[q] * s
            u_lo, u_hi, v_lo, v_hi = min(u_lo, u), max(u_hi, u), min(v_lo, v), max(v_hi, v)
        du, dv = u_hi - u_lo, v_hi - v_lo
        area[e], length[e], width[e] = du * dv, max(du, dv), min(du, dv)
    k = np.argmin(area)
    clear = width[k] > side_tol
    for e in range(h):
        if area[e] <= area[k] * (1.0 + area_tol) and (abs(length[e] - length[k]) > side_tol
                                                      or abs(width[e] - width[k]) > side_tol):
            clear = False
    return length[k], width[k], clear


@njit(cache=True)
def _root(parent, i):
    while parent[i] != i:
        i = parent[i]
    return i


@njit(cache=True)
def _unite(ra, rb, parent, head, nxt, tail, top):
    """Join the groups of roots ra, rb: the smaller root stays, its list is ra's then rb's objects."""
    keep, drop = min(ra, rb), max(ra, rb)
    first, last = head[ra], tail[rb]
    nxt[tail[ra]] = head[rb]
    parent[drop] = keep
    head[keep], tail[keep] = first, last
    top[keep] = max(top[ra], top[rb])


@njit(cache=True)
def merge_pairs(xy, starts, n, pa, pb, first, decided, bounds, margin, parent, head, nxt, tail, top):
    """The merge's union loop (perception_reference.unite_reference) from pair `first` on: the groups of objects
    pa[p] and pb[p] (P,) are joined, in order p, when the minimum-area rectangle of their points fits one
    vehicle; bounds as _cut_mask. State, updated in place, per object (K,): parent (its group's root is reached
    along it), head/tail (a root's first and last object), nxt (the next object in its group, -1 last), top
    (a root's highest point above the road [m]). decided >= 0: the test of pair `first` (1 join, 0 not).

    Returns the first pair whose test is not clear (flat or ambiguous rectangle, or a side within margin [m] of
    its bound: rounding could flip it; the caller runs the reference test and calls again with its result), or
    P when done."""
    for p in range(first, len(pa)):
        ra, rb = _root(parent, pa[p]), _root(parent, pb[p])
        if ra == rb:
            continue
        if p == first and decided >= 0:
            fits = decided == 1
        else:
            hx, hy = _group_hull(xy, starts, n, head, nxt, ra, rb)
            if len(hx) < 3:
                return p
            length, width, clear = _min_area_box(hx, hy, 1e-9, margin)
            t = max(top[ra], top[rb])
            max_length = bounds[3] if t >= bounds[2] else bounds[0]
            if not clear or abs(length - max_length) <= margin or abs(width - bounds[1]) <= margin:
                return p
            fits = not (length > max_length or width > bounds[1])
        if fits:
            _unite(ra, rb, parent, head, nxt, tail, top)
    return len(pa)


# --- box fit inputs (sensors/perception_reference.open_ends_reference) -------------------------------------

@njit(cache=True)
def open_ends(ray, members, starts, n, keys, ranges, margin, look):
    """(K, 2) bool per object of keys (K,): whether its (first, last) azimuth edge, counter-clockwise, is bounded
    by a nearer return (perception_reference.open_ends_reference), and whether every member's ray (N,) is known
    (else the ends are not computed). An object's columns start after the widest empty arc of its azimuth
    columns (the first widest, counter-clockwise); an edge is open when in one of the `look` columns beyond it
    a beam the object uses at that edge returns more than margin [m] nearer than the object's nearest return in
    that column. ranges (A, B) [m]."""
    n_az, n_beams = ranges.shape
    out = np.zeros((len(keys), 2), np.bool_)
    for k in keys:
        for i in range(starts[k], starts[k] + n[k]):
            if ray[members[i]] < 0:
                return out, False
    seen = np.zeros(n_az, np.bool_)  # the columns met so far in this object (reset after each)
    found = np.empty(n_az, np.int64)
    for q in range(len(keys)):
        s0, m = starts[keys[q]], n[keys[q]]
        az = np.empty(m, np.int64)
        n_cols = 0
        for i in range(m):
            a = ray[members[s0 + i]] // n_beams
            az[i] = a
            if not seen[a]:
                seen[a] = True
                found[n_cols] = a
                n_cols += 1
        cols = np.sort(found[:n_cols])  # np.unique(az) without sorting all members
        seen[cols] = False
        widest, widest_gap = 0, -1
        for i in range(len(cols)):
            gap = (cols[i + 1] if i + 1 < len(cols) else cols[0] + n_az) - cols[i]
            if gap > widest_gap:
                widest, widest_gap = i, gap
        edges = (cols[(widest + 1) % len(cols)], cols[widest])  # (first, last)
        for e in range(2):
            edge, step = edges[e], -1 if e == 0 else 1
            here = np.inf
            for i in range(m):
                if az[i] == edge:
                    here = min(here, ranges[edge, ray[members[s0 + i]] % n_beams])
            for i in range(m):
                if az[i] == edge and not out[q, e]:
                    b = ray[members[s0 + i]] % n_beams
                    for step_k in range(1, look + 1):
                        if ranges[(edge + step * step_k) % n_az, b] < here - margin:
                            out[q, e] = True
    return out, True


# --- scan-line links (sensors/perception_reference.link_unions_reference) ----------------------------------

@njit(cache=True)
def _root_halving(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def link_unions(ia, ib, pending, lo, hi, top, holds_cluster, truck_top, truck_len, car_len):
    """The union loop of sensors.perception._linked (perception_reference.link_unions_reference): links (L,) join
    nodes ia[k], ib[k] (U nodes: boxes lo, hi (U, 2) [m], tops (U,) [m], holds_cluster (U,) bool), in the order
    pending (L,), in passes until none joins. Returns the root (U,) int64 of every node. Only comparisons, min and
    max: the same decisions as the reference."""
    u_all = len(lo)
    parent = np.arange(u_all)
    lo, hi, top, holds = lo.copy(), hi.copy(), top.copy(), holds_cluster.copy()
    todo = pending.copy()
    n_todo = len(todo)
    grew = True
    while n_todo > 0 and grew:
        grew = False
        n_later = 0
        for j in range(n_todo):
            k = todo[j]
            r, s = _root_halving(parent, ia[k]), _root_halving(parent, ib[k])
            if r == s or holds[r] == holds[s]:
                if r != s and not holds[r]:
                    todo[n_later] = k  # n_later <= j: overwrites only links already taken
                    n_later += 1
                continue
            bx0, by0 = min(lo[r, 0], lo[s, 0]), min(lo[r, 1], lo[s, 1])
            bx1, by1 = max(hi[r, 0], hi[s, 0]), max(hi[r, 1], hi[s, 1])
            t = max(top[r], top[s])
            if max(bx1 - bx0, by1 - by0) > (truck_len if t >= truck_top else car_len):
                continue
            parent[s] = r
            lo[r, 0], lo[r, 1], hi[r, 0], hi[r, 1], top[r] = bx0, by0, bx1, by1, t
            holds[r] = True
            grew = True
        n_todo = n_later
    roots = np.empty(u_all, np.int64)
    for i in range(u_all):
        roots[i] = _root_halving(parent, i)
    return roots


# --- scan-line links (sensors/clustering.scan_line_links) ----------------------------------------------------

@njit(cache=True)
def _norm3(x, y, z):
    """np.linalg.norm of one row (x, y, z): sqrt((x x + y y) + z z), numpy's order for a 3-wide axis."""
    return np.sqrt((x * x + y * y) + z * z)


@njit(cache=True, error_model="numpy")
def line_links(pts, ray, n_az, n_beams, returned, labels, has_labels, origin, max_gap, min_sin):
    """sensors.clustering.scan_line_links (perception_reference.scan_line_links_reference): (L, 2) int64 pairs of
    indices into pts (N, 3) [m] of consecutive returns of one beam (ray (N,) int64 flat index a * n_beams + b,
    -1 unknown; the next azimuth, or the one after when the next returned nothing: returned (n_az, n_beams)
    bool), not already in one cluster (labels (N,) int64 when has_labels), at most max_gap [m] apart and at
    least asin(min_sin) off the line of sight from origin (3,) [m]. The same float operations in numpy's order."""
    n = len(ray)
    n_known = 0
    for k in range(n):
        n_known += ray[k] >= 0
    if n_known < 2 or n_az < 2:
        return np.zeros((0, 2), np.int64)
    at = np.full(n_az * n_beams, -1, np.int32)  # int32: half the table to fill (N < 2^31 points)
    for k in range(n):
        if ray[k] >= 0:
            at[ray[k]] = k
    out = np.empty((n_known, 2), np.int64)
    m = 0
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in range(n):
        if ray[i] < 0:
            continue
        a, b = ray[i] // n_beams, ray[i] % n_beams
        j = at[((a + 1) % n_az) * n_beams + b]
        if j < 0 and not returned[(a + 1) % n_az, b]:
            j = at[((a + 2) % n_az) * n_beams + b]
        if j < 0:
            continue
        if has_labels and not (labels[i] != labels[j] or labels[i] < 0):
            continue
        dx, dy, dz = pts[j, 0] - pts[i, 0], pts[j, 1] - pts[i, 1], pts[j, 2] - pts[i, 2]
        length = _norm3(dx, dy, dz)
        far_j = _norm3(pts[j, 0] - ox, pts[j, 1] - oy, pts[j, 2] - oz) >= _norm3(pts[i, 0] - ox, pts[i, 1] - oy,
                                                                                pts[i, 2] - oz)
        f = j if far_j else i
        ux, uy, uz = pts[f, 0] - ox, pts[f, 1] - oy, pts[f, 2] - oz
        un = _norm3(ux, uy, uz)
        ux, uy, uz = ux / un, uy / un, uz / un
        cx, cy, cz = dy * uz - dz * uy, dz * ux - dx * uz, dx * uy - dy * ux  # np.cross(d, u)
        sin_angle = _norm3(cx, cy, cz) / max(length, 1e-12)
        if length <= max_gap and sin_angle >= min_sin:
            out[m, 0], out[m, 1] = i, j
            m += 1
    return out[:m].copy()


# --- provenance (sensors/perception_reference.plurality_reference) -------------------------------------------

_FEW_LABELS = 8  # plurality: distinct labels counted in its table before it sorts the object's labels


@njit(cache=True)
def plurality(source, starts, n):
    """(K,) per object (source[starts[k] : starts[k] + n[k]], n >= 1) its most frequent label if >= 0, else -1;
    ties go to the smallest label. The counts of up to _FEW_LABELS distinct labels are kept in a small table (an
    object's points come from one or a few boxes); an object with more is sorted (the former kernel)."""
    out = np.empty(len(starts), np.int64)
    values, counts = np.empty(_FEW_LABELS, np.int64), np.empty(_FEW_LABELS, np.int64)
    for k in range(len(starts)):
        s0, m = starts[k], n[k]
        n_values, few = 0, True
        for i in range(s0, s0 + m):
            j = 0
            while j < n_values and values[j] != source[i]:
                j += 1
            if j == n_values:
                if n_values == _FEW_LABELS:
                    few = False
                    break
                values[j], counts[j] = source[i], 0
                n_values += 1
            counts[j] += 1
        if not few:
            out[k] = _plurality_sorted(source[s0 : s0 + m])
            continue
        best, best_count = values[0], counts[0]
        for j in range(1, n_values):  # most points, then the smallest label (the sorted runs' rule)
            if counts[j] > best_count or (counts[j] == best_count and values[j] < best):
                best, best_count = values[j], counts[j]
        out[k] = best if best >= 0 else -1
    return out


@njit(cache=True)
def _plurality_sorted(source):
    """plurality of one object's labels source (n,) by sorting them: the most frequent if >= 0 (ties: smallest)."""
    labels = np.sort(source)
    best, best_count, run = labels[0], 0, 0
    for i in range(len(labels)):
        run = run + 1 if i > 0 and labels[i] == labels[i - 1] else 1
        if run > best_count:  # a later label needs strictly more points: ties keep the smaller
            best, best_count = labels[i], run
    return best if best >= 0 else -1


# --- split candidates (sensors/perception_reference.widest_gaps_reference) -----------------------------------

@njit(cache=True)
def widest_gaps(u, starts, n, u_min, span, keys):
    """(K,) the widest gap between consecutive sorted values of each object's u (sum n,) for the objects keys (Q,)
    (0 for the others), and whether the reference's one sort by the key k * span + (u - u_min) orders every one
    of those objects' distinct u the same way (no two distinct u of one share a key); when not, the caller uses
    the reference."""
    out = np.zeros(len(starts))
    for k in keys:
        seg = np.sort(u[starts[k] : starts[k] + n[k]])
        base = k * span
        best = 0.0
        for i in range(1, len(seg)):
            if seg[i] != seg[i - 1] and base + (seg[i] - u_min) == base + (seg[i - 1] - u_min):
                return out, False
            best = max(best, seg[i] - seg[i - 1])
        out[k] = best
    return out, True


# --- statistics after split and merge (sensors/perception._restats) -----------------------------------------

@njit(cache=True)
def take_runs(is_new, where, old_starts, new_starts, n, starts, members0, u0, xy0, z0, rel0, members1, u1, xy1,
              z1, rel1):
    """The packed member rows (members, u, xy, z, rel) of K objects (starts, n (K,)), object k's copied from the
    new arrays (suffix 1) at new_starts[where[k]] when is_new[k], else from the old ones (suffix 0) at
    old_starts[where[k]]."""
    m = 0
    for k in range(len(n)):
        m += n[k]
    members, u, z = np.empty(m, np.int64), np.empty(m), np.empty(m)
    xy, rel = np.empty((m, 2)), np.empty((m, 2))
    for k in range(len(n)):
        o = starts[k]
        if is_new[k]:
            s = new_starts[where[k]]
            for i in range(n[k]):
                members[o + i], u[o + i], z[o + i] = members1[s + i], u1[s + i], z1[s + i]
                xy[o + i, 0], xy[o + i, 1], rel[o + i, 0], rel[o + i, 1] = xy1[s + i, 0], xy1[s + i, 1], rel1[s + i, 0], rel1[s + i, 1]
        else:
            s = old_starts[where[k]]
            for i in range(n[k]):
                members[o + i], u[o + i], z[o + i] = members0[s + i], u0[s + i], z0[s + i]
                xy[o + i, 0], xy[o + i, 1], rel[o + i, 0], rel[o + i, 1] = xy0[s + i, 0], xy0[s + i, 1], rel0[s + i, 0], rel0[s + i, 1]
    return members, u, xy, z, rel


# --- cluster numbering (sensors/clustering.numbered) -----------------------------------------------------------

@njit(cache=True)
def _lex_less(pts, i, j):
    """Whether point pts[i] comes before pts[j] (pts (N, 3)) in lexicographic (x, y, z) order (equal: neither)."""
    for d in range(3):
        if pts[i, d] != pts[j, d]:
            return pts[i, d] < pts[j, d]
    return False


@njit(cache=True)
def first_points(label, rows, pts, k):
    """Per label 0..k-1 of the points pts[rows] (rows (M,) into pts (N, 3)) labelled label (M,) >= 0: its point
    count (k,) and its first point (k,), an index into rows, in lexicographic (x, y, z) order, the earliest of
    equal points (-1 for a label without points): what sensors/clustering.numbered's lexsort of the labels'
    lowest-x points found (perception_reference.numbered_reference)."""
    counts = np.zeros(k, np.int64)
    first = np.full(k, -1, np.int64)
    for i in range(len(label)):
        c = label[i]
        counts[c] += 1
        if first[c] < 0 or _lex_less(pts, rows[i], rows[first[c]]):
            first[c] = i
    return counts, first


# --- objects (sensors/perception._raw_objects) ----------------------------------------------------------------

@njit(cache=True)
def member_keys(candidates, sub, pts):
    """_raw_objects's sort key in two passes: the members (M,) (candidates (C,) whose label sub (C,) is >= 0, in
    order), their key (M,) label * (ptp(x) + 1.0) + (x - min(x)) (x the members' pts (N, 3) x [m]; the same float
    operations as numpy's), and the members per label (L,) (np.bincount of their labels). M >= 1."""
    c_all = len(sub)
    members, label, x = np.empty(c_all, np.int64), np.empty(c_all, np.int64), np.empty(c_all)
    m, n_labels = 0, 0
    x_lo, x_hi = np.inf, -np.inf
    for j in range(c_all):
        if sub[j] >= 0:
            p = candidates[j]
            members[m], label[m], x[m] = p, sub[j], pts[p, 0]
            x_lo, x_hi = min(x_lo, x[m]), max(x_hi, x[m])
            n_labels = max(n_labels, sub[j] + 1)
            m += 1
    span = (x_hi - x_lo) + 1.0
    key = np.empty(m)
    counts = np.zeros(n_labels, np.int64)
    for i in range(m):
        key[i] = label[i] * span + (x[i] - x_lo)
        counts[label[i]] += 1
    return members[:m], key, counts


@njit(cache=True)
def take_if_distinct(key, order, members):
    """members[order] (M,) when the keys (M,) in that order are all distinct (no two consecutive equal), and
    whether they were (else nothing is taken: the caller orders the runs of equal keys)."""
    for i in range(1, len(order)):
        if key[order[i]] == key[order[i - 1]]:
            return members[:0], False
    out = np.empty(len(order), np.int64)
    for i in range(len(order)):
        out[i] = members[order[i]]
    return out, True


@njit(cache=True)
def side_pool(pts, is_ground, road_z, z_lo, z_hi):
    """sensors.perception._SidePool in one pass: the indices (P,) of the points pts (N, 3) [m] that are not
    ground (is_ground (N,)) and whose height above the road z - road_z lies in [z_lo, z_hi] [m], their xy (P, 2)
    [m] and that height (P,) [m] (the same subtraction as numpy's)."""
    n = len(is_ground)
    idx = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        h = pts[i, 2] - road_z
        if not is_ground[i] and h >= z_lo and h <= z_hi:
            idx[m] = i
            m += 1
    xy, z = np.empty((m, 2)), np.empty(m)
    for j in range(m):
        i = idx[j]
        xy[j, 0], xy[j, 1], z[j] = pts[i, 0], pts[i, 1], pts[i, 2] - road_z
    return idx[:m], xy, z


# --- grid clustering (sensors/clustering._grid) ---------------------------------------------------------------

@njit(cache=True)
def candidate_points(pts, is_ground, road_z, max_height):
    """sensors.perception.perceive's clustering input in one pass: the indices (M,) of the points pts (N, 3) [m]
    that are not ground (is_ground (N,) bool) and whose z - road_z <= max_height [m] (np.flatnonzero of that
    mask), and their points (M, 3) (pts[indices])."""
    n = len(is_ground)
    idx = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        if not is_ground[i] and pts[i, 2] - road_z <= max_height:
            idx[m] = i
            m += 1
    cand = np.empty((m, 3))
    for j in range(m):
        i = idx[j]
        cand[j, 0], cand[j, 1], cand[j, 2] = pts[i, 0], pts[i, 1], pts[i, 2]
    return idx[:m], cand


@njit(cache=True)
def grid_clusters(pts, inv, max_cells):
    """sensors/clustering's grid clusters before numbering, in two passes over pts (N, 3) (N >= 1): each point's
    8-connected component (N,) of occupied cells (sensors/grid.bev_cells numbering with 1 / cell = inv, then
    _grid_components), and per component its point count and first point in lexicographic (x, y, z) order
    (first_points with rows = all points). ok False (nothing else computed) when the grid would exceed
    max_cells cells (bev_cells raises then)."""
    n = len(pts)
    ix, iy = np.empty(n, np.int64), np.empty(n, np.int64)
    x_lo = y_lo = np.int64(2**62)
    x_hi = y_hi = -np.int64(2**62)
    for i in range(n):
        a, b = np.int64(np.floor(pts[i, 0] * inv)), np.int64(np.floor(pts[i, 1] * inv))
        ix[i], iy[i] = a, b
        x_lo, x_hi, y_lo, y_hi = min(x_lo, a), max(x_hi, a), min(y_lo, b), max(y_hi, b)
    nx, ny = x_hi - x_lo + 1, y_hi - y_lo + 1
    empty = np.zeros(0, np.int64)
    if nx * ny > max_cells:
        return empty, empty, empty, False
    for i in range(n):
        ix[i] -= x_lo
        iy[i] -= y_lo
    comp = _grid_components(ix, iy, nx, ny)
    k = 0
    for i in range(n):
        k = max(k, comp[i] + 1)
    counts = np.zeros(k, np.int64)
    first = np.full(k, -1, np.int64)
    for i in range(n):
        c = comp[i]
        counts[c] += 1
        if first[c] < 0 or _lex_less(pts, i, first[c]):
            first[c] = i
    return comp, counts, first, True



@njit(cache=True)
def _grid_components(ix, iy, nx, ny):
    """(N,) int64 component of each point's cell (ix, iy (N,) in [0, nx) x [0, ny)) among the occupied cells,
    8-connected: the partition scipy.ndimage.label gives with a 3x3 structure (perception_reference.
    grid_labels_reference), numbered 0.. in the order the points first reach each component (not ndimage's)."""
    node = np.full(nx * ny, -1, np.int32)  # cell -> its node, by first point (int32: half the table to fill)
    cells = np.empty(len(ix), np.int64)
    n_nodes = 0
    for i in range(len(ix)):
        c = ix[i] * ny + iy[i]
        if node[c] < 0:
            node[c] = n_nodes
            cells[n_nodes] = c
            n_nodes += 1
    parent = np.arange(n_nodes)
    for k in range(n_nodes):
        cx, cy = cells[k] // ny, cells[k] % ny
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                x, y = cx + dx, cy + dy
                if (dx or dy) and 0 <= x < nx and 0 <= y < ny and node[x * ny + y] >= 0:
                    a, b = _root_halving(parent, k), _root_halving(parent, node[x * ny + y])
                    if a != b:
                        parent[max(a, b)] = min(a, b)
    comp = np.full(n_nodes, -1, np.int64)
    out = np.empty(len(ix), np.int64)
    n_comp = 0
    for i in range(len(ix)):
        r = _root_halving(parent, node[ix[i] * ny + iy[i]])
        if comp[r] < 0:
            comp[r] = n_comp
            n_comp += 1
        out[i] = comp[r]
    return out
