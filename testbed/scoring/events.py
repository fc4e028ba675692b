"""Break-up events of a run with their causes: each relabel of a car (the thesis's track break-ups, counted as in
testbed/scoring/rates.py) as one row.

    breakup_events(truth, tracks, scoring=None) -> pandas.DataFrame

Columns: frame (the first frame with the new label), car (vehicle id), old_track, new_track, cause. The cause is
read from the tables alone (no tracker internals), in this order:

* "swap": the old track is still confirmed at that frame and assigned to another car (it took that car);
* "manoeuvre": the car turned: its heading changed by more than :data:`TURN_RAD` over the :data:`LOOKBACK_S`
  before the old track's deletion (or before the relabel, if the old track lives on);
* "merge": the old track is still confirmed but on no car (it left its car: merged or split detections, or a
  duplicate track that won);
* "occlusion": the old track was deleted while its car was hidden (fewer than the scoring's visible points on
  at least half of the frames between the old track's last frame on the car and its deletion);
* "deletion while visible": any other deletion (the car was in view and not turning).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from ..scenario.spec import ScoringSpec
from .evaluate import scoring_rows
from .timeline import car_timeline

CAUSES = ("swap", "manoeuvre", "merge", "occlusion", "deletion while visible")
TURN_RAD = 0.15
"""Heading change [rad] over :data:`LOOKBACK_S` that makes a deletion a manoeuvre's (a lane change at highway
speed turns the car by 0.1-0.2 rad; the 20 m U-turn by 0.5 rad per second)."""
LOOKBACK_S = 2.0


def breakup_events(truth, tracks, scoring: ScoringSpec | None = None, dt: float = 0.1) -> pd.DataFrame:
    """The relabel events of a run's truth and tracks tables (testbed.scoring.evaluate's schemas), one row each,
    by frame: frame, car, old_track, new_track, cause (module docstring); dt: the frame period [s]."""
    sc = scoring or ScoringSpec()
    tl = car_timeline(truth, tracks, sc)
    g, t = scoring_rows(truth, tracks, sc)
    conf = t["confirmed"]
    last = pd.Series(t["frame"][conf]).groupby(t["track_id"][conf]).max()
    on_car = {}  # (frame, track) -> car of the frame's assignment
    for c, v in enumerate(tl.cars):
        for f, a in zip(tl.frames[c], tl.assigned[c]):
            if a >= 0:
                on_car[(int(f), int(a))] = int(v)
    heading = _headings(truth)
    rows = []
    for c, v in enumerate(tl.cars):
        a, f, vis = tl.assigned[c], tl.frames[c], tl.visible[c]
        for fr in tl.relabels(c):
            i = int(np.flatnonzero(f == fr)[0])
            prev = a[:i][a[:i] >= 0]
            old, new = int(prev[-1]), int(a[i])
            cause = _cause(int(v), int(fr), old, f, a[:i], vis, last, on_car, heading.get(int(v)),
                           int(round(LOOKBACK_S / dt)))
            rows.append(dict(frame=int(fr), car=int(v), old_track=old, new_track=new, cause=cause))
    out = pd.DataFrame(rows, columns=["frame", "car", "old_track", "new_track", "cause"])
    return out.sort_values(["frame", "car"], kind="stable").reset_index(drop=True)


def _headings(truth) -> dict[int, pd.Series]:
    df = truth if isinstance(truth, pd.DataFrame) else pd.DataFrame(truth)
    if "heading" not in df.columns:
        return {}
    return {int(v): grp.set_index("frame")["heading"] for v, grp in df.groupby("vehicle_id")}


def _cause(car: int, frame: int, old: int, frames: np.ndarray, before: np.ndarray, visible: np.ndarray,
           last: pd.Series, on_car: dict, h: pd.Series | None, lookback: int) -> str:
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
    if span.any() and (~visible[span]).mean() >= 0.5:
        return "occlusion"
    return "deletion while visible"
