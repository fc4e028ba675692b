"""Compiled (numba) kernels of the LiDAR fast path: ray / oriented-box slab intersection over each box's
candidate rays, and the assembly of the kept returns into points, labels and the range image.

Boxes are given by their footprint centre (cx, cy), long-axis unit vector (ux, uy), half length and half
width, bottom and top heights, all in the sensor frame (origin on the road below the sensor, x along the
sensor yaw), float64. They are the exact boxes of the open3d mesh the full cast uses (sensors/lidar.py
`_mesh`), which casts in float32: the two agree up to float32 round-off (~1e-5 m at 70 m), except for rays
grazing a box edge or face within that round-off, which one may count as a hit and the other not.

Installed as roadtrack.sensors.raycast (issue 31.1). numba's cache pickles that module name and recognises this
file by a hash of its text (numba 0.68): code cached under the former top-level name `sensors.raycast` cannot be
loaded ("No module named 'sensors'"), so this paragraph came with the rename: a new text, compiled afresh.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _slab(ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, cx: float, cy: float, ux: float,
          uy: float, hl: float, hw: float, zb: float, zt: float) -> float:
    """Range along the unit ray o + t d to the first surface of the box (the exit face when o is inside
    the box), inf when it misses or the box lies behind."""
    t_near, t_far = -np.inf, np.inf
    rx, ry = ox - cx, oy - cy
    for axis in range(3):
        if axis == 0:  # along the box
            s, d, lo, hi = rx * ux + ry * uy, dx * ux + dy * uy, -hl, hl
        elif axis == 1:  # across it
            s, d, lo, hi = -rx * uy + ry * ux, -dx * uy + dy * ux, -hw, hw
        else:
            s, d, lo, hi = oz, dz, zb, zt
        if d == 0.0:
            if s < lo or s > hi:
                return np.inf
            continue
        t1, t2 = (lo - s) / d, (hi - s) / d
        if t1 > t2:
            t1, t2 = t2, t1
        if t1 > t_near:
            t_near = t1
        if t2 < t_far:
            t_far = t2
        if t_near > t_far:
            return np.inf
    if t_far <= 0.0:
        return np.inf
    return t_near if t_near > 0.0 else t_far


@njit(cache=True)
def cast_boxes(dirs, h, t, which, boxes, active, b0, b1, i0, i1, wrap, every, n_az, n_el):
    """Cast each active box's candidate rays and keep, per ray, the nearest box hit when it is nearer than
    the road hit already in t (a tie, a box bottom lying on the road, is road).

    dirs (R, 3) unit ray directions, sensor frame, R = n_az * n_el azimuth-major; h the sensor height [m].
    t (R,) range to the road per ray (inf: none) and which (R,) int64 (-1), updated in place: the range to
    the hit box and its index. boxes (K, 8) [cx, cy, ux, uy, half length, half width, z bottom, z top];
    active (K',) the boxes to cast; per box the beam range [b0, b1), the azimuth range [i0, i1] plus
    [0, wrap] when wrap >= 0, or every azimuth when `every`.
    """
    n = len(t)
    t_box = np.full(n, np.inf)
    w_box = np.full(n, -1, np.int64)
    for j in range(len(active)):
        k = active[j]
        cx, cy, ux, uy, hl, hw, zb, zt = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3], boxes[k, 4], \
            boxes[k, 5], boxes[k, 6], boxes[k, 7]
        for part in range(2):
            if every[k]:
                if part == 1:
                    break
                a0, a1 = 0, n_az - 1
            elif part == 0:
                a0, a1 = i0[k], i1[k]
            else:
                if wrap[k] < 0:
                    break
                a0, a1 = 0, min(wrap[k], n_az - 1)
            for a in range(a0, a1 + 1):
                for b in range(b0[k], b1[k]):
                    r = a * n_el + b
                    th = _slab(0.0, 0.0, h, dirs[r, 0], dirs[r, 1], dirs[r, 2], cx, cy, ux, uy, hl, hw, zb, zt)
                    if th < t_box[r]:
                        t_box[r] = th
                        w_box[r] = k
    for r in range(n):
        if t_box[r] < t[r] * (1.0 - 1e-6):
            t[r] = t_box[r]
            which[r] = w_box[r]


@njit(cache=True)
def assemble(t, which, u_drop, dropout, noise, min_range, max_range, dirs, yaw_c, yaw_s, x0, y0, z0, box_ids,
             ground):
    """The kept returns of one turn: a ray is kept when it hit something (t finite), survived dropout
    (u_drop >= dropout; u_drop empty = no dropout) and its measured range t + noise (noise empty = none)
    lies in [min_range, max_range].

    Returns ranges (R,) measured range or inf, idx (N,) int64 kept ray indices, points (N, 3) world frame
    (nominal direction dirs (R, 3) times the measured range, rotated by the yaw and shifted by x0, y0, z0),
    source (N,) int64 the hit box's id (box_ids) or `ground`."""
    n = len(t)
    ranges = np.full(n, np.inf)
    has_drop, has_noise = len(u_drop) > 0, len(noise) > 0
    count = 0
    for r in range(n):
        if not np.isfinite(t[r]):
            continue
        if has_drop and u_drop[r] < dropout:
            continue
        m = t[r] + noise[r] if has_noise else t[r]
        if m >= min_range and m <= max_range:
            ranges[r] = m
            count += 1
    idx = np.empty(count, np.int64)
    points = np.empty((count, 3))
    source = np.empty(count, np.int64)
    i = 0
    for r in range(n):
        m = ranges[r]
        if m == np.inf:
            continue
        px, py = dirs[r, 0] * m, dirs[r, 1] * m
        idx[i] = r
        points[i, 0] = px * yaw_c - py * yaw_s + x0
        points[i, 1] = px * yaw_s + py * yaw_c + y0
        points[i, 2] = dirs[r, 2] * m + z0
        source[i] = box_ids[which[r]] if which[r] >= 0 else ground
        i += 1
    return ranges, idx, points, source
