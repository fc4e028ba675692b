"""Bird's-eye-view cell indices shared by the grid ground segmenter and the grid clusterer."""

from __future__ import annotations

import numpy as np

MAX_CELLS = 1 << 22  # 4 M cells: a 1 km square at 0.5 m


def bev_cells(points: np.ndarray, cell_m: float, what: str) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Cell row ix (N,), column iy (N,) int64 from 0, and the dense grid shape, for (N, 3) points [m].

    The grid starts at the cell holding the smallest x and y, so cells do not depend on point order.
    Raises ValueError when the points span more than MAX_CELLS cells (crop to the sensor range first).
    """
    ix = np.floor(points[:, 0] * (1.0 / cell_m)).astype(np.int64)
    iy = np.floor(points[:, 1] * (1.0 / cell_m)).astype(np.int64)
    ix -= ix.min()
    iy -= iy.min()
    shape = (int(ix.max()) + 1, int(iy.max()) + 1)
    if shape[0] * shape[1] > MAX_CELLS:
        raise ValueError(
            f"points: span {shape[0] * cell_m:.0f} x {shape[1] * cell_m:.0f} m is too large for the {what} grid; "
            "crop to the sensor range first"
        )
    return ix, iy, shape
