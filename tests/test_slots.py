"""Diagnostics slots (testbed/recording/slots.py): bounded lines for any number of tracks, a gap before a slot
changes hands, a new slot while fewer than POOL exist, then the slot freed longest ago reused first, colours per
slot; a track's colour differs from the one replacing it (issue 34.2)."""
from __future__ import annotations

import numpy as np

from roadtrack.testbed.recording import palette as pal
import pandas as pd

from roadtrack.testbed.recording.slots import POOL, Slots, colours, track_colours


def _step(s: Slots, ids, confirmed):
    return s.update(np.array(ids, dtype=np.int64), np.array(confirmed, dtype=bool)).tolist()


def test_slots_follow_confirmation_and_deletion():
    s = Slots()
    assert _step(s, [1, 2], [False, False]) == [-1, -1]  # tentative tracks hold none
    assert _step(s, [1, 2], [True, False]) == [0, -1]
    assert _step(s, [1, 2], [False, True]) == [0, 1]  # 1 keeps its slot while it lives, confirmed or not
    assert _step(s, [2], [True]) == [1]  # 1 deleted: slot 0 freed in this frame
    assert _step(s, [2, 3], [True, True]) == [1, 2]  # a never-used slot before a freed one (POOL > 2)
    assert s.count == 3 and s.track_ids().tolist()[1:] == [2.0, 3.0] and np.isnan(s.track_ids()[0])


def _fill(s: Slots, first: int = 100) -> None:
    """Open every slot of the pool with tracks first .. first + POOL - 1, then delete them all."""
    _step(s, list(range(first, first + POOL)), [True] * POOL)
    _step(s, [], [])


def test_a_slot_freed_in_a_frame_is_not_reused_in_that_frame():
    s = Slots()
    _fill(s)
    _step(s, [1], [True])  # slot 0, freed longest ago
    assert _step(s, [2], [True]) == [1]  # 1 gone this frame: 2 gets the next free slot, slot 0 a NaN row first
    assert np.isnan(s.track_ids()[0])
    assert _step(s, [2, 3], [True, True]) == [1, 2]  # slot 0 is now the one freed last


def test_the_slot_freed_longest_ago_is_reused_first_and_count_is_the_peak():
    s = Slots()
    _step(s, [1, 2, 3], [True] * 3)
    assert _step(s, [1, 2, 3, 4], [True] * 4) == [0, 1, 2, 3]  # new slots while fewer than POOL exist
    s = Slots()
    _fill(s)
    _step(s, [1, 2, 3], [True] * 3)  # slots 0, 1, 2
    _step(s, [1, 3], [True] * 2)  # 2 (slot 1) freed, behind slots 3 .. POOL - 1
    _step(s, [3], [True])  # 1 (slot 0) freed
    for k in range(3, POOL):  # the slots freed by _fill come first
        assert _step(s, [3, 1000 + k], [True, True]) == [2, k]
    assert _step(s, [3, 4], [True, True]) == [2, 1]  # then slot 1, freed before slot 0
    assert _step(s, [3, 4, 5], [True] * 3) == [2, 1, 0]
    rng = np.random.default_rng(0)
    s, alive, bound, nxt, made = Slots(), set(), 0, 10, 0
    for _ in range(500):  # a long run of tracks born and deleted
        kept = {t for t in alive if rng.random() > 0.1}
        born = set(range(nxt, nxt + int(rng.integers(0, 3))))
        nxt, made = nxt + 3, made + len(born)
        deleted = alive - kept
        alive = kept | born
        bound = max(bound, len(alive) + len(deleted))  # a new slot only when every other is held or just freed
        got = _step(s, sorted(alive), [True] * len(alive))
        assert len(set(got)) == len(got) and min(got, default=0) >= 0  # distinct slots
    assert s.count <= max(bound, POOL) and s.count < made / 10


def test_a_track_and_the_track_replacing_it_differ_in_colour_and_the_table_replays_the_recorder():
    """T3 deleted at frame 5 and T4 confirmed at frame 6 on its car (the demo's break-up): different colours;
    track_colours(tracks table) gives the colours the recorder's Slots gave, frame by frame (empty frames too)."""
    rows, s, seen = [], Slots(), {}
    life = {1: (0, 30), 2: (0, 30), 3: (2, 5), 4: (6, 20), 5: (22, 28)}  # no track at all on frames 21
    for f in range(30):
        ids = [t for t, (a, b) in life.items() if a <= f <= b and not (f == 21)]
        conf = [f >= life[t][0] + 1 for t in ids]  # confirmed from their second frame
        for t, k in zip(ids, s.update(np.array(ids, np.int64), np.array(conf, bool))):
            if k >= 0:
                seen.setdefault(t, colours([k])[0].tolist())
        rows += [dict(frame=f, track_id=t, status="confirmed" if c else "tentative") for t, c in zip(ids, conf)]
    got = {t: c.tolist() for t, c in track_colours(pd.DataFrame(rows)).items()}
    assert got == seen and set(got) == set(life)
    assert got[3] != got[4] and len({tuple(c) for c in got.values()}) == len(got)


def test_colours_are_the_slots_palette_and_grey_without_one():
    c = colours(np.array([0, 1, -1, len(pal.SLOTS)]))
    assert c.dtype == np.uint8 and c.shape == (4, 3)
    assert c[0].tolist() == pal.SLOTS[0].tolist() and c[3].tolist() == pal.SLOTS[0].tolist()
    assert c[2].tolist() == list(pal.UNSLOTTED)
    assert len({tuple(x) for x in pal.SLOTS.tolist()}) == len(pal.SLOTS)
    assert tuple(pal.EGO) not in {tuple(x) for x in pal.SLOTS.tolist()}
