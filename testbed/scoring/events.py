"""A run's events with their causes: each relabel of a car (the thesis's track break-ups, counted as in
testbed/scoring/rates.py), each false track and each missed car, one row each.

    breakup_events(truth, tracks, scoring=None, dt=0.1) -> pandas.DataFrame     the relabels
    run_events(truth, tracks, scoring=None, dt=0.1) -> pandas.DataFrame         all three kinds, by time
    format_events(events, limit=20) -> str                                      the list the CLI prints

Columns: frame (the first frame with the new label), car (vehicle id), old_track, new_track, cause. The cause is
read from the tables alone (no tracker internals), in this order:

* "swap": the old track is still confirmed at that frame and assigned to another car (it took that car);
* "manoeuvre": the car turned: its heading changed by more than :data:`TURN_RAD` over the :data:`LOOKBACK_S`
  before the old track's deletion (or before the relabel, if the old track lives on);
* "merge": the old track is still confirmed but on no car (it left its car: merged or split detections, or a
  duplicate track that won);
* "out of range": the old track was deleted while its car was beyond the sensor's range (truth's ``in_range``
  false on at least half of the frames between the old track's last frame on the car and its deletion): a car
  that drove out of reach and came back, which no tracker keeps (a truth table without ``in_range`` never
  gives this cause);
* "occlusion": the old track was deleted while its car was hidden (fewer than the scoring's visible points on
  at least half of those frames);
* "deletion while visible": any other deletion (the car was in view and not turning).

A **false track** (a confirmed track no car claims as correct, rates.py rule 3) is dated at its first confirmed
frame; its cause, in this order: "clutter" (never assigned to a car: clutter, a static object or a stray
fragment), "swap" (assigned to two or more cars), "duplicate" (assigned to one car that has a correct track of
its own), "drift" (assigned to one otherwise untracked car for less than the scoring's ``correct_fraction`` of
its confirmed life). A **missed car** (a car seen that no correct track follows) is dated at its first visible
frame; its cause: "wrong track" (a confirmed track not its own covered it), "seen briefly" (visible on fewer
than :data:`BRIEF_S` of frames), "occlusion" (hidden on at least half of the frames from its first to its last
visible one), "never confirmed" (in view, but no track was confirmed on it).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from ..scenario.spec import ScoringSpec
from .evaluate import scoring_rows
from .timeline import car_timeline

CAUSES = ("swap", "manoeuvre", "merge", "out of range", "occlusion", "deletion while visible")
FALSE_CAUSES = ("clutter", "swap", "duplicate", "drift")
MISSED_CAUSES = ("wrong track", "seen briefly", "occlusion", "never confirmed")
KINDS = ("relabel", "false track", "missed car")
COLUMNS = ("event", "time", "frame", "kind", "car", "old_track", "new_track", "cause", "x", "y")
"""events.parquet: event number (1, 2, ... by time), time [s], frame, kind (:data:`KINDS`), car (vehicle id, -1:
none), old_track and new_track (track ids, -1: none; a false track is its new_track), cause, x, y [m] (where it
happened: the car's position, or the false track's)."""
BRIEF_S = 1.0
"""A missed car visible for less than this [s] was "seen briefly"."""
TURN_RAD = 0.15
"""Heading change [rad] over :data:`LOOKBACK_S` that makes a deletion a manoeuvre's (a lane change at highway
speed turns the car by 0.1-0.2 rad; the 20 m U-turn by 0.5 rad per second)."""
LOOKBACK_S = 2.0


def breakup_events(truth, tracks, scoring: ScoringSpec | None = None, dt: float = 0.1) -> pd.DataFrame:
    """The relabel events of a run's truth and tracks tables (testbed.scoring.evaluate's schemas), one row each,
    by frame: frame, car, old_track, new_track, cause (module docstring); dt: the frame period [s]."""
    sc = scoring or ScoringSpec()
    _, t = scoring_rows(truth, tracks, sc)
    return _breakups(car_timeline(truth, tracks, sc), t, truth, dt)


def _breakups(tl, t: dict, truth, dt: float) -> pd.DataFrame:
    """:func:`breakup_events` from the run's Timeline ``tl`` and its scoring track rows ``t``."""
    conf = t["confirmed"]
    last = pd.Series(t["frame"][conf]).groupby(t["track_id"][conf]).max()
    on_car = {}  # (frame, track) -> car of the frame's assignment
    for c, v in enumerate(tl.cars):
        for f, a in zip(tl.frames[c], tl.assigned[c]):
            if a >= 0:
                on_car[(int(f), int(a))] = int(v)
    heading = _headings(truth)
    beyond = _beyond(truth)
    rows = []
    for c, v in enumerate(tl.cars):
        a, f, vis = tl.assigned[c], tl.frames[c], tl.visible[c]
        for fr in tl.relabels(c):
            i = int(np.flatnonzero(f == fr)[0])
            prev = a[:i][a[:i] >= 0]
            old, new = int(prev[-1]), int(a[i])
            far = beyond.get(int(v))
            cause = _cause(int(v), int(fr), old, f, a[:i], vis, last, on_car, heading.get(int(v)),
                           int(round(LOOKBACK_S / dt)), None if far is None else far.reindex(f, fill_value=False).to_numpy(bool))
            rows.append(dict(frame=int(fr), car=int(v), old_track=old, new_track=new, cause=cause))
    out = pd.DataFrame(rows, columns=["frame", "car", "old_track", "new_track", "cause"])
    return out.sort_values(["frame", "car"], kind="stable").reset_index(drop=True)


