"""Moving-object test at track level: report a track as a vehicle only once it has been seen to move.

Production stacks without a map keep static objects (bushes, signs, tree crowns) out of the object list
this way: a track's ground speed over a window, the distance its position estimate moved in the last
``window_s`` seconds divided by that time, must reach ``min_speed_mps`` once; from then on the track is
reported for the rest of its life (a car that stops in a jam stays a car). Until then it is withheld as
"static": still tracked, so it keeps absorbing the detections of its object, but not reported and not
scored.

Positions are in the world frame (the tracker's frame), so the ego motion does not enter. The net
displacement is used, not the filter's velocity estimate: a new track's velocity carries the two-point
initial guess and reaches 10-18 m/s on a bush for a few scans (measured on a roadside-heavy road), while the
position of a static object's track wanders by well under a metre as the sensor passes it.
"""
from __future__ import annotations

from collections import deque
import numpy as np

from ..scenario.moving import MovingTestSpec


class MovingTest:
    """Per-track state of the moving-object test; call :meth:`update` once per frame with every live track."""

    def __init__(self, spec: MovingTestSpec):
        self.spec = spec
        self._history: dict[int, deque] = {}  # id -> (time, x, y) within the window
        self._moved: set[int] = set()

    def update(self, ids: np.ndarray, xy: np.ndarray, time: float) -> np.ndarray:
        """ids (T,) int64 live track ids; xy (T, 2) their position estimates [m]; time [s].
        Returns (T,) bool: the track has moved (is reported). Tracks absent from ``ids`` are forgotten."""
        ids = np.asarray(ids, dtype=np.int64)
        if not self.spec.enabled:
            return np.ones(len(ids), dtype=bool)
        live = set(ids.tolist())
        for gone in set(self._history) - live:
            del self._history[gone]
            self._moved.discard(gone)
        out = np.zeros(len(ids), dtype=bool)
        window = self.spec.window_s
        for k, i in enumerate(ids.tolist()):
            hist = self._history.setdefault(i, deque())
            hist.append((float(time), float(xy[k, 0]), float(xy[k, 1])))
            while len(hist) > 1 and hist[1][0] <= time - window + 1e-9:
                hist.popleft()  # keep the newest sample at least window_s old
            t0, x0, y0 = hist[0]
            if i not in self._moved and time - t0 >= window - 1e-9:
                if np.hypot(xy[k, 0] - x0, xy[k, 1] - y0) >= self.spec.min_speed_mps * (time - t0):
                    self._moved.add(i)
            out[k] = i in self._moved
        return out
