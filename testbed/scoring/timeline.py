"""A run's tracks against its cars over time: the thesis's break-ups at a glance (``timeline.png``).

    car_timeline(truth, tracks, scoring=None) -> Timeline       from a run's truth and tracks tables
    draw_timeline(tl, path, rate_hz, title="", colours=None, events=None) -> Path   the figure

Per car seen (the scores' denominator, testbed/scoring/rates.py): a bar over the frames it was visible (hit by
a beam), coloured by the confirmed track assigned to it in that frame (the scores' per-frame assignment), grey
where no confirmed track covered it; a relabel (the assigned label changes: a break-up) is a black tick; a
frame whose track is not the car's correct track is hatched. Below, one row per false confirmed track (a
track no car claims as correct), red over its confirmed life. The lower panel: each car's position error to
its assigned track [m] against time, coloured as the bars. Track colours are the viewer's when given
(testbed/recording/slots.py ``track_colours``: a track's colour differs from the one that replaces it). At most
:data:`MAX_ROWS` cars are drawn: those with a relabel or never correctly tracked first, then those seen longest.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..common.safe_io import save_figure
from ..scenario.spec import ScoringSpec
from .evaluate import scoring_rows
from .rates import assign_frames, track_cars

MAX_ROWS = 40
"""At most this many car rows are drawn (the cars with events first, then the cars seen longest); the title says
how many were left out."""
MAX_FALSE_ROWS = 10
"""At most this many false-track rows are drawn (the longest-lived)."""


@dataclass(frozen=True, eq=False)
class Timeline:
    """cars (C,) vehicle ids of the cars seen, by first visible frame; per car c: visible[c] (frames,) and
    assigned[c] (frames,) the confirmed track id assigned in each of its frames (-1: none; aligned with
    frames[c]), err[c] (frames,) position error [m] (NaN when none); correct: {track id: its car};
    false_tracks: {track id: (frames,)} confirmed frames of each false track."""

    cars: np.ndarray
    frames: list[np.ndarray]
    visible: list[np.ndarray]
    assigned: list[np.ndarray]
    err: list[np.ndarray]
    correct: dict[int, int]
    false_tracks: dict[int, np.ndarray]

    def relabels(self, c: int) -> np.ndarray:
        """Frames at which car c's assigned confirmed label changes to another label (a break-up)."""
        a, f = self.assigned[c], self.frames[c]
        on = a >= 0
        lab, fr = a[on], f[on]
        return fr[1:][lab[1:] != lab[:-1]]


def car_timeline(truth, tracks, scoring: ScoringSpec | None = None) -> Timeline:
    """The :class:`Timeline` of a run's truth and tracks tables (testbed.scoring.evaluate's schemas)."""
    sc = scoring or ScoringSpec()
    g, t = scoring_rows(truth, tracks, sc)
    conf = t["confirmed"]
    t_frame, t_id, t_xy = t["frame"][conf], t["track_id"][conf], t["xy"][conf]
    rt, rg = assign_frames(t_frame, t_xy, g["frame"], g["xy"], sc.match_distance_m)
    correct = track_cars(t_id, t_id[rt], g["vehicle_id"][rg], sc.correct_fraction)
    pair_track = np.full(len(g["frame"]), -1, np.int64)
    pair_track[rg] = t_id[rt]
    pair_err = np.full(len(g["frame"]), np.nan)
    pair_err[rg] = np.hypot(*(t_xy[rt] - g["xy"][rg]).T)
    vis, vid, frame = g["visible"], g["vehicle_id"], g["frame"]
    order = np.lexsort((frame, vid))  # each vehicle's rows together, by frame
    ids, start = np.unique(vid[order], return_index=True)
    groups = dict(zip(ids.tolist(), np.split(order, start[1:])))
    first = {v: int(frame[r][vis[r]].min()) for v, r in groups.items() if vis[r].any()}  # the cars seen
    cars = np.array(sorted(first, key=lambda v: (first[v], v)), dtype=np.int64)
    rows = [groups[int(v)] for v in cars]
    frames, visible = [frame[r] for r in rows], [vis[r] for r in rows]
    assigned, err = [pair_track[r] for r in rows], [pair_err[r] for r in rows]
    false = {int(i): np.unique(t_frame[t_id == i]) for i in np.unique(t_id) if int(i) not in correct}
    return Timeline(cars=cars, frames=frames, visible=visible, assigned=assigned, err=err, correct=correct,
                    false_tracks=false)


