"""Compiled (numba) body of sensors/boxfit.fit_vehicle_box: the same steps, statement for statement, without
the per-call cost of dozens of small numpy operations (a fit of a 300-point cluster took ~0.2 ms, mostly
interpreter overhead). Validation, the size prior and the result dataclass stay in boxfit.py.

`fit_many(...)` fits K objects and returns one row of `FIELDS` per object; `params(cfg)` packs a BoxFitConfig
into the float64 array the kernel reads (`P_*` indices). Results equal the former numpy code up to floating-point
summation order (~1e-15 relative).

Installed as roadtrack.sensors.boxfit_jit (issue 31.1). numba's cache pickles that module name and recognises
this file by a hash of its text (numba 0.68): code cached under the former top-level name `sensors.boxfit_jit`
cannot be loaded ("No module named 'sensors'"), so this paragraph came with the rename: a new text, compiled
afresh.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

SHAPE_CODES = ("vehicle", "thin_long", "post", "panel")  # shape code -> boxfit.SHAPES name
FIELDS = ("cx", "cy", "heading", "length", "width", "seen_length", "seen_width", "faces", "completed",
          "r_xx", "r_xy", "r_yy", "shape", "seen_cx", "seen_cy")

(P_STEP, P_COARSE, P_D0, P_MAX_POINTS, P_FACE_TOL, P_MIN_FACE, P_OPEN_NBR, P_AZ_STEP, P_MAX_RANGE, P_GAP_FACTOR,
 P_GAP_TOL, P_RANGE_NOISE, P_FLOOR, P_HEADING_STD, P_FREE_HEADING_STD, P_FEW_POINTS, P_THIN_WIDTH,
 P_THIN_LENGTH, P_THIN_MAX_TOP, P_POST_SIZE, P_POST_MIN_TOP, P_PANEL_GAP, P_PANEL_MIN_TOP, P_PANEL_MAX_TOP,
 P_PANEL_MAX_COVER, P_PANEL_BIN, P_HINT_OVERRIDE) = range(27)
_PARAM_FIELDS = ("step_deg", "coarse_step_deg", "d0_m", "max_points", "face_tol_m", "min_face_m", "open_nbr_deg",
                 "azimuth_step_deg", "max_range_m", "gap_factor", "gap_heading_tol_deg", "range_noise_m",
                 "floor_std_m", "heading_std_deg", "free_heading_std_deg", "few_points", "thin_width_m",
                 "thin_length_m", "thin_max_top_m", "post_size_m", "post_min_top_m", "panel_gap_m",
                 "panel_min_top_m", "panel_max_top_m", "panel_max_cover", "panel_bin_m", "hint_override")


def params(cfg) -> np.ndarray:
    """(27,) float64 the BoxFitConfig fields the kernel reads, in P_* order."""
    return np.array([float(getattr(cfg, name)) for name in _PARAM_FIELDS])


@njit(cache=True)
def _closeness(sx, sy, angles, d0):
    """(E,) closeness score of the points (sx, sy) (m,) for each rectangle orientation angles (E,) [rad]."""
    m, e = len(sx), len(angles)
    out = np.zeros(e)
    du = np.empty(m)
    for j in range(e):
        ca, sa = math.cos(angles[j]), math.sin(angles[j])
        cb, sb = math.cos(angles[j] + math.pi / 2), math.sin(angles[j] + math.pi / 2)
        u_lo, u_hi, v_lo, v_hi = np.inf, -np.inf, np.inf, -np.inf
        for i in range(m):
            u = sx[i] * ca + sy[i] * sa
            v = sx[i] * cb + sy[i] * sb
            u_lo, u_hi = min(u_lo, u), max(u_hi, u)
            v_lo, v_hi = min(v_lo, v), max(v_hi, v)
        total = 0.0
        for i in range(m):
            u = sx[i] * ca + sy[i] * sa
            v = sx[i] * cb + sy[i] * sb
            d = min(min(u_hi - u, u - u_lo), min(v_hi - v, v - v_lo))
            total += 1.0 / max(d, d0)
        out[j] = total
    return out


@njit(cache=True)
def _argmax(a, lo, hi):
    k = lo
    for i in range(lo + 1, hi):
        if a[i] > a[k]:
            k = i
    return k


@njit(cache=True)
def _orientation(lx, ly, has_hint, hint, window, n_inner, refine, free, p):
    """Closeness orientation [rad] (mod pi/2), nan for fewer than 3 points (boxfit._orientation)."""
    n = len(lx)
    if n < 3:
        return np.nan
    max_points = int(p[P_MAX_POINTS])
    if n <= max_points:
        sx, sy = lx, ly
    else:
        step = -(-n // max_points)
        sx, sy = lx[::step].copy(), ly[::step].copy()
    fine = math.radians(p[P_STEP])
    if has_hint:
        grid = hint + window
        score = _closeness(sx, sy, grid, p[P_D0])
        k = _argmax(score, 0, n_inner)
        if len(grid) > n_inner:
            k_out = _argmax(score, n_inner, len(grid))
            if score[k_out] >= p[P_HINT_OVERRIDE] * score[k]:  # clearly turned: refine around the coarse winner
                grid = grid[k_out] + refine
                score = _closeness(sx, sy, grid, p[P_D0])
                k = _argmax(score, 0, len(grid))
    else:
        s_free = _closeness(sx, sy, free, p[P_D0])
        grid = free[_argmax(s_free, 0, len(free))] + refine
        score = _closeness(sx, sy, grid, p[P_D0])
        k = _argmax(score, 0, len(grid))
    if not score[k] > 0.0 or not np.isfinite(score[k]):
        return np.nan
    theta = grid[k]
    if 0 < k < len(grid) - 1 and abs(grid[k + 1] - grid[k - 1] - 2 * fine) < 1e-9:  # parabola through the peak
        a, b, c = score[k - 1], score[k], score[k + 1]
        if a - 2 * b + c < 0:
            theta += fine * min(max(0.5 * (a - c) / (a - 2 * b + c), -0.5), 0.5)
    return theta


@njit(cache=True)
def _project(lx, ly, theta):
    """Coordinates along theta and across it (u, v) (n,) of the points (lx, ly), and their extents."""
    c, s = math.cos(theta), math.sin(theta)
    n = len(lx)
    u, v = np.empty(n), np.empty(n)
    for i in range(n):
        u[i] = lx[i] * c + ly[i] * s
        v[i] = -lx[i] * s + ly[i] * c
    return u, v, u.min(), u.max(), v.min(), v.max()


@njit(cache=True)
def _remainder(x, y):
    """IEEE remainder of x / y (math.remainder)."""
    return x - y * np.rint(x / y)


@njit(cache=True)
def _face_direction(lx, ly, on, nominal, p):
    """boxfit._face_direction of the points (lx, ly)[on]."""
    m = 0
    mx = my = 0.0
    for i in range(len(lx)):
        if on[i]:
            m += 1
            mx += lx[i]
            my += ly[i]
    if m < 3:
        return 0.0
    mx /= m
    my /= m
    cxx = cyy = cxy = 0.0
    for i in range(len(lx)):
        if on[i]:
            dx, dy = lx[i] - mx, ly[i] - my
            cxx += dx * dx
            cyy += dy * dy
            cxy += dx * dy
    spread = (cxx + cyy) / m
    if spread < (p[P_MIN_FACE] / 2) ** 2 / 3:
        return 0.0
    direction = 0.5 * math.atan2(2.0 * cxy, cxx - cyy)
    delta = _remainder(direction - nominal, math.pi)
    return delta if abs(delta) <= 2 * math.radians(p[P_COARSE]) else 0.0


@njit(cache=True)
def _spacing(d2, h, daz, tilt, max_range):
    d = math.sqrt(d2)
    h -= d * tilt
    if h <= 0.0:
        return np.inf
    g = d2 * daz / h
    return g if d + g < max_range else np.inf


@njit(cache=True)
def _complete(lo, hi, g_lo, g_hi, size, size_std):
    seen = hi - lo
    room = g_lo + g_hi
    full = min(max(seen, size), seen + room)
    extra = full - seen
    e_lo = min(max(extra / 2, extra - g_hi), g_lo)
    bounded = full < size or seen >= size
    sd = min(size_std, room / math.sqrt(12.0)) if bounded else size_std
    split = min(g_lo, min(g_hi, extra))
    return lo - e_lo, hi + (extra - e_lo), sd, split


@njit(cache=True)
def _complete_seen(lo, hi, g_lo, g_hi, s_lo, s_hi, size, size_std, min_size):
    """_complete along the axis of a class whose length varies widely (trucks, 7.5-18.75 m): when both ends
    are bounded (g_lo, g_hi finite: one faces the sensor, the other is reached along a seen side) each
    lies half its ray spacing s_lo, s_hi beyond the points (uniform within one spacing: var s^2 / 12), but
    the size is at least min_size (less means the side is hidden: the class's shortest, std size_std); an
    end nothing bounds takes the class's size as _complete does."""
    if math.isinf(g_lo) or math.isinf(g_hi):
        return _complete(lo, hi, g_lo, g_hi, size, size_std)
    e_lo, e_hi = min(0.5 * s_lo, g_lo), min(0.5 * s_hi, g_hi)
    short = min_size - (hi - lo + e_lo + e_hi)
    if short <= 0.0:
        return lo - e_lo, hi + e_hi, math.sqrt((s_lo * s_lo + s_hi * s_hi) / 12.0), 0.0
    if g_lo > 0.0 and g_hi > 0.0:  # seen from beside: the hidden length goes to both ends
        e_lo, e_hi = e_lo + 0.5 * short, e_hi + 0.5 * short
    elif g_lo > 0.0:
        e_lo += short
    else:
        e_hi += short
    return lo - e_lo, hi + e_hi, size_std, 0.0


@njit(cache=True)
def _shape(u, v, ext, z, has_z, top, footprint, p):
    """boxfit._shape as a SHAPE_CODES index."""
    u_lo, u_hi, v_lo, v_hi = ext[0], ext[1], ext[2], ext[3]
    length, width = max(u_hi - u_lo, v_hi - v_lo), min(u_hi - u_lo, v_hi - v_lo)
    if footprint and width < p[P_THIN_WIDTH] and length > p[P_THIN_LENGTH] and top < p[P_THIN_MAX_TOP]:
        return 1
    if footprint and length < p[P_POST_SIZE] and top >= p[P_POST_MIN_TOP]:
        return 2
    if has_z and p[P_PANEL_MIN_TOP] <= top < p[P_PANEL_MAX_TOP]:
        along, lo = (u, u_lo) if u_hi - u_lo >= v_hi - v_lo else (v, v_lo)
        n = len(u)
        bins = np.empty(n, np.int64)
        for i in range(n):
            bins[i] = np.int64((along[i] - lo) / p[P_PANEL_BIN])
        nb = bins.max() + 1
        high, low = np.zeros(nb, np.bool_), np.zeros(nb, np.bool_)
        for i in range(n):
            if z[i] < p[P_PANEL_GAP]:
                low[bins[i]] = True
            else:
                high[bins[i]] = True
        n_high = covered = 0
        for b in range(nb):
            if high[b]:
                n_high += 1
                covered += low[b]
        if n_high > 0 and covered / n_high <= p[P_PANEL_MAX_COVER]:
            return 3
    return 0


@njit(cache=True)
def _ptp_where(a, mask):
    lo, hi = np.inf, -np.inf
    for i in range(len(a)):
        if mask[i]:
            lo, hi = min(lo, a[i]), max(hi, a[i])
    return hi - lo


@njit(cache=True)
def _open_edges(u, v, us, vs, ext, end, side, open0, open1, p):
    """(4,) bool: the extents [u0, u1, v0, v1] cut by an occluded azimuth edge (boxfit._open_azimuth_edges)."""
    n = len(u)
    az = np.empty(n)
    two_pi = 2 * math.pi
    a0 = math.atan2(v[0] - vs, u[0] - us)
    for i in range(n):
        x = math.atan2(v[i] - vs, u[i] - us) - a0 + math.pi
        r = np.fmod(x, two_pi)
        if r != 0.0 and r < 0.0:
            r += two_pi
        az[i] = r
    tol = p[P_FACE_TOL]
    cut = np.zeros(4, np.bool_)
    for which in range(2):
        if which == 0:
            sign, is_open, q = -1.0, open0, np.argmin(az)
        else:
            sign, is_open, q = 1.0, open1, np.argmax(az)
        if not is_open:
            continue
        up, vp = u[q], v[q]
        on_side = side >= 0 and abs(vp - ext[side]) <= tol
        on_end = end >= 0 and abs(up - ext[end]) <= tol
        along_u = along_v = True
        if on_side != on_end:
            along_u, along_v = on_side, on_end
        else:
            nbr = np.abs(az - az[q]) <= math.radians(p[P_OPEN_NBR])
            spread_u, spread_v = _ptp_where(u, nbr), _ptp_where(v, nbr)
            if max(spread_u, spread_v) > tol:
                along_u, along_v = spread_u >= spread_v, spread_v > spread_u
        t_u, t_v = -sign * (vp - vs), sign * (up - us)
        if along_u:
            cut[1 if t_u > 0 else 0] = True
        if along_v:
            cut[3 if t_v > 0 else 2] = True
    return cut


@njit(cache=True)
def _long_axis_frame(lx, ly, rx, ry, prior, has_hint, hint, window, n_inner, refine, free, p):
    """Heading of the box's long axis and the points in its frame: (heading, u (n,), v (n,), u0, u1, v0, v1),
    u along the heading, v across, (u0, u1, v0, v1) the points' extent (boxfit._orientation,
    _dominant_face, _face_direction, _long_axis)."""
    n = lx.shape[0]
    tol = p[P_FACE_TOL]
    theta = _orientation(lx, ly, has_hint, hint, window, n_inner, refine, free, p)
    if np.isnan(theta):  # fewer than 3 points: the hint, else along the line of sight
        heading = hint if has_hint else math.atan2(-ry, -rx)
        u, v, u0, u1, v0, v1 = _project(lx, ly, heading)
    else:
        u, v, u0, u1, v0, v1 = _project(lx, ly, theta)
        # the edge of the points' box holding most points (boxfit._dominant_face)
        n_lo0 = n_lo1 = n_hi0 = n_hi1 = 0
        for i in range(n):
            n_lo0 += u[i] - u0 <= tol
            n_lo1 += v[i] - v0 <= tol
            n_hi0 += u1 - u[i] <= tol
            n_hi1 += v1 - v[i] <= tol
        k = 0 if n_lo0 >= n_lo1 else 1
        n_lo_k = n_lo0 if k == 0 else n_lo1
        on = np.empty(n, np.bool_)
        if max(n_hi0, n_hi1) > n_lo_k:
            axis = 0 if n_hi0 >= n_hi1 else 1
            for i in range(n):
                on[i] = (u1 - u[i] <= tol) if axis == 0 else (v1 - v[i] <= tol)
        else:
            axis = k
            for i in range(n):
                on[i] = (u[i] - u0 <= tol) if axis == 0 else (v[i] - v0 <= tol)
        delta = _face_direction(lx, ly, on, theta + (math.pi / 2 if axis == 0 else 0.0), p)
        if delta != 0.0:  # the closeness heading, refined by a line fit to the face holding most points
            theta += delta
            u, v, u0, u1, v0, v1 = _project(lx, ly, theta)
        # the long axis (boxfit._long_axis)
        ext_a, ext_b = u1 - u0, v1 - v0
        if has_hint:
            along_a = abs(math.cos(theta - hint)) >= abs(math.sin(theta - hint))
            along, across = (ext_a, ext_b) if along_a else (ext_b, ext_a)
            turned = across > prior[1] + 1.0 and across > along
            heading = theta if along_a != turned else theta + math.pi / 2
        else:
            face = v if axis == 0 else u
            f_lo, f_hi = np.inf, -np.inf
            count = 0
            for i in range(n):
                if on[i]:
                    count += 1
                    f_lo, f_hi = min(f_lo, face[i]), max(f_hi, face[i])
            is_side = count > 0 and f_hi - f_lo > prior[1] + 3 * prior[3] + 0.1
            heading = theta if (axis == 1) == is_side else theta + math.pi / 2
        if heading != theta:  # the long axis is theta + 90 deg: (u, v) -> (v, -u)
            u, v = v, -u
            u0, u1, v0, v1 = v0, v1, -u1, -u0
    return heading, u, v, u0, u1, v0, v1


@njit(cache=True)
def _edge_gaps(us, vs, ext, end, side, cut, daz, tilt, max_range):
    """(4,) how far each edge (u0, u1, v0, v1) of the points' box may lie from the real one: 0 facing the
    sensor, the ray spacing along a seen face (azimuth step daz [rad], heading tolerance tan tilt), inf
    where nothing bounds it or an occluder cuts it."""
    gaps = np.full(4, np.inf)
    for i in range(2):
        if i == end:
            gaps[i] = 0.0
        elif side >= 0:
            h = abs(vs - ext[side])
            gaps[i] = _spacing((ext[i] - us) ** 2 + h * h, h, daz, tilt, max_range)
        if 2 + i == side:
            gaps[2 + i] = 0.0
        elif end >= 0:
            h = abs(us - ext[end])
            gaps[2 + i] = _spacing((ext[2 + i] - vs) ** 2 + h * h, h, daz, tilt, max_range)
    for i in range(4):
        if cut[i]:
            gaps[i] = np.inf
    return gaps


@njit(cache=True)
def _seen_faces(u, v, ext, end, side, tol, min_face):
    """Faces seen (boxfit._faces): of the end (0/1) and side (2/3) facing the sensor (-1: none), those whose
    points span at least min_face [m]."""
    faces = 0
    if end >= 0:
        faces += _ptp_where(v, np.abs(u - ext[end]) <= tol) >= min_face
    if side >= 0:
        faces += _ptp_where(u, np.abs(v - ext[side]) <= tol) >= min_face
    return faces


@njit(cache=True)
def _fit(xy, sensor, top, prior, has_hint, hint, open0, open1, z, has_z, window, n_inner, refine, free, p):
    """boxfit.fit_vehicle_box on validated inputs: xy (n >= 1, 2), sensor (2,), prior (5,) the size prior's
    (length, width, length std, width std, min length; 0: the length is the prior's where the points allow);
    z (n,) when has_z. Returns the FIELDS tuple."""
    n = xy.shape[0]
    ox, oy = 0.0, 0.0
    for i in range(n):
        ox += xy[i, 0]
        oy += xy[i, 1]
    ox /= n
    oy /= n
    lx, ly = xy[:, 0] - ox, xy[:, 1] - oy
    rx, ry = sensor[0] - ox, sensor[1] - oy
    tol = p[P_FACE_TOL]
    heading, u, v, u0, u1, v0, v1 = _long_axis_frame(lx, ly, rx, ry, prior, has_hint, hint, window, n_inner, refine,
                                                     free, p)
    c, s = math.cos(heading), math.sin(heading)
    us, vs = c * rx + s * ry, -s * rx + c * ry
    ext = np.array([u0, u1, v0, v1])
    shape = _shape(u, v, ext, z, has_z, top, not (open0 or open1), p)

    end = 0 if us < u0 else 1 if us > u1 else -1
    side = 2 if vs < v0 else 3 if vs > v1 else -1
    faces = _seen_faces(u, v, ext, end, side, tol, p[P_MIN_FACE])
    if open0 or open1:
        cut = _open_edges(u, v, us, vs, ext, end, side, open0, open1, p)
    else:
        cut = np.zeros(4, np.bool_)
    if end >= 0 and cut[end]:  # an occluder's edge, not the object's
        end = -1
    if side >= 0 and cut[side]:
        side = -1
    daz = math.radians(p[P_AZ_STEP])
    gaps = _edge_gaps(us, vs, ext, end, side, cut, daz * p[P_GAP_FACTOR], math.tan(math.radians(p[P_GAP_TOL])),
                      p[P_MAX_RANGE])  # boxfit._gaps
    if shape == 0:
        size_l, size_w, std_l, std_w = prior[0], prior[1], prior[2], prior[3]
    else:  # not completed: the box of the points, only the sampling gaps as uncertainty
        size_l = size_w = std_l = std_w = 0.0
    if shape == 0 and prior[4] > 0.0:  # a class of widely varying length (trucks): the length from what is seen
        spacing = _edge_gaps(us, vs, ext, end, side, cut, daz, 0.0, np.inf)  # the ray spacing itself
        cu0, cu1, sd_u, sp_u = _complete_seen(u0, u1, gaps[0], gaps[1], spacing[0], spacing[1], size_l, std_l,
                                              prior[4])
    else:
        cu0, cu1, sd_u, sp_u = _complete(u0, u1, gaps[0], gaps[1], size_l, std_l)
    cv0, cv1, sd_v, sp_v = _complete(v0, v1, gaps[2], gaps[3], size_w, std_w)
    mu, mv = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
    du, dv = 0.5 * (cu0 + cu1) - mu, 0.5 * (cv0 + cv1) - mv  # completion offset, box frame
    scx, scy = ox + (c * mu - s * mv), oy + (s * mu + c * mv)
    cx, cy = scx + (c * du - s * dv), scy + (s * du + c * dv)
    length, width, hdg = cu1 - cu0, cv1 - cv0, heading
    if width > length:  # keep length >= width (only for odd, wide clusters)
        length, width, hdg = width, length, heading + math.pi / 2
    # covariance (boxfit._covariance)
    base = p[P_FLOOR] ** 2 + p[P_RANGE_NOISE] ** 2
    var_u = base + sd_u ** 2 / 4 + sp_u ** 2 / 12
    var_v = base + sd_v ** 2 / 4 + sp_v ** 2 / 12
    sig = math.radians(p[P_HEADING_STD] if has_hint else p[P_FREE_HEADING_STD])
    sig2 = sig * sig * max(1.0, p[P_FEW_POINTS] / max(n, 1))
    a, b, d = var_u + sig2 * dv * dv, -sig2 * du * dv, var_v + sig2 * du * du
    xx = c * c * a - 2 * c * s * b + s * s * d
    yy = s * s * a + 2 * c * s * b + c * c * d
    xy_ = c * s * (a - d) + (c * c - s * s) * b
    ref = hint if has_hint else 0.0
    wrapped = ref + np.fmod(np.fmod(hdg - ref + math.pi / 2, math.pi) + math.pi, math.pi) - math.pi / 2
    return (cx, cy, wrapped, length, width, u1 - u0, v1 - v0, faces, math.hypot(du, dv) > 0.05,
            xx, xy_, yy, shape, scx, scy)


@njit(cache=True)
def fit_many(xy, z, starts, n, sensor, tops, priors, has_hint, hints, open0, open1, has_z, window, n_inner, refine,
             free, p):
    """`_fit` of each of K objects, packed: object k's points xy[starts[k] : starts[k] + n[k]] (sum n, 2), heights
    z (same rows, when has_z), tops (K,), priors (K, 5), hints (K,), open0, open1 (K,) bool. Returns (K, 15)
    float64, one row of FIELDS per object (faces, completed and shape as numbers)."""
    out = np.empty((len(starts), 15))
    for k in range(len(starts)):
        s0, s1 = starts[k], starts[k] + n[k]
        r = _fit(xy[s0:s1], sensor, tops[k], priors[k], has_hint, hints[k], open0[k], open1[k],
                z[s0:s1] if has_z else z, has_z, window, n_inner, refine, free, p)
        cx, cy, heading, length, width, seen_l, seen_w, faces, completed, rxx, rxy, ryy, shape, scx, scy = r
        out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4] = cx, cy, heading, length, width
        out[k, 5], out[k, 6], out[k, 7], out[k, 8], out[k, 9] = seen_l, seen_w, faces, completed, rxx
        out[k, 10], out[k, 11], out[k, 12], out[k, 13], out[k, 14] = rxy, ryy, shape, scx, scy
    return out


