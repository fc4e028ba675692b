"""Diagnostics slots: a bounded set of lines for an unbounded number of tracks.

The rerun viewer's work grows with the number of entities and chunks in a recording (rerun issues #7115,
#8233): one entity per track and quantity made a 7-minute highway run 6,876 entities, and a plot a line per
track of the whole run. Instead each diagnostic quantity has one series per *slot*
(``diagnostics/<group>/<name>/<k>``), and each confirmed track holds one slot from its first confirmation
until it is deleted. The number of slots is the largest number of such tracks alive at once (15-25 on the
motorway), not the number of tracks of the run.

- A slot freed in one frame is reused in a later frame only (its series gets a NaN, a gap in the plot),
  the slot freed longest ago first, so two tracks never share a line without a break.
- A track's slot gives its colour (``palette.SLOTS``): in the scene (point, label, velocity, trail, ellipse,
  gate) and in every diagnostics plot, so the line in T57's colour is T57's; the ``track id per slot`` plot
  (``diagnostics/slots/track_id/<k>``) says exactly which track held which slot when.

    Slots().update(ids, confirmed) -> (N,) int64    each track's slot, -1 for tracks that never were confirmed
    colours(slots) -> (N, 3) uint8
"""
from __future__ import annotations

import numpy as np

from . import palette as pal


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
                if self.free:
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
