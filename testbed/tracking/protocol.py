"""The tracker protocol: what any tracker is fed at each scan (:class:`Frame`) and returns (:class:`TrackSet`).

A tracker is any object with ``step(frame: Frame) -> TrackSet``; it keeps its own state between scans (the
testbed calls ``step`` once per scan, in time order, from the first scan). Nothing else is required: the testbed
builds the tables, scores, diagnostics and recording from what ``step`` returns. A minimal one::

    class Nearest:
        def __init__(self, scenario):
            self.xy = np.zeros((0, 2))

        def step(self, frame):
            self.xy = frame.z.copy()          # every detection is a "track" (no association at all)
            return TrackSet(ids=np.arange(len(self.xy)), xy=self.xy)

Units: metres, seconds, world frame (x along the road, y to the left), positions first.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

STATUSES = ("confirmed", "tentative")
"""What a tracker may call a track: confirmed tracks are reported and scored, tentative ones only logged."""


@dataclass(frozen=True, eq=False)
class Frame:
    """One scan as a tracker sees it.

    index: scan number (0 first); time [s]; dt [s] since the previous scan (0 at the first).
    z: (M, 2) float64 detection positions [m]; R: (M, 2, 2) their measurement covariances [m^2];
    extent: (M, 3) fitted length, width, height [m]; heading: (M,) fitted box heading in [0, pi) [rad].
    pd: the occlusion-aware detection probability, or None when the scenario has it off:
        ``pd(xy (T, 2) [m], nominal, trucks=None) -> (T,)``: ``nominal`` where the range image shows a vehicle at
        xy in view, near 0 in a shadow or where no beam reaches one; ``trucks`` (T,) bool asks for a truck-sized
        box at those positions (testbed/sensing: occlusion_pd).
    road: the lane map, or None when the scenario has none: ``road(xy (T, 2) [m]) -> (heading (T,) [rad], offset
        (T,) [m], half_width (T,) [m], curvature (T,) [1/m])`` of the nearest lane (sensors.RoadMap.lane_frame; what
        the built-in trackers' road-map aid reads, trackers/road.py).
    measurements: the further sensors' detections by name (sensor.extra), each a testbed.sensing.Measurements
        (z (M, m) with its measurement model, R, P_D and clutter density); the built-in trackers take those named
        in ``tracker.sensors``.
    """

    index: int
    time: float
    dt: float
    z: np.ndarray
    R: np.ndarray
    extent: np.ndarray
    heading: np.ndarray
    pd: Callable[..., np.ndarray] | None = None
    road: Callable[[np.ndarray], tuple] | None = None
    measurements: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class TrackSet:
    """The tracks a tracker reports after one scan (T of them).

    ids: (T,) int64 labels, unique within the set (a label kept from scan to scan is one track).
    xy: (T, 2) position estimates [m]. v: (T, 2) velocity estimates [m/s] (NaN: not estimated).
    cov: (T, 4, 4) covariance of [x, y, vx, vy] (NaN: not given). status: (T,) "confirmed" or "tentative"
    (default: all confirmed). score: (T,) track score (NaN: none). regime: (T,) a label the viewer shows (e.g. the
    KS track-regime verdict). diagnostics: name -> (K,) float64 per-track quantities (NIS, gate volume, ...) for the
    diagnostics table and the viewer, of the tracks diagnostic_ids (K,) int64 (default: ids). info: the built-in trackers' StepInfo (gates, boundary layers) for the recording, else None.
    gate_alpha: the gate's chi-square threshold the recording draws ``info``'s gates at.
    fallbacks: association problems of this scan solved by a fallback because the exact one was over its budget
    (a JPDA cluster over max_nodes; the run sums them into scores.json's ``association_fallbacks``).
    stitched: tracks of this scan given the label of a recently deleted track (track-to-track stitching,
    ``tracker.stitch_s``; testbed/tracking/stitch.py); the run sums them into scores.json's ``stitched_tracks``.
    box: (T, 3) each track's bird's-eye-view box [heading (rad), length (m), width (m)] (box tracking,
    ``tracker.box``), or None.
    """

    ids: np.ndarray
    xy: np.ndarray
    v: np.ndarray | None = None
    cov: np.ndarray | None = None
    status: np.ndarray | None = None
    score: np.ndarray | None = None
    regime: np.ndarray | None = None
    diagnostics: dict[str, np.ndarray] = field(default_factory=dict)
    diagnostic_ids: np.ndarray | None = None
    info: object | None = None
    gate_alpha: float = 9.21
    fallbacks: int = 0
    stitched: int = 0
    box: np.ndarray | None = None

    def __post_init__(self) -> None:
        ids = np.asarray(self.ids)
        if ids.ndim != 1 or (ids.size and not np.issubdtype(ids.dtype, np.integer)):
            raise ValueError(f"TrackSet.ids: expected (T,) integers, got {ids.dtype} of shape {ids.shape}")
        ids = ids.astype(np.int64)
        t = len(ids)
        if len(set(ids.tolist())) != t:
            raise ValueError("TrackSet.ids: a label appears twice")
        shapes = dict(xy=(t, 2), v=(t, 2), cov=(t, 4, 4), score=(t,))
        for name, shape in shapes.items():
            value = getattr(self, name)
            a = np.full(shape, np.nan) if value is None else np.asarray(value, dtype=np.float64)
            if a.shape != shape:
                raise ValueError(f"TrackSet.{name}: expected shape {shape}, got {a.shape}")
            object.__setattr__(self, name, a)
        if not np.isfinite(self.xy).all():
            raise ValueError("TrackSet.xy: positions must be finite")
        status = np.full(t, "confirmed", dtype=object) if self.status is None else np.asarray(self.status, dtype=object)
        if status.shape != (t,) or not set(status.tolist()) <= set(STATUSES):
            raise ValueError(f"TrackSet.status: expected (T,) of {', '.join(STATUSES)}")
        regime = np.full(t, "", dtype=object) if self.regime is None else np.asarray(self.regime, dtype=object)
        if regime.shape != (t,):
            raise ValueError(f"TrackSet.regime: expected shape ({t},), got {regime.shape}")
        for name in ("fallbacks", "stitched"):
            n = getattr(self, name)
            if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
                raise ValueError(f"TrackSet.{name}: expected an int >= 0, got {n!r}")
        if self.box is not None:
            box = np.asarray(self.box, dtype=np.float64)
            if box.shape != (t, 3) or not np.isfinite(box).all():
                raise ValueError(f"TrackSet.box: expected finite (T, 3) = ({t}, 3), got {box.shape}")
            object.__setattr__(self, "box", box)
        diag_ids = ids if self.diagnostic_ids is None else np.asarray(self.diagnostic_ids, dtype=np.int64).reshape(-1)
        diag = {}
        for name, values in self.diagnostics.items():
            a = np.asarray(values, dtype=np.float64)
            if a.shape != diag_ids.shape:
                raise ValueError(f"TrackSet.diagnostics[{name!r}]: expected shape {diag_ids.shape}, got {a.shape}")
            diag[str(name)] = a
        for name, value in (("ids", ids), ("status", status), ("regime", regime), ("diagnostics", diag),
                            ("diagnostic_ids", diag_ids)):
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return len(self.ids)

    def with_status(self, status: np.ndarray) -> "TrackSet":
        """The same tracks with another status (T,) (the testbed's moving-object test adds "static")."""
        new = object.__new__(TrackSet)
        new.__dict__.update(self.__dict__)
        new.__dict__["status"] = np.asarray(status, dtype=object).reshape(len(self))
        return new


@runtime_checkable
class Tracker(Protocol):
    """Anything with ``step(frame: Frame) -> TrackSet``, called once per scan in time order."""

    def step(self, frame: Frame) -> TrackSet: ...