def run_events(truth, tracks, scoring: ScoringSpec | None = None, dt: float = 0.1) -> pd.DataFrame:
    """Every relabel, false track and missed car of a run's truth and tracks tables, one row each, by time
    (columns :data:`COLUMNS`); dt: the frame period [s]."""
    sc = scoring or ScoringSpec()
    tl = car_timeline(truth, tracks, sc)
    g, t = scoring_rows(truth, tracks, sc)
    pos = {(int(f), int(v)): xy for f, v, xy in zip(g["frame"], g["vehicle_id"], g["xy"])}
    rows = [dict(kind="relabel", **r) for r in _breakups(tl, t, truth, dt).to_dict("records")]
    for r in rows:
        r["x"], r["y"] = pos.get((r["frame"], r["car"]), (np.nan, np.nan))
    conf = t["confirmed"]
    t_frame, t_id, t_xy = t["frame"][conf], t["track_id"][conf], t["xy"][conf]
    cars_of: dict[int, list[int]] = {}  # track -> the cars it was assigned to, one entry per frame
    for c, v in enumerate(tl.cars):
        for a in tl.assigned[c][tl.assigned[c] >= 0]:
            cars_of.setdefault(int(a), []).append(int(v))
    tracked = set(tl.correct.values())
    for tid, frames in tl.false_tracks.items():
        on = cars_of.get(tid, [])
        cars = sorted(set(on))
        cause = ("clutter" if not cars else "swap" if len(cars) > 1 else "duplicate" if cars[0] in tracked
                 else "drift")
        first = int(frames[0])
        k = np.flatnonzero((t_id == tid) & (t_frame == first))[0]
        rows.append(dict(frame=first, car=max(set(on), key=on.count) if on else -1, old_track=-1, new_track=tid,
                         cause=cause, kind="false track", x=float(t_xy[k, 0]), y=float(t_xy[k, 1])))
    brief = int(round(BRIEF_S / dt))
    for c, v in enumerate(tl.cars):
        if int(v) in tracked:
            continue
        f, vis, a = tl.frames[c], tl.visible[c], tl.assigned[c]
        seen = np.flatnonzero(vis)
        span = slice(seen[0], seen[-1] + 1)
        cause = ("wrong track" if (a >= 0).any() else "seen briefly" if len(seen) < brief
                 else "occlusion" if (~vis[span]).mean() >= 0.5 else "never confirmed")
        x, y = pos.get((int(f[seen[0]]), int(v)), (np.nan, np.nan))
        rows.append(dict(frame=int(f[seen[0]]), car=int(v), old_track=-1, new_track=-1, cause=cause,
                         kind="missed car", x=float(x), y=float(y)))
    out = pd.DataFrame(rows, columns=[c for c in COLUMNS if c not in ("event", "time")])
    out["kind_order"] = out["kind"].map({k: i for i, k in enumerate(KINDS)})
    out = out.sort_values(["frame", "kind_order", "car"], kind="stable").drop(columns="kind_order")
    out.insert(0, "time", out["frame"].to_numpy(dtype=np.float64) * dt)
    out.insert(0, "event", np.arange(1, len(out) + 1, dtype=np.int64))
    return out.astype(dict(frame=np.int64, car=np.int64, old_track=np.int64, new_track=np.int64,
                           x=np.float64, y=np.float64))[list(COLUMNS)].reset_index(drop=True)


