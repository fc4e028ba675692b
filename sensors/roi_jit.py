"""Compiled nearest-sample look-up of sensors.roi.RoadMap: a uniform grid of the lane centre samples."""
from __future__ import annotations

import numpy as np
from numba import njit

_FAR_CELLS = 1e15
"""Cell coordinates are clamped to +-this before the integer conversion (a query light-years away stays defined)."""


@njit(cache=True)
def grid_nearest(q, centre, ox, oy, h, nx, ny, start, items, margin):
    """Distance (M,) [m] and index (M,) int64 of the nearest of centre (P, 2) [m] to each of q (M, 2) [m]
    (C-contiguous float64), and tie (M,) bool: another sample is exactly as near (the index is then the lower one).
    The grid: cells of h [m] from (ox, oy), nx by ny, cell c = i * ny + j holding the samples
    items[start[c]:start[c + 1]]. Rings of cells around each query's cell, from the first that reaches the grid,
    until the nearest sample found lies closer, by margin [m], than any cell outside them (then no other sample is
    as near). The distance is sqrt(dx * dx + dy * dy), as scipy's cKDTree computes it."""
    M = q.shape[0]
    dist = np.empty(M)
    idx = np.empty(M, np.int64)
    tie = np.zeros(M, np.bool_)
    for m in range(M):
        qx, qy = q[m, 0], q[m, 1]
        ci = int(np.floor(min(max((qx - ox) / h, -_FAR_CELLS), _FAR_CELLS)))
        cj = int(np.floor(min(max((qy - oy) / h, -_FAR_CELLS), _FAR_CELLS)))
        best, bi, tied = np.inf, -1, False
        r = max(0, -ci, ci - (nx - 1), -cj, cj - (ny - 1))  # the smaller rings hold no cell of the grid
        while True:
            i_lo, i_hi, j_lo, j_hi = ci - r, ci + r, cj - r, cj + r
            for i in range(max(i_lo, 0), min(i_hi, nx - 1) + 1):
                if i == i_lo or i == i_hi:  # the ring's first and last rows: every cell
                    for j in range(max(j_lo, 0), min(j_hi, ny - 1) + 1):
                        best, bi, tied = _cell_nearest(qx, qy, centre, start, items, i * ny + j, best, bi, tied)
                else:  # the rows between: their two end cells (the inside was searched by the smaller rings)
                    for j in (j_lo, j_hi):
                        if 0 <= j < ny:
                            best, bi, tied = _cell_nearest(qx, qy, centre, start, items, i * ny + j, best, bi, tied)
            if i_lo <= 0 and i_hi >= nx - 1 and j_lo <= 0 and j_hi >= ny - 1:
                break  # the block covers the grid
            # a sample outside the block i_lo..i_hi x j_lo..j_hi is at least its edge's distance away
            edge = min(qx - (ox + i_lo * h), (ox + (i_hi + 1) * h) - qx, qy - (oy + j_lo * h),
                       (oy + (j_hi + 1) * h) - qy)
            if bi >= 0 and np.sqrt(best) < edge - margin:
                break
            r += 1
        dist[m], idx[m], tie[m] = np.sqrt(best), bi, tied
    return dist, idx, tie


@njit(cache=True)
def _cell_nearest(qx, qy, centre, start, items, c, best, bi, tied):
    """(best squared distance, its sample, tie) after the samples of cell c, from those found before."""
    for t in range(start[c], start[c + 1]):
        k = items[t]
        dx, dy = qx - centre[k, 0], qy - centre[k, 1]
        d2 = dx * dx + dy * dy
        if d2 < best or bi < 0:
            best, bi, tied = d2, k, False
        elif d2 == best and k != bi:
            bi, tied = min(bi, k), True
    return best, bi, tied
