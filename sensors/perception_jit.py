"""Compiled (numba) per-object loops of sensors/perception.py and sensors/ground.py.

Each kernel computes what the former numpy code computed, bit for bit: sums follow numpy's pairwise
summation (the order `np.add.reduceat` adds in, `_reduceat_add`), products and differences are the same
float64 operations, and trigonometry stays in numpy (the callers pass cos/sin arrays). Objects are packed:
`starts` (K,) and `n` (K,) index the members' rows of the (sum n, ...) arrays, object by object.
"""

from __future__ import annotations

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
    per member: xy (sum n, 2) and rel = xy - its object's centroid (sum n, 2). pts (N, 3) [m]."""
    k_all, m = len(starts), len(members)
    xy = np.empty((m, 2))
    x, y = np.empty(m), np.empty(m)
    top = np.empty(k_all)
    lo, hi = np.empty((k_all, 2)), np.empty((k_all, 2))
    d_min = np.empty(k_all)
    for k in range(k_all):
        s0 = starts[k]
        t, xl, xh, yl, yh, d = -np.inf, np.inf, -np.inf, np.inf, -np.inf, np.inf
        for i in range(s0, s0 + n[k]):
            p = members[i]
            px, py, pz = pts[p, 0], pts[p, 1], pts[p, 2]
            xy[i, 0], xy[i, 1] = px, py
            x[i], y[i] = px, py
            t = max(t, pz)
            xl, xh, yl, yh = min(xl, px), max(xh, px), min(yl, py), max(yh, py)
            d = min(d, np.hypot(px - sx, py - sy))
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
            _reduceat_add(xy_, starts, n), d_min, xy, rel)


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
def along(rel, cx, cy, starts, n):
    """u (sum n,) each member's coordinate rel along its object's (cx, cy) (K,), and (K,) its extent."""
    u = np.empty(len(rel))
    out = np.empty(len(starts))
    for k in range(len(starts)):
        w_lo, w_hi = np.inf, -np.inf
        for i in range(starts[k], starts[k] + n[k]):
            w = rel[i, 0] * cx[k] + rel[i, 1] * cy[k]
            u[i] = w
            w_lo, w_hi = min(w_lo, w), max(w_hi, w)
        out[k] = w_hi - w_lo
    return u, out


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
def cell_lowest(pts, z, inv, fx0, fy0, ny, size):
    """(size,) the lowest z (N,) in each BEV cell (floor(x inv) - fx0) * ny + floor(y inv) - fy0 of the points
    (N, 3) (sensors/grid.bev_cells numbering), inf where empty."""
    out = np.full(size, np.inf)
    for i in range(len(z)):
        c = np.int64(np.floor(pts[i, 0] * inv) - fx0) * ny + np.int64(np.floor(pts[i, 1] * inv) - fy0)
        if z[i] < out[c]:
            out[c] = z[i]
    return out


@njit(cache=True)
def road_band(x, y, z, a, b, c, with_range, road_tol, range_term, tan_angle, height_tol, foot_cell, foot_lo,
              foot_hi, foot_keep):
    """sensors/ground._road_plane's labels: (N,) bool, a point at most its band above the plane z = a x + b y + c
    (x, y, z (N,) relative to the sensor), minus the band's upper part at an object foot.

    with_range: band = min(road_tol + range_term / max(r, 1e-9) + r tan_angle, height_tol) at the range r,
    else height_tol. foot_cell > 0: a point with height above the plane in (foot_keep band, band] sharing a
    foot_cell cell with one in (band + foot_lo, band + foot_hi] is not road."""
    n = len(z)
    is_ground = np.empty(n, np.bool_)
    test = np.empty(n, np.bool_)
    above = np.empty(n, np.bool_)
    n_above = 0
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
        test[i] = g and res > foot_keep * tol
        above[i] = res > tol + foot_lo and res <= tol + foot_hi
        n_above += above[i]
    if foot_cell <= 0.0 or n_above == 0:
        return is_ground
    inv = 1.0 / foot_cell
    keys = np.empty(n_above, np.int64)
    j = 0
    for i in range(n):
        if above[i]:
            keys[j] = _foot_key(x[i], y[i], inv)
            j += 1
    keys.sort()
    for i in range(n):
        if test[i]:
            q = _foot_key(x[i], y[i], inv)
            at = np.searchsorted(keys, q)
            if at < n_above and keys[at] == q:
                is_ground[i] = False
    return is_ground


@njit(cache=True)
def _foot_key(x, y, inv):
    """One int64 per (floor(x inv), floor(y inv)) cell (distinct cells, distinct keys, within +-2^31 cells)."""
    return np.int64(np.floor(x * inv)) * 4294967296 + np.int64(np.floor(y * inv))