def _runs(mask: np.ndarray, frames: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) frame spans where ``mask`` holds over consecutive ``frames`` (sorted, (K,))."""
    idx = np.flatnonzero(mask)
    if not len(idx):
        return []
    f = frames[idx]
    cut = np.flatnonzero(np.diff(f) != 1) + 1  # a gap in the frames, or a frame where mask fails
    cut = np.union1d(cut, np.flatnonzero(np.diff(idx) != 1) + 1)
    starts = np.r_[0, cut]
    stops = np.r_[cut, len(f)]
    return [(int(f[a]), int(f[b - 1]) + 1) for a, b in zip(starts, stops)]


_TRACK_COLOURS = (0, 1, 2, 3, 4, 5, 8, 9, 10, 11, 12, 13, 16, 17, 18, 19)
"""tab20 without its reds (false tracks) and greys (uncovered frames): a track's colour without given ones."""


def shown_cars(tl: Timeline, max_rows: int = MAX_ROWS) -> list[int]:
    """Indices into ``tl.cars`` of the cars drawn, in first-seen order: those with a relabel or without a correct
    track first, then the cars seen longest, at most ``max_rows``."""
    tracked = set(tl.correct.values())
    key = [(not (len(tl.relabels(c)) or int(v) not in tracked), -int(tl.visible[c].sum()))
           for c, v in enumerate(tl.cars)]
    order = sorted(range(len(tl.cars)), key=lambda c: key[c])[:max_rows]
    return sorted(order)


def _car_row(ax, ax2, tl: Timeline, c: int, y: float, dt: float, colour, numbered: dict | None, labelled: bool,
             span_s: float) -> None:
    """Car ``c``'s bar at height y (visible stretches grey, covered ones in the track's colour, hatched when the
    track is not its own, relabel ticks with their event labels) and its position errors on ``ax2``."""
    f, vis, a = tl.frames[c], tl.visible[c], tl.assigned[c]
    for s, e in _runs(vis, f):
        ax.broken_barh([(s * dt, (e - s) * dt)], (y - 0.35, 0.7), color="0.85", lw=0)
    for tid in np.unique(a[a >= 0]):
        good = tl.correct.get(int(tid)) == int(tl.cars[c])
        for s, e in _runs(a == tid, f):
            ax.broken_barh([(s * dt, (e - s) * dt)], (y - 0.35, 0.7), color=colour(tid), lw=0,
                           hatch=None if good else "////", edgecolor="k" if not good else None)
            if labelled and (e - s) * dt >= span_s / 40:  # room for the label
                ax.text(s * dt, y, f" T{int(tid)}", va="center", ha="left", fontsize=7)
            sel = (f >= s) & (f < e)  # one error line per stretch of one track on this car
            ax2.plot(f[sel] * dt, tl.err[c][sel], "-", lw=0.9, color=colour(tid))
    for fr in tl.relabels(c):
        ax.plot([fr * dt, fr * dt], [y - 0.5, y + 0.5], color="k", lw=1.4)
        if numbered is not None and (int(fr), int(tl.cars[c])) in numbered:
            ax.text(fr * dt, y + 0.42, numbered[(int(fr), int(tl.cars[c]))], fontsize=7, ha="left",
                    va="bottom", color="k", bbox=dict(boxstyle="square,pad=0.1", fc="white", ec="none", alpha=0.8))