def describe_event(row) -> str:
    """One event (a row of :func:`run_events`) in words: ``relabel of car 2: T3 -> T4 (occlusion)``."""
    kind, cause = str(row["kind"]), str(row["cause"])
    if kind == "relabel":
        return f"relabel of car {int(row['car'])}: T{int(row['old_track'])} -> T{int(row['new_track'])} ({cause})"
    if kind == "false track":
        on = f" on car {int(row['car'])}" if int(row["car"]) >= 0 else ""
        return f"false track T{int(row['new_track'])}{on} ({cause})"
    return f"missed car {int(row['car'])} ({cause})"


def format_events(events: pd.DataFrame, limit: int = 20) -> str:
    """The events table as numbered lines (at most ``limit``; the count of the rest after them)."""
    if not len(events):
        return "events: none (no relabel, false track or missed car)"
    lines = [f"events ({len(events)}: " + ", ".join(f"{int((events['kind'] == k).sum())} {k}s" for k in KINDS)
             + "):"]
    for row in events.head(limit).to_dict("records"):
        lines.append(f"  {int(row['event']):3d}  {row['time']:7.1f} s  {describe_event(row)}")
    if len(events) > limit:
        lines.append(f"  ... and {len(events) - limit} more in events.parquet")
    return "\n".join(lines)


def _headings(truth) -> dict[int, pd.Series]:
    df = truth if isinstance(truth, pd.DataFrame) else pd.DataFrame(truth)
    if "heading" not in df.columns:
        return {}
    return {int(v): grp.set_index("frame")["heading"] for v, grp in df.groupby("vehicle_id")}


def _beyond(truth) -> dict[int, pd.Series]:
    """Per vehicle id, frame -> whether it was beyond the sensor's range (truth's ``in_range``); empty without it."""
    df = truth if isinstance(truth, pd.DataFrame) else pd.DataFrame(truth)
    if "in_range" not in df.columns:
        return {}
    return {int(v): ~grp.set_index("frame")["in_range"].astype(bool) for v, grp in df.groupby("vehicle_id")}


def _cause(car: int, frame: int, old: int, frames: np.ndarray, before: np.ndarray, visible: np.ndarray,
           last: pd.Series, on_car: dict, h: pd.Series | None, lookback: int, beyond: np.ndarray | None = None) -> str:
    """The cause of car ``car``'s relabel at ``frame`` (module docstring); visible and beyond (F,) bool per frame
    of ``frames``: the car in view, beyond the sensor's range (None: not known)."""
    end = int(last.get(old, -1))
    alive = end >= frame  # the old track lives on
    if alive and on_car.get((frame, old), car) != car:
        return "swap"
    stop = frame if alive else end
    if h is not None and stop in h.index:
        back = h.loc[max(stop - lookback, int(h.index.min())):stop].to_numpy()
        if back.size and np.abs(np.angle(np.exp(1j * (back - back[0])))).max() > TURN_RAD:
            return "manoeuvre"
    if alive:
        return "merge"
    seen = np.flatnonzero(before == old)
    start = int(frames[seen[-1]]) if seen.size else end
    span = (frames >= start) & (frames <= end)
    if span.any() and beyond is not None and beyond[span].mean() >= 0.5:
        return "out of range"
    if span.any() and (~visible[span]).mean() >= 0.5:
        return "occlusion"
    return "deletion while visible"
