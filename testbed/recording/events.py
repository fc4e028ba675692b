"""A run's events (testbed/scoring/events.py: relabels, false tracks, missed cars) marked in its recording.

Each event is a line of the ``events`` text log at its time ("#3 relabel of car 1: T3 -> T4 (occlusion)"), and
a ring of :data:`RING_M` around its car (a false track: around the track) on ``world/events``, with a dot beside
it labelled with its number, kind and cause (``world/events/labels``), following the car for :data:`MARK_S` seconds, so ``testbed view RUN --event N`` opens on it.

    log_events(rec, events, truth, tracks, rate_hz)
"""
from __future__ import annotations

import numpy as np
import rerun as rr

from ..scoring.events import describe_event
from . import palette as pal

MARK_S = 3.0  # seconds an event's ring stays on its car
RING_M = 4.0  # ring radius [m]: around a car, clear of its track's point and label


def _ring(xy: np.ndarray, n: int = 40) -> np.ndarray:
    """(n+1, 3) circle of radius RING_M around ``xy`` (2,), 1.5 m above the road."""
    t = np.linspace(0.0, 2 * np.pi, n + 1)
    return np.column_stack([xy[0] + RING_M * np.cos(t), xy[1] + RING_M * np.sin(t), np.full(n + 1, 1.5)])


def log_events(rec: rr.RecordingStream, events, truth, tracks, rate_hz: float) -> None:
    """Log ``events`` (testbed.scoring.events.run_events) into ``rec``: the text log and the rings. ``truth``
    (frame, vehicle_id, x, y) and ``tracks`` (frame, track_id, x, y) give where each ring is, frame by frame."""
    if events is None or not len(events):
        return
    car_at = {(int(f), int(v)): (x, y) for f, v, x, y in truth[["frame", "vehicle_id", "x", "y"]].itertuples(False)}
    trk_at = {(int(f), int(t)): (x, y) for f, t, x, y in tracks[["frame", "track_id", "x", "y"]].itertuples(False)}
    rows = events.to_dict("records")
    for r in rows:
        _at(rec, int(r["frame"]), rate_hz)
        rec.log("events", rr.TextLog(f"#{int(r['event'])} {describe_event(r)}", level=rr.TextLogLevel.WARN))
    span = int(round(MARK_S * rate_hz))
    last = min(max(int(r["frame"]) for r in rows) + span, int(truth["frame"].max()))  # never past the run's end
    for f in range(min(int(r["frame"]) for r in rows), last + 1):
        rings, tags, labels = [], [], []
        for r in rows:
            if not int(r["frame"]) <= f < int(r["frame"]) + span:
                continue
            key = (f, int(r["new_track"])) if r["kind"] == "false track" else (f, int(r["car"]))
            xy = (trk_at if r["kind"] == "false track" else car_at).get(key)
            if xy is not None:
                rings.append(_ring(np.asarray(xy, dtype=np.float64)))
                tags.append([xy[0], xy[1] + RING_M + 2.0, 2.5])  # beside the ring, clear of the track's label
                labels.append(f"#{int(r['event'])} {r['kind']}: {r['cause']}")
        _at(rec, f, rate_hz)
        rec.log("world/events", rr.LineStrips3D(np.array(rings).reshape(-1, 41, 3), colors=[pal.EVENT], radii=0.15))
        rec.log("world/events/labels", rr.Points3D(np.array(tags).reshape(-1, 3), labels=labels, colors=[pal.EVENT],
                                                   radii=0.3, show_labels=True))


def _at(rec: rr.RecordingStream, frame: int, rate_hz: float) -> None:
    rec.set_time("frame", sequence=frame)
    rec.set_time("sim_time", duration=frame / rate_hz)