def draw_timeline(tl: Timeline, path: str | Path, rate_hz: float, title: str = "",
                  colours: dict[int, np.ndarray] | None = None, events=None) -> Path:
    """Draw ``tl`` into ``path`` (PNG): car bars (upper panel, time [s] across) and position errors (lower).
    ``colours``: {track id: (3,) uint8} the tracks' colours (the viewer's); else a colour by track id.
    ``events``: the run's events table (testbed.scoring.events.run_events): each relabel tick is labelled with
    its number and cause ("#3 occlusion", as `testbed run` lists them)."""
    import matplotlib
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch
    from matplotlib.lines import Line2D

    def _colour(track_id: int):
        if colours is not None and int(track_id) in colours:
            return tuple(np.asarray(colours[int(track_id)], dtype=np.float64) / 255.0)
        return matplotlib.colormaps["tab20"](_TRACK_COLOURS[int(track_id) % len(_TRACK_COLOURS)])

    dt = 1.0 / rate_hz
    numbered = None if events is None else {
        (int(r["frame"]), int(r["car"])): f"#{int(r['event'])} {r['cause']}"
        for r in events[events["kind"] == "relabel"].to_dict("records")}
    shown = shown_cars(tl)
    n_false = len(tl.false_tracks)
    false_shown = sorted(tl.false_tracks, key=lambda t: -len(tl.false_tracks[t]))[:MAX_FALSE_ROWS]
    rows = len(shown) + len(false_shown)
    h_bars = max(2.0, min(0.16 * rows + 1.0, 30.0))
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(13, h_bars + 3.2), sharex=True,
                                  gridspec_kw=dict(height_ratios=[h_bars, 3.0]))
    labels = []
    last = max([int(f[-1]) for f in tl.frames if len(f)] + [1])
    for r, c in enumerate(shown):
        _car_row(ax, ax2, tl, c, -r, dt, _colour, numbered, len(shown) <= 40, (last + 1) * dt)
        labels.append(f"car {int(tl.cars[c])}")
    for k, (tid, fr) in enumerate((t, tl.false_tracks[t]) for t in sorted(false_shown)):
        y = -(len(shown) + k)
        for s, e in _runs(np.ones(len(fr), bool), fr):
            ax.broken_barh([(s * dt, (e - s) * dt)], (y - 0.35, 0.7), color="tab:red", lw=0)
        labels.append(f"false T{tid}")
    ax.set_yticks(-np.arange(len(labels)))
    ax.set_yticklabels(labels, fontsize=6 if len(labels) > 40 else 8)
    ax.set_ylim(-len(labels) + 0.4, 0.6)
    left, left_false = len(tl.cars) - len(shown), n_false - len(false_shown)
    omitted = [f"{left} cars without events seen least" if left > 0 else "",
               f"{left_false} shortest false tracks" if left_false > 0 else ""]
    omitted = [o for o in omitted if o]
    head = title + (" - " if title else "") + f"{len(tl.cars)} cars seen, {len(tl.correct)} correct tracks, " \
        f"{n_false} false tracks" + (f"\n(not drawn: {'; '.join(omitted)})" if omitted else "")
    ax.set_title(head, fontsize=10, loc="left")
    ax.legend(handles=[Patch(color="0.85", label="visible, no confirmed track"),
                       Patch(facecolor="tab:blue", label="covered by a track (colour: its id)"),
                       Patch(facecolor="white", edgecolor="k", hatch="////", label="by a track not its own"),
                       Line2D([], [], color="k", lw=1.4, label="relabel (break-up)"),
                       Patch(color="tab:red", label="false track (confirmed life)")],
              fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    ax2.set_ylabel("position error [m]")
    ax2.set_xlabel("time [s]")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    out = Path(path)
    save_figure(fig, out, dpi=110)
    plt.close(fig)
    return out
