"""The built-in trackers (``trackers.make_tracker``: any filter with any associator) behind the tracker protocol.

``BuiltinTracker`` keeps the tracks, the next label and which tracks follow trucks between scans, feeds the
occlusion-aware P_D (a truck-sized box for the tracks whose last detection, or the one they were started on, was
truck-long) and reports the
non-candidate tracks with their gates, boundary layers and diagnostics for the recording.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from roadtrack import trackers
from roadtrack.trackers.association.jpda import FALLBACK_DIAGNOSTIC, fallback_clusters

from .protocol import Frame, TrackSet
from .stitch import Stitcher

TRUCK_MIN_LENGTH_M = 7.0
"""A detection longer than this [m] is a truck's (the box fit's truck boxes are at least 7.5 m long)."""


def truck_tracks(ids: np.ndarray, W: np.ndarray, lengths: np.ndarray, known: dict[int, bool]) -> dict[int, bool]:
    """``known`` (track id -> truck) updated from one step: a track whose association weight W (T, M) on one
    detection exceeds 1/2 takes that detection's class (``lengths`` (M,) [m] > :data:`TRUCK_MIN_LENGTH_M`)."""
    out = dict(known)
    if W.size:
        best = np.argmax(W, axis=1)
        for t in np.flatnonzero(W[np.arange(len(ids)), best] > 0.5):
            out[int(ids[t])] = bool(lengths[best[t]] > TRUCK_MIN_LENGTH_M)
    return out


BORN_ON_M = 1e-6
"""A new track lies this close [m] to the detection it was started from (its position is that measurement's)."""


def born_trucks(ids: np.ndarray, xy: np.ndarray, Z: np.ndarray, lengths: np.ndarray) -> dict[int, bool]:
    """Track id -> truck for new tracks ``ids`` (B,) at positions ``xy`` (B, 2) [m]: the class of the detection of
    ``Z`` (M, 2) [m] it was started on (within :data:`BORN_ON_M`; ``lengths`` (M,) [m] > :data:`TRUCK_MIN_LENGTH_M`).
    A track is born a truck's so that its P_D is a truck box's from its first scan: with a car box a truck's own
    rear face hides its centre, its P_D is 0, its detections get no weight and it never learns its class from
    them (the oncoming trucks dense_motorway never confirmed)."""
    if not len(ids) or not len(Z):
        return {}
    d2 = ((xy[:, None, :2] - Z[None, :, :2]) ** 2).sum(axis=2)
    j = np.argmin(d2, axis=1)
    on = d2[np.arange(len(ids)), j] <= BORN_ON_M**2
    return {int(i): bool(lengths[k] > TRUCK_MIN_LENGTH_M) for i, k, o in zip(ids, j, on) if o}


class BuiltinTracker:
    """A ``trackers.Tracker`` as a protocol tracker. ``tracker``: the built tracker (``trackers.make_tracker``);
    ``tracks``: the live tracks after the last step (candidates included), ``next_id`` the next label."""

    def __init__(self, tracker: trackers.Tracker, stitch_s: float = 0.0):
        self.tracker = tracker
        self.name = tracker.name
        self.tracks: tuple = ()
        self.next_id = 1
        self._trucks: dict[int, bool] = {}
        self.stitcher = Stitcher(stitch_s) if stitch_s > 0 else None  # track-to-track stitching (stitch.py)
        self._confirmed: set[int] = set()

    def step(self, frame: Frame) -> TrackSet:
        trk = self.tracker
        pd = None
        if frame.pd is not None:
            live = np.array([self._trucks.get(t.id, False) for t in self.tracks if not t.candidate], dtype=bool)
            nominal, occ = trk.association.pd, frame.pd
            pd = lambda z_hat: occ(z_hat[:, :2], nominal, live)  # noqa: E731 - the tracker calls it once
        first_new = self.next_id
        res = trk.step(self.tracks, frame.z, frame.dt, self.next_id, pd=pd, road=frame.road, R=frame.R)
        self.tracks, self.next_id = res.tracks, res.next_id
        if frame.pd is not None:
            alive = {t.id for t in res.tracks}
            known = truck_tracks(res.info.ids, res.info.W, frame.extent[:, 0], self._trucks)
            born = [t for t in res.tracks if t.id >= first_new and not t.candidate]
            if born:
                xy = trk.kinematics(born)[0][:, :2]
                known.update(born_trucks(np.array([t.id for t in born]), xy, frame.z, frame.extent[:, 0]))
            self._trucks = {k: v for k, v in known.items() if k in alive}
        reported = tuple(t for t in res.tracks if not t.candidate)  # candidates await a second measurement
        kin, cov = trk.kinematics(reported)
        d = kin.shape[1] // 2
        idx = np.array([0, 1, d, d + 1])  # [x, y, vx, vy] of the filter's [p; v]
        ids, info = np.array([t.id for t in reported], dtype=np.int64), res.info
        stitched = self._stitch(frame.time, res, reported, kin[:, idx], cov[:, idx][:, :, idx])
        if self.stitcher is not None:  # reported under the labels they continue; diagnostic "stitched" marks the scan
            mark = np.isin(info.ids, list(stitched)).astype(np.float64)
            info = dataclasses.replace(info, ids=self.stitcher.label(info.ids),
                                       diagnostics={**info.diagnostics, "stitched": mark})
            ids = self.stitcher.label(ids)
        return TrackSet(
            ids=ids, xy=kin[:, :2], v=kin[:, d:d + 2],
            cov=cov[:, idx][:, :, idx], status=np.array(["confirmed" if t.confirmed else "tentative" for t in reported],
                                                        dtype=object),
            score=np.array([t.score for t in reported], dtype=np.float64),
            regime=np.array([t.regime for t in reported], dtype=object),
            diagnostics=info.diagnostics, diagnostic_ids=info.ids, info=info,
            gate_alpha=trk.association.gate_alpha, fallbacks=self.fallbacks(res.info), stitched=len(stitched))

    def _stitch(self, time: float, res, reported: tuple, kin: np.ndarray, cov: np.ndarray) -> set[int]:
        """The track ids stitched in this step (none without a stitcher): the confirmed tracks it deleted are kept,
        the tracks it confirmed are stitched to kept ones (kin (T, 4) [x, y, vx, vy], cov (T, 4, 4) of ``reported``)."""
        if self.stitcher is None:
            return set()
        gone = tuple(t for t in res.deleted if t.id in self._confirmed)
        d_kin, d_cov = self.tracker.kinematics(gone) if gone else (np.zeros((0, 4)), np.zeros((0, 4, 4)))
        if gone:
            dd = d_kin.shape[1] // 2
            j = np.array([0, 1, dd, dd + 1])
            d_kin, d_cov = d_kin[:, j], d_cov[:, j][:, :, j]
        new = np.array([t.confirmed and t.id not in self._confirmed for t in reported], dtype=bool).reshape(-1)
        self._confirmed = {t.id for t in reported if t.confirmed}
        before = set(self.stitcher.alias)
        self.stitcher.update(time, (np.array([t.id for t in gone], dtype=np.int64), d_kin, d_cov),
                             (np.array([t.id for t in reported], dtype=np.int64)[new], kin[new], cov[new]))
        return set(self.stitcher.alias) - before

    @staticmethod
    def fallbacks(info) -> int:
        """Clusters of the step (StepInfo) that the associator solved by its fallback (its FALLBACK_DIAGNOSTIC)."""
        flags = info.diagnostics.get(FALLBACK_DIAGNOSTIC)
        return 0 if flags is None else fallback_clusters(info.gated, flags)