@njit(cache=True)
def _robust_turn(x, y, a, b, q, thr2):
    """+1 / -1 when a, b, q turn counter-clockwise / clockwise with q farther than sqrt(thr2) [m] from the line
    a-b, 0 within it (or when a and b coincide)."""
    bx, by = x[b] - x[a], y[b] - y[a]
    cross = bx * (y[q] - y[a]) - by * (x[q] - x[a])
    if cross * cross <= thr2 * (bx * bx + by * by):
        return 0
    return 1 if cross > 0.0 else -1


@njit(cache=True)
def convex_hull(xy, tol):
    """(h,) int64 the convex-hull vertices of the points xy (n, 2), counter-clockwise: scipy's
    ConvexHull(xy).vertices for 2-D up to its first vertex (Andrew's monotone chain). Empty when a decision lies
    within tol * (the largest |coordinate|) of collinear, where qhull's own rounding may decide otherwise (so the
    caller asks qhull), or when there are fewer than 3 distinct points. Repeated points count once."""
    n = xy.shape[0]
    x, y = xy[:, 0].copy(), xy[:, 1].copy()
    order = np.arange(n)
    for i in range(1, n):
        if x[i] < x[i - 1] or (x[i] == x[i - 1] and y[i] < y[i - 1]):
            order = np.argsort(x, kind="mergesort")
            for j in range(1, n):  # equal x: by y (insertion into the sorted run)
                q, r = order[j], j
                while r > 0 and x[order[r - 1]] == x[q] and y[order[r - 1]] > y[q]:
                    order[r] = order[r - 1]
                    r -= 1
                order[r] = q
            break
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(x[i]), abs(y[i]))
    thr2 = (tol * scale) ** 2
    h = np.empty(2 * n + 1, np.int64)
    k = 0
    for step in range(2):  # lower chain left to right, then upper chain back
        floor = 2 if step == 0 else k + 1
        for j in range(n) if step == 0 else range(n - 2, -1, -1):
            q = order[j]
            if k > 0 and x[h[k - 1]] == x[q] and y[h[k - 1]] == y[q]:
                continue  # a repeated point
            while k >= floor:
                turn = _robust_turn(x, y, h[k - 2], h[k - 1], q, thr2)
                if turn == 0:
                    return np.zeros(0, np.int64)
                if turn > 0:
                    break
                k -= 1
            h[k] = q
            k += 1
    k -= 1  # the first point closes the upper chain
    if k < 3:
        return np.zeros(0, np.int64)
    for i in range(k):  # every corner, the two extreme points' too, robustly convex
        if _robust_turn(x, y, h[i - 1 if i > 0 else k - 1], h[i], h[(i + 1) % k], thr2) <= 0:
            return np.zeros(0, np.int64)
    return h[:k].copy()
