"""Diagnostics slots (testbed/recording/slots.py): bounded lines for any number of tracks, a gap before a slot
changes hands, the slot freed longest ago reused first, colours per slot."""
from __future__ import annotations

import numpy as np

from testbed.recording import palette as pal
from testbed.recording.slots import Slots, colours


def _step(s: Slots, ids, confirmed):
    return s.update(np.array(ids, dtype=np.int64), np.array(confirmed, dtype=bool)).tolist()


def test_slots_follow_confirmation_and_deletion():
    s = Slots()
    assert _step(s, [1, 2], [False, False]) == [-1, -1]  # tentative tracks hold none
    assert _step(s, [1, 2], [True, False]) == [0, -1]
    assert _step(s, [1, 2], [False, True]) == [0, 1]  # 1 keeps its slot while it lives, confirmed or not
    assert _step(s, [2], [True]) == [1]  # 1 deleted: slot 0 freed in this frame
    assert _step(s, [2, 3], [True, True]) == [1, 0]  # ... and reused only in a later one
    assert s.count == 2 and s.track_ids().tolist() == [3.0, 2.0]


def test_a_slot_freed_in_a_frame_is_not_reused_in_that_frame():
    s = Slots()
    _step(s, [1], [True])
    assert _step(s, [2], [True]) == [1]  # 1 gone this frame: 2 gets a new slot, slot 0 has a NaN row first
    assert np.isnan(s.track_ids()[0])
    assert _step(s, [2, 3], [True, True]) == [1, 0]


def test_the_slot_freed_longest_ago_is_reused_first_and_count_is_the_peak():
    s = Slots()
    _step(s, [1, 2, 3], [True] * 3)
    _step(s, [1, 3], [True] * 2)  # 2 (slot 1) freed
    _step(s, [3], [True])  # 1 (slot 0) freed
    assert _step(s, [3, 4], [True, True]) == [2, 1]  # slot 1 was freed first
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
    assert s.count <= bound and s.count < made / 10


def test_colours_are_the_slots_palette_and_grey_without_one():
    c = colours(np.array([0, 1, -1, len(pal.SLOTS)]))
    assert c.dtype == np.uint8 and c.shape == (4, 3)
    assert c[0].tolist() == pal.SLOTS[0].tolist() and c[3].tolist() == pal.SLOTS[0].tolist()
    assert c[2].tolist() == list(pal.UNSLOTTED)
    assert len({tuple(x) for x in pal.SLOTS.tolist()}) == len(pal.SLOTS)
    assert tuple(pal.EGO) not in {tuple(x) for x in pal.SLOTS.tolist()}
