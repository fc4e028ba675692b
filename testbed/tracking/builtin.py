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

from ..common.errors import RunError
from ..config import ConfigError
from .protocol import Frame, TrackSet
from .stitch import Stitcher

TRUCK_MIN_LENGTH_M = 7.0
"""A detection longer than this [m] is a truck's (the box fit's truck boxes are at least 7.5 m long)."""


def truck_tracks(ids: np.ndarray, W: np.ndarray, lengths: np.ndarray, known: dict[int, bool],
                 born_from: dict[int, int] | None = None) -> dict[int, bool]:
    """``known`` (track id -> truck) updated from one step: a track whose association weight W (T, M) on one
    detection exceeds 1/2 takes that detection's class (``lengths`` (M,) [m] > :data:`TRUCK_MIN_LENGTH_M`), and a
    track started in the step (``born_from``: its id -> the detection it was started on, StepInfo.born_from) takes
    the class of that detection. A truck's new track so gets a truck box's P_D from its first scan: with a car box
    the truck's own rear face hides its centre, its P_D is 0, its detections get no weight and it never learnt its
    class from them (the oncoming trucks dense_motorway never confirmed)."""
    out = dict(known)
    if W.size:
        best = np.argmax(W, axis=1)
        rows = np.flatnonzero(W[np.arange(len(ids)), best] > 0.5)
        trucks = lengths[best[rows]] > TRUCK_MIN_LENGTH_M
        out.update(zip(np.asarray(ids, dtype=np.int64)[rows].tolist(), trucks.tolist()))
    for i, j in (born_from or {}).items():
        out[int(i)] = bool(lengths[j] > TRUCK_MIN_LENGTH_M)
    return out


