"""Diagnostics slots: a bounded set of lines for an unbounded number of tracks.

The rerun viewer's work grows with the number of entities and chunks in a recording (rerun issues #7115,
#8233): one entity per track and quantity made a 7-minute highway run 6,876 entities, and a plot a line per
track of the whole run. Instead each diagnostic quantity has one series per *slot*
(``diagnostics/<group>/<name>/<k>``), and each confirmed track holds one slot from its first confirmation
until it is deleted. The number of slots is the largest number of such tracks alive at once (15-25 on the
motorway), not the number of tracks of the run.

- A slot freed in one frame is reused in a later frame only (its series gets a NaN, a gap in the plot).
  A new slot is opened while fewer than :data:`POOL` (the palette's size) exist; after that the slot freed
  longest ago is reused first. So a track never takes the colour of the track it replaces (the one just
  deleted) unless :data:`POOL` - 1 tracks are alive at once, and two tracks never share a line without a
  break.
- A track's slot gives its colour (``palette.SLOTS``): in the scene (point, label, velocity, trail, ellipse,
  gate) and in every diagnostics plot, so the line in T57's colour is T57's; the ``track id per slot`` plot
  (``diagnostics/slots/track_id/<k>``) says exactly which track held which slot when.

    Slots().update(ids, confirmed) -> (N,) int64    each track's slot, -1 for tracks that never were confirmed
    colours(slots) -> (N, 3) uint8
    track_colours(tracks) -> {track id: (3,) uint8}  the same colours replayed from a run's tracks table (for the
                                                      timeline, the plots and the exports)
"""
from __future__ import annotations

import numpy as np

from . import palette as pal

POOL = len(pal.SLOTS)
"""Slots opened before any is reused: one per colour of the palette."""


class Slots:
    """Slot assignment over a run; :meth:`update` once per frame with the frame's tracks."""

    def __init__(self):
        self.of: dict[int, int] = {}  # track id -> slot
        self.free: list[int] = []  # free slots, the one freed longest ago first
        self.count = 0  # slots used so far

    def update(self, ids: np.ndarray, confirmed: np.ndarray) -> np.ndarray:
        """Release the slots of tracks gone from ``ids`` (N,), give one to each track confirmed (``confirmed``
        (N,) bool) for the first time; the slot of each of ``ids`` (-1: none)."""
        present = {int(i) for i in ids}
        released = [t for t in self.of if t not in present]
        for t in np.asarray(ids)[np.asarray(confirmed, dtype=bool)]:
            t = int(t)
            if t not in self.of:
                if self.free and self.count >= POOL:
                    self.of[t] = self.free.pop(0)
                else:
                    self.of[t] = self.count
                    self.count += 1
        self.free.extend(self.of.pop(t) for t in released)  # reusable from the next frame on: a gap first
        return np.array([self.of.get(int(i), -1) for i in ids], dtype=np.int64)

    def track_ids(self) -> np.ndarray:
        """(count,) float64: the track id holding each slot now, NaN for a free one."""
        out = np.full(self.count, np.nan)
        for t, k in self.of.items():
            out[k] = t
        return out


def colours(slots: np.ndarray) -> np.ndarray:
    """(N, 3) uint8: slot k's colour ``palette.SLOTS[k % len]``, ``palette.UNSLOTTED`` for -1."""
    slots = np.asarray(slots, dtype=np.int64)
    out = np.tile(np.array(pal.UNSLOTTED, np.uint8), (len(slots), 1))
    has = slots >= 0
    out[has] = pal.SLOTS[slots[has] % len(pal.SLOTS)]
    return out


def track_colours(tracks) -> dict[int, np.ndarray]:
    """{track id: (3,) uint8 colour} of every track ever confirmed in a run's tracks table (pandas: frame,
    track_id, status), replayed frame by frame as the recorder assigns them: the viewer's colours."""
    df = tracks[["frame", "track_id", "status"]]
    frame = df["frame"].to_numpy(dtype=np.int64)
    ids = df["track_id"].to_numpy(dtype=np.int64)
    conf = df["status"].astype(str).to_numpy() == "confirmed"
    order = np.argsort(frame, kind="stable")  # each frame's rows in table order
    frame, ids, conf = frame[order], ids[order], conf[order]
    cut = np.searchsorted(frame, np.arange(1, int(frame.max()) + 1 if len(frame) else 0))  # every frame, empty too
    s, out = Slots(), {}
    for fi, fc in zip(np.split(ids, cut), np.split(conf, cut)):
        slot = s.update(fi, fc)
        for t, k in zip(fi[slot >= 0], slot[slot >= 0]):
            out.setdefault(int(t), pal.SLOTS[int(k) % len(pal.SLOTS)])
    return out
