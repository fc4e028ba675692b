"""Road map for the region of interest: lane centre-line samples, their heading and half width.

A production stack with an HD map keeps only clusters on the carriageway (plus a margin for fit errors
and vehicles straddling a lane edge) and uses the lane direction as a heading prior for the box fit.
The map here is the sampled lane centre lines of the scenario's road (samples at most ~1 m apart, so
the nearest sample is within 0.5 m along the lane of the query point's foot).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from roadtrack.sensors import checks, roi_jit


_CURVATURE_BLOCK = 512
"""Centre samples whose curvature `RoadMap.curvature_at` computes together (about 0.5 km of one lane)."""

GRID_CELL_M = 4.0
"""Smallest cell [m] of the grid a RoadMap finds nearest samples with; larger on a map whose samples are sparse over
its bounding box (at most 4 cells per sample: a 10 x 10 km network of 100 k samples gets 16 m cells)."""
_GRID_MARGIN_M = 1e-6
"""A grid look-up stops only when the nearest sample found is this much [m] nearer than every cell left (rounding
of the cell edges is far below it)."""


def centre_grid(centre: np.ndarray) -> tuple:
    """The look-up grid of samples centre (P, 2) [m]: (ox, oy, h, nx, ny, start, items) for roi_jit.grid_nearest:
    square cells of h [m] from the samples' lower-left corner (ox, oy), nx along x by ny along y, cell i * ny + j
    holding the samples items[start[c]:start[c + 1]] (ascending)."""
    lo = centre.min(axis=0)
    span = centre.max(axis=0) - lo
    h = max(GRID_CELL_M, float(np.sqrt(span[0] * span[1] / (4.0 * len(centre)))))
    ij = np.floor((centre - lo) / h).astype(np.int64)  # the kernel's floor((q - o) / h)
    nx, ny = int(ij[:, 0].max()) + 1, int(ij[:, 1].max()) + 1
    cell = ij[:, 0] * ny + ij[:, 1]
    items = np.argsort(cell, kind="stable").astype(np.int64)
    start = np.concatenate([[0], np.cumsum(np.bincount(cell, minlength=nx * ny))]).astype(np.int64)
    return float(lo[0]), float(lo[1]), h, nx, ny, start, items


@dataclass(frozen=True, eq=False)
class RoadMap:
    """P lane centre-line samples (all lanes of all carriageways together).

    centre: (P, 2) float64 sample positions, world frame [m], at most ~1 m apart along each lane.
    heading: (P,) float64 lane direction at each sample [rad] (only its value mod pi is used by the fit).
    half_width: (P,) float64 half the lane width at each sample [m], > 0.
    """

    centre: np.ndarray
    heading: np.ndarray
    half_width: np.ndarray
    _grid: tuple = field(init=False, repr=False)  # `centre_grid`: the nearest-sample look-up
    _tree: list = field(init=False, repr=False)  # [scipy cKDTree of the samples, made when first needed] or []
    _kappa: tuple = field(init=False, repr=False)  # (curvature (P,), known (P,) bool): `curvature_at`'s memory

    def __post_init__(self) -> None:
        centre = checks.float_array("RoadMap.centre", self.centre, (None, 2))
        if len(centre) == 0:
            raise ValueError("RoadMap.centre: expected at least one sample, got 0")
        heading = checks.float_array("RoadMap.heading", self.heading, (len(centre),))
        half_width = checks.float_array("RoadMap.half_width", self.half_width, (len(centre),))
        if np.any(half_width <= 0.0):
            raise ValueError(f"RoadMap.half_width: expected > 0 everywhere, got min {half_width.min()!r}")
        centre = np.ascontiguousarray(centre)  # one layout for the compiled look-up (one numba signature)
        object.__setattr__(self, "centre", centre)
        object.__setattr__(self, "heading", heading)
        object.__setattr__(self, "half_width", half_width)
        object.__setattr__(self, "_grid", centre_grid(centre))
        object.__setattr__(self, "_tree", [])
        object.__setattr__(self, "_kappa", (np.zeros(len(centre)), np.zeros(len(centre), dtype=bool)))

    def nearest(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance (M,) [m] to the nearest centre sample and its index (M,) int64, for xy (M, 2) [m]."""
        q = checks.float_array("xy", xy, (None, 2))
        if len(q) == 0:
            return np.zeros(0), np.zeros(0, np.int64)
        return self._query(q)

    def _query(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`nearest` of finite q (M, 2): compiled (roi_jit.grid_nearest), the samples and distances of scipy's cKDTree
        over the samples bit for bit (tests/test_sensors_roi.py). A point exactly as far from two samples (a lane's
        last sample and the next lane's first, at one position) is the tree's to decide, as it was before the grid:
        which of them it gives depends on how it was built. About 5x faster than the tree for the few points a scan
        asks at a time; on highway_benchmark the loop's 8.7 look-ups a frame took about 1 ms with the tree and
        0.24 ms with the grid."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        dist, k, tie = roi_jit.grid_nearest(q, self.centre, *self._grid, _GRID_MARGIN_M)
        if tie.any():
            if not self._tree:
                self._tree.append(cKDTree(self.centre))
            d_t, k_t = self._tree[0].query(q[tie])
            dist[tie], k[tie] = d_t, k_t
        return dist, k

    def nearest_index(self, q: np.ndarray) -> np.ndarray:
        """Index (M,) int64 of the nearest centre sample to each of q (M, 2) [m], finite float64 (checked by the
        caller): `nearest`'s index."""
        if len(q) == 0:
            return np.zeros(0, np.int64)
        return self._query(q)[1]

    def on_road(self, xy: np.ndarray, margin_m: float) -> np.ndarray:
        """(M,) bool: xy (M, 2) [m] lies within the nearest sample's half width + margin_m [m] of it.

        Between samples s apart the distance to the nearest one is up to sqrt(d^2 + (s/2)^2) for a
        lateral offset d: the lane edge moves in by at most 0.07 m (half width 1.75 m, s = 1 m)."""
        checks.positive("margin_m", margin_m, allow_zero=True)
        dist, k = self.nearest(xy)
        return dist <= self.half_width[k] + margin_m

    @property
    def curvature(self) -> np.ndarray:
        """(P,) signed curvature of the lane at each centre sample [1/m] (> 0: the lane turns left), from the
        heading change to the next sample of the same lane: the sample nearest to 1 m ahead along the heading,
        within 0.5 m of that point and turned by less than 0.5 rad (0 at a lane's end)."""
        return self.curvature_at(np.arange(len(self.centre)))

    def curvature_at(self, k: np.ndarray) -> np.ndarray:
        """`curvature` (K,) [1/m] at the centre samples k (K,) int. Computed a block of _CURVATURE_BLOCK samples at a
        time (a stretch of one lane: the samples are stored lane by lane), each block when first asked for, and
        remembered: a tracker asks a few samples a scan, and the whole map's (112 k samples on highway_benchmark)
        took 80-190 ms."""
        k = np.asarray(k)
        if k.size and (k.dtype.kind not in "iu" or k.min() < 0 or k.max() >= len(self.centre)):
            raise ValueError(f"RoadMap.curvature_at: expected sample indices in [0, {len(self.centre)}), got "
                             f"{k.dtype} {k.min()}..{k.max()}")
        k = k.astype(np.int64, copy=False)
        kappa, known = self._kappa
        if not known[k].all():
            blocks = np.unique(k[~known[k]] // _CURVATURE_BLOCK)
            new = np.concatenate([np.arange(b * _CURVATURE_BLOCK, min((b + 1) * _CURVATURE_BLOCK, len(kappa)))
                                  for b in blocks.tolist()])
            h = self.heading[new]
            t = np.column_stack([np.cos(h), np.sin(h)])
            dist, nxt = self._query(self.centre[new] + t)
            step = np.hypot(*(self.centre[nxt] - self.centre[new]).T)
            turn = np.angle(np.exp(1j * (self.heading[nxt] - h)))
            ok = (dist <= 0.5) & (step >= 0.2) & (np.abs(turn) < 0.5)
            kappa[new] = np.where(ok, turn / np.where(ok, step, 1.0), 0.0)
            known[new] = True
        return kappa[k]

    def lane_frame(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The lane nearest to each of xy (M, 2) [m]: its heading (M,) [rad], the signed offset (M,) [m] of xy
        from its centre line (> 0: left of the lane's direction), its half width (M,) [m] and curvature (M,)
        [1/m], all at the nearest centre sample."""
        q = checks.float_array("xy", xy, (None, 2))
        k = self.nearest_index(q)
        h = self.heading[k]
        d = q - self.centre[k]
        offset = -np.sin(h) * d[:, 0] + np.cos(h) * d[:, 1]
        return h, offset, self.half_width[k], self.curvature_at(k)

    def heading_at(self, xy: np.ndarray) -> np.ndarray:
        """(M,) lane heading [rad] of the nearest centre sample to each of xy (M, 2) [m]."""
        return self.heading[self.nearest_index(checks.float_array("xy", xy, (None, 2)))]
