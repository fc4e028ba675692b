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

The speed must be reached over the whole window and also over each of ``parts`` equal parts of it (default
4): a static object's track whose gate has grown while its object was hidden (a few-point bush is detected only
sometimes) can jump a few metres onto the next static object and coast on with the jump's velocity; over the
whole window that looked like 4 m/s, over each quarter it does not (measured on cut_in_out with roadside objects
and the map ROI off: one false track with ``parts = 1`` and the P_D of few-point objects, none with 4).
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
        window, now = self.spec.window_s, float(time)
        for k, (i, (x, y)) in enumerate(zip(ids.tolist(), np.asarray(xy, dtype=np.float64).tolist())):
            hist = self._history.setdefault(i, deque())
            hist.append((now, x, y))
            while len(hist) > 1 and hist[1][0] <= time - window + 1e-9:
                hist.popleft()  # keep the newest sample at least window_s old
            if i not in self._moved and time - hist[0][0] >= window - 1e-9 and self._steady(hist, xy[k]):
                self._moved.add(i)
            out[k] = i in self._moved
        return out

    def _steady(self, hist: deque, xy: np.ndarray) -> bool:
        """The track moved at min_speed_mps over the whole window and over each of its ``parts`` equal parts
        (from hist[0], the newest sample at least window_s old, to hist[-1], at position ``xy``; each part ends at
        the sample nearest its end; a window of fewer scans than parts has one part per scan). A track that jumps
        from one static object to the next one (a low-P_D track whose gate has grown) and coasts on with the jump's
        velocity covers the window's distance in one or two parts only."""
        t = np.array([h[0] for h in hist])
        p = np.array([h[1:] for h in hist])
        p[-1] = xy
        ends = np.linspace(t[0], t[-1], min(self.spec.parts, len(t) - 1) + 1)  # no more parts than scans
        k = np.unique(np.abs(t[None, :] - ends[:, None]).argmin(axis=1))
        step = np.hypot(*np.diff(p[k], axis=0).T)
        v = self.spec.min_speed_mps
        whole = np.hypot(*(p[-1] - p[0])) >= v * (t[-1] - t[0])  # net: a static object's jitter averages out
        return bool(whole and (step >= v * np.diff(t[k]) - 1e-9).all())
