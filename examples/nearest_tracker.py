"""A user's own tracker in a few lines: nearest neighbour with a constant-velocity alpha-beta filter.

It implements the testbed's tracker protocol (docs/api.md): ``step(frame) -> TrackSet``, fed each scan's
detections (``frame.z`` (M, 2) [m]) in time order. Run it from the command line:

    testbed run cut_in_out --tracker examples/nearest_tracker.py:NearestNeighbour
"""
import numpy as np
from scipy.optimize import linear_sum_assignment

from roadtrack.testbed import TrackSet


class NearestNeighbour:
    gate_m = 3.0  # a detection farther than this from every prediction starts a track
    alpha, beta = 0.5, 0.3  # position and velocity gains of the alpha-beta filter
    confirm_hits, max_misses = 3, 3

    def __init__(self, scenario):
        self.x = np.zeros((0, 4))  # [x, y, vx, vy] per track
        self.ids = np.zeros(0, np.int64)
        self.hits = np.zeros(0, np.int64)
        self.misses = np.zeros(0, np.int64)
        self.next_id = 1

    def step(self, frame):
        x = self.x.copy()
        x[:, :2] += frame.dt * x[:, 2:]  # predict
        z = frame.z
        d = np.linalg.norm(x[:, None, :2] - z[None, :, :], axis=2)
        rows, cols = linear_sum_assignment(np.where(d < self.gate_m, d, 1e6)) if d.size else ([], [])
        pairs = [(r, c) for r, c in zip(rows, cols) if d[r, c] < self.gate_m]
        seen = np.zeros(len(x), bool)
        for r, c in pairs:  # update
            resid = z[c] - x[r, :2]
            x[r, :2] += self.alpha * resid
            if frame.dt > 0:
                x[r, 2:] += self.beta * resid / frame.dt
            seen[r] = True
        self.hits = self.hits + seen
        self.misses = np.where(seen, 0, self.misses + 1)
        new = np.setdiff1d(np.arange(len(z)), [c for _, c in pairs])  # start tracks
        keep = self.misses <= self.max_misses
        self.x = np.vstack([x[keep], np.column_stack([z[new], np.zeros((len(new), 2))])])
        self.ids = np.concatenate([self.ids[keep], self.next_id + np.arange(len(new))])
        self.hits = np.concatenate([self.hits[keep], np.ones(len(new), np.int64)])
        self.misses = np.concatenate([self.misses[keep], np.zeros(len(new), np.int64)])
        self.next_id += len(new)
        status = np.where(self.hits >= self.confirm_hits, "confirmed", "tentative")
        return TrackSet(ids=self.ids, xy=self.x[:, :2], v=self.x[:, 2:], status=status)
