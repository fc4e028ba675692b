"""Track-to-track stitching (switchable, ``tracker.stitch_s``): a newly confirmed track takes the label of a confirmed
track deleted at most ``window_s`` seconds before, when it lies where that track would be now.

A car whose track was deleted a moment too early (its detections missing for a few scans while the occlusion-aware
P_D still saw it) gets a new track once it is detected again: a relabel, a break-up in the thesis's scores. The
stitcher keeps the last state of each confirmed track deleted within the window; when a track is confirmed, each kept
track is moved to the current time at constant velocity, x' = x + dt v, with its position covariance
P' = F P F^T (F = [[I, dt I], [0, I]]) plus an acceleration term (sigma_a dt^2 / 2)^2 I, and the new track's position
is gated against it: d^2 = e^T (P'_pos + P_new,pos)^-1 e <= ``d2_max`` (chi-square, 2 degrees of freedom). The
nearest kept track within the gate gives its label, once. It is causal (decided at the confirmation, from the
past only) and reported: the run counts the stitches (scores.json ``stitched_tracks``) and marks each in
diagnostics.parquet (quantity ``stitched``, testbed/tracking/builtin.py), so scores with it on can be told from
scores without it.
"""
from __future__ import annotations

import numpy as np

STITCH_D2 = 9.21
"""Gate of a stitch: the 99 % point of the chi-square distribution with 2 degrees of freedom."""
SIGMA_A = 1.0
"""Acceleration std [m/s^2] a deleted track's prediction allows for over the gap (a car at steady speed)."""


class Stitcher:
    """The deleted tracks of the last ``window_s`` seconds and the labels given to the tracks stitched to them.

    ``update`` once per scan with that scan's deleted and newly confirmed tracks; ``label`` maps a tracker's own
    track ids (T,) to the ids reported (a stitched track's is the label of the track it continues)."""

    def __init__(self, window_s: float, d2_max: float = STITCH_D2, sigma_a: float = SIGMA_A):
        if not window_s > 0:
            raise ValueError(f"stitch window: expected > 0 s, got {window_s!r}")
        self.window_s, self.d2_max, self.sigma_a = float(window_s), float(d2_max), float(sigma_a)
        self.alias: dict[int, int] = {}
        self._kept: list[tuple[int, float, np.ndarray, np.ndarray]] = []  # (label, time, kin (4,), cov (4, 4))

    def label(self, ids: np.ndarray) -> np.ndarray:
        """(T,) int64 reported labels of the tracker's track ids (T,)."""
        return np.array([self.alias.get(int(i), int(i)) for i in ids], dtype=np.int64).reshape(len(ids))

    def update(self, time: float, deleted: tuple, new: tuple) -> list[int]:
        """Keep ``deleted`` (ids (D,), kin (D, 4) [x, y, vx, vy], cov (D, 4, 4)): the confirmed tracks deleted at
        ``time`` [s]; stitch ``new`` (ids (N,), kin (N, 4), cov (N, 4, 4)): the tracks confirmed at ``time``.
        Returns the ids of ``new`` that were stitched."""
        self._kept = [k for k in self._kept if time - k[1] <= self.window_s]
        made = []
        for i, x, P in zip(*new):
            best, best_d2 = None, self.d2_max
            for n, (label, t0, x0, P0) in enumerate(self._kept):
                d2 = self._distance2(time - t0, x0, P0, x, P)
                if d2 <= best_d2:
                    best, best_d2 = n, d2
            if best is not None:
                self.alias[int(i)] = self._kept.pop(best)[0]
                made.append(int(i))
        self._kept += [(self.alias.get(int(i), int(i)), float(time), x, P) for i, x, P in zip(*deleted)]
        return made

    def _distance2(self, dt: float, x0: np.ndarray, P0: np.ndarray, x: np.ndarray, P: np.ndarray) -> float:
        """Squared Mahalanobis distance of position x[:2] from x0 moved by dt [s] (module docstring)."""
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        S = (F @ P0 @ F.T)[:2, :2] + P[:2, :2] + (self.sigma_a * dt * dt / 2.0) ** 2 * np.eye(2)
        e = x[:2] - (F @ x0)[:2]
        return float(e @ np.linalg.solve(S, e))