def position_velocity(kin: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[x, y, vx, vy] (T, 4) and its covariance (T, 4, 4) of a tracker's kinematics (T, 2d) [p; v] and (T, 2d, 2d)."""
    d = kin.shape[1] // 2
    if d == 2:  # [x, y, vx, vy] already
        return kin, cov
    idx = np.array([0, 1, d, d + 1])
    return kin[:, idx], cov[:, idx][:, :, idx]


def along_motion(box: np.ndarray, v: np.ndarray, min_speed_mps: float = 1.0) -> np.ndarray:
    """Boxes (T, 3) [heading, length, width] with each heading turned by pi where it points against the track's
    velocity v (T, 2) [m/s] (a fitted box's heading is known modulo pi), for tracks moving at min_speed_mps or more."""
    out = box.copy()
    speed = np.hypot(v[:, 0], v[:, 1])
    back = (speed >= min_speed_mps) & (np.cos(box[:, 0] - np.arctan2(v[:, 1], v[:, 0])) < 0)
    out[back, 0] = (box[back, 0] + 2.0 * np.pi) % (2.0 * np.pi) - np.pi  # heading + pi, in [-pi, pi)
    return out


class BoxTracks:
    """Box tracking (``tracker.box``): each track's bird's-eye-view box [heading, length, width] and its variances,
    filtered beside the kinematic state with the association weights of each step (trackers.box), started from
    the detection the track was started on (StepInfo.born_from)."""

    def __init__(self, params: trackers.BoxParams | None = None):
        self.params = params or trackers.BoxParams()
        self.state: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def update(self, res, y: np.ndarray, dt: float) -> None:
        """After a step (StepResult ``res``) on detections whose fitted boxes are y (M, 3) [heading, length, width]."""
        info = res.info
        ids = [int(i) for i in info.ids]
        b = np.array([self.state[i][0] for i in ids]).reshape(-1, 3)
        var = np.array([self.state[i][1] for i in ids]).reshape(-1, 3)
        b, var = trackers.box_update(b, var, y, info.W, info.w0, dt, self.params)
        new = {i: (b[t], var[t]) for t, i in enumerate(ids)}
        for i, j in info.born_from.items():
            new[int(i)] = trackers.box_birth(y[j], self.params)
        alive = {t.id for t in res.tracks}
        self.state = {i: v for i, v in new.items() if i in alive}

    def of(self, ids: list[int]) -> np.ndarray:
        """The boxes (T, 3) of tracks ``ids``."""
        return np.array([self.state[i][0] for i in ids], dtype=np.float64).reshape(len(ids), 3)


class BuiltinTracker:
    """A ``trackers.Tracker`` as a protocol tracker. ``tracker``: the built tracker (``trackers.make_tracker``);
    ``tracks``: the live tracks after the last step (candidates included), ``next_id`` the next label."""

    def __init__(self, tracker: trackers.Tracker, stitch_s: float = 0.0, sensors: tuple[str, ...] = ("lidar",),
                 box: bool = False):
        self.tracker = tracker
        self.name = tracker.name
        self.sensors = tuple(sensors)  # tracker.sensors: the first runs the step, the others update (sequential)
        self.boxes = BoxTracks() if box else None  # box tracking (tracker.box): each track's [heading, l, w]
        self.tracks: tuple = ()
        self.next_id = 1
        self._trucks: dict[int, bool] = {}
        self.stitcher = Stitcher(stitch_s) if stitch_s > 0 else None  # track-to-track stitching (stitch.py)
        self._confirmed: set[int] = set()

    def step(self, frame: Frame) -> TrackSet:
        trk = self.tracker
        if self.sensors[0] == "lidar":
            res = self._lidar_step(frame)
            if self.boxes is not None:
                self.boxes.update(res, np.c_[frame.heading, frame.extent[:, :2]], frame.dt)
        else:  # another sensor's detections, with the measurement model they carry, run the whole step
            meas = self._measurements(frame, self.sensors[0])
            trk = self._for(meas)
            res = trk.step(self.tracks, meas.z, frame.dt, self.next_id, road=frame.road, R=meas.R)
            self.tracks, self.next_id = res.tracks, res.next_id
        for name in self.sensors[1:]:  # sequential updates of the same instant, in the order of tracker.sensors
            meas = self._measurements(frame, name)
            if len(meas.z):
                self.tracks = self._for(meas).update(self.tracks, meas.z, 0.0, R=meas.R).tracks
        reported = tuple(t for t in self.tracks if not t.candidate)  # candidates await a second measurement
        kin, cov = self.tracker.kinematics(reported)
        xyv, xyv_cov = position_velocity(kin, cov)
        ids, info, stitched = np.array([t.id for t in reported], dtype=np.int64), res.info, []
        if self.stitcher is not None:  # reported under the labels they continue; diagnostic "stitched" marks the scan
            stitched = self._stitch(frame.time, res.deleted, reported, xyv, xyv_cov)
            info = dataclasses.replace(info, ids=self.stitcher.label(info.ids), diagnostics={
                **info.diagnostics, "stitched": np.isin(info.ids, stitched).astype(np.float64)})
            ids = self.stitcher.label(ids)
        return TrackSet(
            ids=ids, xy=xyv[:, :2], v=xyv[:, 2:], cov=xyv_cov,
            status=np.array(["confirmed" if t.confirmed else "tentative" for t in reported], dtype=object),
            score=np.array([t.score for t in reported], dtype=np.float64),
            regime=np.array([t.regime for t in reported], dtype=object),
            diagnostics=info.diagnostics, diagnostic_ids=info.ids, info=info if trk is self.tracker else None,
            gate_alpha=trk.association.gate_alpha, fallbacks=self.fallbacks(res.info), stitched=len(stitched),
            box=None if self.boxes is None else along_motion(self.boxes.of([t.id for t in reported]), xyv[:, 2:]))

    def _lidar_step(self, frame: Frame):
        """The step on the LiDAR's detections, with the occlusion-aware P_D (truck boxes for trucks' tracks)."""
        trk = self.tracker
        pd = None
        if frame.pd is not None:
            live = np.array([self._trucks.get(t.id, False) for t in self.tracks if not t.candidate], dtype=bool)
            nominal, occ = trk.association.pd, frame.pd
            pd = lambda z_hat: occ(z_hat[:, :2], nominal, live)  # noqa: E731 - the tracker calls it once
        res = trk.step(self.tracks, frame.z, frame.dt, self.next_id, pd=pd, road=frame.road, R=frame.R)
        self.tracks, self.next_id = res.tracks, res.next_id
        if frame.pd is not None:
            alive = {t.id for t in res.tracks}
            self._trucks = {k: v for k, v in truck_tracks(res.info.ids, res.info.W, frame.extent[:, 0], self._trucks,
                                                          res.info.born_from).items() if k in alive}
        return res

    @staticmethod
    def _measurements(frame: Frame, name: str):
        meas = frame.measurements.get(name)
        if meas is None:
            raise RunError(f"tracker.sensors names {name!r}, but frame {frame.index} has no measurements of it")
        return meas

    def _for(self, meas) -> trackers.Tracker:
        """The tracker with the measurement model, P_D and clutter density ``meas`` carries (a one-line ConfigError
        when its filter cannot take the model)."""
        try:
            return self.tracker.with_measurement(meas.model, pd=meas.pd, clutter_density=meas.clutter_density)
        except ValueError as err:
            raise ConfigError("tracker.sensors", f"{self.name}: {err}") from None

    def _stitch(self, time: float, deleted: tuple, reported: tuple, xyv: np.ndarray, xyv_cov: np.ndarray) -> list[int]:
        """The ids of the ``reported`` tracks (their [x, y, vx, vy] (T, 4) and covariance) stitched in this step: the
        confirmed tracks the step deleted are kept, the tracks it confirmed are stitched to kept ones."""
        gone = tuple(t for t in deleted if t.id in self._confirmed)
        gone_kin = position_velocity(*self.tracker.kinematics(gone)) if gone else (np.zeros((0, 4)), np.zeros((0, 4, 4)))
        new = np.array([t.confirmed and t.id not in self._confirmed for t in reported], dtype=bool).reshape(-1)
        self._confirmed = {t.id for t in reported if t.confirmed}
        return self.stitcher.update(time, (np.array([t.id for t in gone], dtype=np.int64), *gone_kin),
                                    (np.array([t.id for t in reported], dtype=np.int64)[new], xyv[new], xyv_cov[new]))

    @staticmethod
    def fallbacks(info) -> int:
        """Clusters of the step (StepInfo) that the associator solved by its fallback (its FALLBACK_DIAGNOSTIC)."""
        flags = info.diagnostics.get(FALLBACK_DIAGNOSTIC)
        return 0 if flags is None else fallback_clusters(info.gated, flags)
